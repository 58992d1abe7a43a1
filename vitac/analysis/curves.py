"""Learning curves of one run from its metrics CSV: training success with the curriculum's randomization
scale, held-out evaluation success, reward per step and PPO's step size (approximate KL per iteration and
learning rate), all against env steps.

    python -m vitac.runs plot outputs/2026-11-25/10-00-00/csv/metrics.csv --out curves.png [--title ...]
        [--baseline other/metrics.csv --baseline-label "..."]
    python -m vitac.runs plot first/csv/metrics.csv resumed/csv/metrics.csv --out curves.png   # one run, resumed
    python -m vitac.runs plot seed1/csv/metrics.csv --compare seed0/csv/metrics.csv --max-steps 8e6 --out c.png

Several CSVs are one run's segments (a run resumed into another directory, or warm-started from the previous
segment's last checkpoint with init_ckpt), in order; a vertical line marks where each later segment starts.

`--baseline` overlays another run's curriculum scale on the first panel, to compare how fast two runs
widen the randomization. `--compare` overlays another run's (or branch's) training success, evaluations
and KL in grey, e.g. two continuations of one checkpoint. `--max-steps` cuts every run at one budget.
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

from vitac.utils.cli import number_above, output_file
from vitac.utils.records import read_whole


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


def read_segments(paths, max_steps: float | None = None):
    """The rows of one run's metrics CSVs in order, and the env steps at which each later segment starts;
    with `max_steps`, only the rows up to that many env steps (to compare runs at one budget).

    A segment whose env steps start below the previous segment's last (a warm start with init_ckpt, which
    counts from 0) is shifted to start where the previous one ended.
    """
    rows, resumes = [], []
    for i, path in enumerate(paths):
        segment = read_whole(path, lambda f: [r for r in csv.DictReader(f) if r.get("charts/env_steps")],
                             "a metrics CSV")
        if not segment:  # a plot or summary of it would silently show nothing
            raise SystemExit(f"{path}: no rows with charts/env_steps: not a vitac metrics CSV")
        if i > 0:
            end = float(rows[-1]["charts/env_steps"]) if rows else 0.0
            if float(segment[0]["charts/env_steps"]) < end:
                for r in segment:
                    r["charts/env_steps"] = str(float(r["charts/env_steps"]) + end)
            resumes.append(float(segment[0]["charts/env_steps"]))
        rows += segment
    if max_steps is not None:
        rows = [r for r in rows if float(r["charts/env_steps"]) <= max_steps]
        resumes = [steps for steps in resumes if steps <= max_steps]
        if not rows:
            raise SystemExit(f"{[str(p) for p in paths]}: no rows up to {max_steps:,.0f} env steps")
    return rows, resumes


def smooth(points, window: int):
    values = [v for _, v in points]
    return [(points[i][0], sum(values[max(0, i - window + 1):i + 1]) / len(values[max(0, i - window + 1):i + 1]))
            for i in range(len(points))]


def main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m vitac.runs plot", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("metrics", type=Path, nargs="+", help="metrics CSV(s) of one run, in order")
    parser.add_argument("--out", type=output_file, required=True)
    parser.add_argument("--title", default="")
    parser.add_argument("--baseline", type=Path, default=None, help="metrics CSV of a run to compare with")
    parser.add_argument("--baseline-label", default="baseline")
    parser.add_argument("--compare", type=Path, nargs="+", default=None, help="metrics CSV(s) of a run to overlay")
    parser.add_argument("--compare-label", default="other run")
    parser.add_argument("--max-steps", type=number_above(0), default=None,
                        help="plot every run up to this many env steps (compare at one budget)")
    args = parser.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows, resumes = read_segments(args.metrics, args.max_steps)
    other = read_segments(args.compare, args.max_steps)[0] if args.compare else []
    fig, axes = plt.subplots(1, 4, figsize=(18, 3.8))
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
        baseline = column(read_segments([args.baseline], args.max_steps)[0], "charts/randomization_scale")
        axes[0].plot(*zip(*baseline, strict=True), ":", color="grey", label=f"scale, {args.baseline_label}")
    other_train = column(other, "charts/success_rate")
    if other_train:
        axes[0].plot(*zip(*smooth(other_train, 10), strict=True), color="grey", label=f"training, {args.compare_label}")
    axes[0].set(xlabel="env steps", ylabel="success rate", title="training (curriculum ranges)", ylim=(-0.02, 1.02))
    axes[0].legend(fontsize=7)
    evals = column(rows, "eval/success_rate")
    if evals:
        axes[1].plot(*zip(*evals, strict=True), "o-", label="this run")
    other_evals = column(other, "eval/success_rate")
    if other_evals:
        axes[1].plot(*zip(*other_evals, strict=True), "o-", color="grey", label=args.compare_label)
        axes[1].legend(fontsize=7)
    axes[1].set(xlabel="env steps", ylabel="success rate", title="held-out evaluation (paper randomization)",
                ylim=(-0.02, 1.02))
    reward = column(rows, "charts/reward_per_step")
    if reward:
        axes[2].plot(*zip(*smooth(reward, 10), strict=True))
    axes[2].set(xlabel="env steps", ylabel="reward per step (moving mean of 10)", title="reward")
    for source, color, label in ((rows, None, "approx. KL"), (other, "grey", f"approx. KL, {args.compare_label}")):
        kl = column(source, "losses/approx_kl")
        if kl:
            axes[3].plot(*zip(*smooth(kl, 10), strict=True), color=color, label=label)
    lr = column(rows, "charts/lr")
    if lr:
        axes[3].plot(*zip(*lr, strict=True), ".", ms=2, color="C3", label="learning rate")
    axes[3].set(xlabel="env steps", yscale="log", title="PPO step size (moving mean of 10)")
    axes[3].legend(fontsize=7)
    fig.suptitle(args.title, fontsize=10)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=100)
    print(f"wrote {args.out}")

