"""Table I (markdown + LaTeX) and figures from your own runs.

    python -m vitac.report outputs/multirun/2026-11-25/10-00-00 [--out docs/report]

Scans the given directories for runs (a `config.yaml` beside `csv/metrics.csv`), groups them by their
Table I row (`row`, set by conf/experiment/table1/*.yaml; otherwise obs/fusion/reg), and reports the final
held-out success rate (mean +- std over seeds; `vitac.evaluate` JSON reports next to the checkpoint win
over the training-time evaluation), steps to succeed, and the paper's number beside each row. Figures:
learning curves (evaluation success and reward per step against env steps) and the paper's
success-vs-steps scatter. Every row names the preset it came from.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
from collections import defaultdict
from pathlib import Path

import yaml

from vitac.utils.cli import stop_quietly_when_the_reader_closes
from vitac.utils.records import read_whole

PAPER = {"Privileged": 96.74, "+ Contact forces": 98.96, "Tactile": 91.41, "Wrist": 93.23,
         "Wrist + Contact forces": 96.09, "Fusion - Naive": 92.97, "Fusion - Gated (lambda_sym=0)": 94.53,
         "Fusion - CMT (lambda_sym=0)": 96.22, "Fusion - Gated + Symmetry (lambda_sym=1)": 95.05,
         "Fusion - CMT + Symmetry (lambda_sym=1)": 96.59}


UNREADABLE = "; evaluate or rerun that run again, or leave its directory out"


def _float(x):
    try:
        value = float(x)
    except (TypeError, ValueError):
        return None
    return None if math.isnan(value) else value


def load_run(run: Path) -> dict | None:
    config_path, metrics_path = run / "config.yaml", run / "csv" / "metrics.csv"
    if not (config_path.is_file() and metrics_path.is_file()):
        return None
    cfg = read_whole(config_path, yaml.safe_load, hint=UNREADABLE)
    rows = read_whole(metrics_path, lambda f: list(csv.DictReader(f)), hint=UNREADABLE)
    curve = [(_float(r.get("charts/env_steps")), _float(r.get("eval/success_rate")), _float(r.get("charts/reward_per_step")))
             for r in rows]
    evals = [(s, e) for s, e, _ in curve if s is not None and e is not None]
    fusion = cfg["fusion"]["_target_"].rsplit(".", 1)[-1]
    fused = cfg["obs"]["name"] == "wrist_tactile"  # the fusion module only matters with wrist + tactile
    row = cfg.get("row") or (f"{cfg['obs']['name']} / {fusion} / lambda_sym={cfg['reg']['lambda_sym']}" if fused
                             else cfg["obs"]["name"])
    result = dict(run=str(run), row=row, seed=cfg.get("seed"), preset=cfg["preset"]["name"], curve=curve,
                  success=evals[-1][1] if evals else None, steps_to_success=None,
                  env_steps=max((s for s, _, _ in curve if s is not None), default=0))
    report = run / "checkpoints" / "last.eval.json"
    if report.is_file():
        data = read_whole(report, json.load, hint=UNREADABLE)
        result.update(success=data["success_rate"], steps_to_success=data.get("steps_to_success_mean"),
                      episodes=data["episodes"])
    else:
        steps = [_float(r.get("eval/steps_to_success")) for r in rows]
        steps = [s for s in steps if s is not None]
        result["steps_to_success"] = steps[-1] if steps else None
    return result


def mean_std(values):
    values = [v for v in values if v is not None]
    if not values:
        return None, None
    mean = sum(values) / len(values)
    std = math.sqrt(sum((v - mean) ** 2 for v in values) / (len(values) - 1)) if len(values) > 1 else 0.0
    return mean, std


def tables(groups: dict) -> tuple[str, str]:
    md = ["| Method | preset | seeds | env steps / run | success (%) | steps to succeed | paper (%) |",
          "|---|---|---|---|---|---|---|"]
    tex = [r"\begin{tabular}{lccc}", r"\hline", r"Method & Seeds & Success rate (\%) & Paper (\%) \\ \hline"]
    order = list(PAPER) + sorted(set(groups) - set(PAPER))
    for row in order:
        runs = groups.get(row)
        if not runs:
            continue
        mean, std = mean_std([100 * r["success"] if r["success"] is not None else None for r in runs])
        steps, _ = mean_std([r["steps_to_success"] for r in runs])
        presets = ",".join(sorted({r["preset"] for r in runs}))
        budget = int(sum(r["env_steps"] for r in runs) / len(runs))
        success = f"{mean:.2f} ± {std:.2f}" if mean is not None else "n/a"
        paper = PAPER.get(row, "")
        md.append(f"| {row} | {presets} | {len(runs)} | {budget:,} | {success} | "
                  f"{steps:.1f} | {paper} |" if steps is not None else
                  f"| {row} | {presets} | {len(runs)} | {budget:,} | {success} | n/a | {paper} |")
        tex_success = f"{mean:.2f} $\\pm$ {std:.2f}" if mean is not None else "n/a"
        tex.append(f"{row.replace('_', '-')} & {len(runs)} & {tex_success} & {paper} \\\\")
    tex += [r"\hline", r"\end{tabular}"]
    return "\n".join(md), "\n".join(tex)


def figures(groups: dict, out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    fig, (ax_eval, ax_reward) = plt.subplots(1, 2, figsize=(11, 4))
    for row, runs in groups.items():
        for i, r in enumerate(runs):
            label = row if i == 0 else None
            evals = [(s, e) for s, e, _ in r["curve"] if s is not None and e is not None]
            rewards = [(s, w) for s, _, w in r["curve"] if s is not None and w is not None]
            if evals:
                ax_eval.plot(*zip(*evals, strict=True), marker="o", ms=3, label=label)
            if rewards:
                ax_reward.plot(*zip(*rewards, strict=True), alpha=0.8, label=label)
    ax_eval.set(xlabel="env steps", ylabel="held-out success rate", title="evaluation (deterministic policy)")
    ax_reward.set(xlabel="env steps", ylabel="reward per step", title="training reward")
    ax_eval.legend(fontsize=7)
    paths.append(_save(fig, out / "learning_curves.png"))
    fig, ax = plt.subplots(figsize=(5, 4))
    for row, runs in groups.items():
        points = [(100 * r["success"], r["steps_to_success"]) for r in runs
                  if r["success"] is not None and r["steps_to_success"] is not None]
        if points:
            ax.scatter(*zip(*points, strict=True), label=row, s=20)
    ax.set(xlabel="success rate (%)", ylabel="steps to succeed", title="success vs steps to succeed (per run)")
    ax.legend(fontsize=7)
    paths.append(_save(fig, out / "success_vs_steps.png"))
    return paths


def _save(fig, path: Path) -> Path:
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main():
    stop_quietly_when_the_reader_closes()
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dirs", nargs="+", type=Path)
    parser.add_argument("--out", type=Path, default=Path("report"))
    args = parser.parse_args()
    runs = []
    for d in args.dirs:
        if not d.exists():
            raise SystemExit(f"{d}: no such directory")
        for config in sorted(d.rglob("config.yaml")):
            run = load_run(config.parent)
            if run is not None:
                runs.append(run)
    if not runs:
        raise SystemExit(f"no runs (config.yaml beside csv/metrics.csv) under {[str(d) for d in args.dirs]}")
    groups = defaultdict(list)
    for r in runs:
        groups[r["row"]].append(r)
    args.out.mkdir(parents=True, exist_ok=True)
    md, tex = tables(groups)
    (args.out / "table1.md").write_text(md + "\n")
    (args.out / "table1.tex").write_text(tex + "\n")
    paths = figures(groups, args.out)
    print(md)
    print(f"\nwrote {args.out / 'table1.md'}, {args.out / 'table1.tex'}, " + ", ".join(str(p) for p in paths))


if __name__ == "__main__":
    main()
