"""Learning curves of one run from its metrics CSV: training success with the curriculum's randomization
scale, held-out evaluation success, reward per step, all against env steps.

    python tools/plot_run.py outputs/2026-11-25/10-00-00/csv/metrics.csv --out curves.png [--title ...]
        [--baseline other/metrics.csv --baseline-label "..."]
    python tools/plot_run.py first/csv/metrics.csv resumed/csv/metrics.csv --out curves.png   # one run, resumed

Several CSVs are one run's segments (a run resumed into another directory), in order; a vertical line marks
where each later segment starts.

`--baseline` overlays another run's curriculum scale on the first panel, to compare how fast two runs
widen the randomization.
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path


def column(rows, key):
    out = []
    for r in rows:
        try:
            steps, value = float(r["charts/env_steps"]), float(r.get(key, ""))
        except (KeyError, ValueError):
            continue
        if not math.isnan(value):
            out.append((steps, value))
    return out


def smooth(points, window: int):
    values = [v for _, v in points]
    return [(points[i][0], sum(values[max(0, i - window + 1):i + 1]) / len(values[max(0, i - window + 1):i + 1]))
            for i in range(len(points))]


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("metrics", type=Path, nargs="+", help="metrics CSV(s) of one run, in order")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--title", default="")
    parser.add_argument("--baseline", type=Path, default=None, help="metrics CSV of a run to compare with")
    parser.add_argument("--baseline-label", default="baseline")
    args = parser.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows, resumes = [], []
    for i, path in enumerate(args.metrics):
        with open(path) as f:
            segment = list(csv.DictReader(f))
        if i > 0 and segment:
            resumes.append(float(segment[0]["charts/env_steps"]))
        rows += segment
    fig, axes = plt.subplots(1, 3, figsize=(14, 3.8))
    for ax in axes:
        for steps in resumes:
            ax.axvline(steps, color="grey", lw=0.8, alpha=0.6)
    train = column(rows, "charts/success_rate")
    if train:
        axes[0].plot(*zip(*train, strict=True), ".", alpha=0.3, label="training episodes")
        axes[0].plot(*zip(*smooth(train, 10), strict=True), label="training (moving mean of 10)")
    scale = column(rows, "charts/randomization_scale")
    if scale:
        axes[0].plot(*zip(*scale, strict=True), "k--", label="curriculum randomization scale")
    if args.baseline:
        with open(args.baseline) as f:
            baseline = column(list(csv.DictReader(f)), "charts/randomization_scale")
        axes[0].plot(*zip(*baseline, strict=True), ":", color="grey", label=f"scale, {args.baseline_label}")
    axes[0].set(xlabel="env steps", ylabel="success rate", title="training (curriculum ranges)", ylim=(-0.02, 1.02))
    axes[0].legend(fontsize=7)
    evals = column(rows, "eval/success_rate")
    if evals:
        axes[1].plot(*zip(*evals, strict=True), "o-")
    axes[1].set(xlabel="env steps", ylabel="success rate", title="held-out evaluation (paper randomization)",
                ylim=(-0.02, 1.02))
    reward = column(rows, "charts/reward_per_step")
    if reward:
        axes[2].plot(*zip(*smooth(reward, 10), strict=True))
    axes[2].set(xlabel="env steps", ylabel="reward per step (moving mean of 10)", title="reward")
    fig.suptitle(args.title, fontsize=10)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=100)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
