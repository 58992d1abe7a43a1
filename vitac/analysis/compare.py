"""Several runs in one figure: held-out success against env steps and against hours of training, training
success against env steps and, where a run distils (DAgger), its action error to the teacher.

    python -m vitac.runs compare --run "label=<run>/csv/metrics.csv[,<resumed run>/csv/metrics.csv]" --run ... \
        --out runs.png [--title ...]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from vitac.analysis.curves import column, read_segments, smooth
from vitac.utils.cli import output_file


def wall_clock_hours(rows) -> list[tuple[float, float]]:
    """(env steps, hours of training so far) per iteration, from each iteration's steps and env steps/s. A run's
    rows may start late (a resumed segment's own CSV): its first iteration is taken to be as long as its second."""
    timed = column(rows, "charts/SPS")
    first_size = timed[1][0] - timed[0][0] if len(timed) > 1 else timed[0][0] if timed else 0.0
    out, hours, previous = [], 0.0, timed[0][0] - first_size if timed else 0.0
    for r in rows:
        try:
            steps, sps = float(r["charts/env_steps"]), float(r["charts/SPS"])
        except (KeyError, ValueError):
            continue
        if sps > 0:
            hours += (steps - previous) / sps / 3600
        previous = steps
        out.append((steps, hours))
    return out


def compare(runs: dict[str, list[Path]], out: Path, title: str = "") -> None:
    """One figure of several runs (label -> metrics CSVs in order): held-out success against env steps and
    against hours of training, training success against env steps and, if any run distils, the action error."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    segments = {label: read_segments(paths)[0] for label, paths in runs.items()}
    distils = any(column(rows, "losses/action_mse") for rows in segments.values())
    fig, axes = plt.subplots(1, 3 + distils, figsize=(5 * (3 + distils), 3.8))
    for i, (label, rows) in enumerate(segments.items()):
        color = f"C{i}"
        evals = column(rows, "eval/success_rate")
        hours = dict(wall_clock_hours(rows))
        if evals:
            axes[0].plot(*zip(*evals, strict=True), "o-", ms=3, color=color, label=label)
            axes[1].plot([hours.get(s, float("nan")) for s, _ in evals], [v for _, v in evals], "o-", ms=3,
                         color=color, label=label)
        train = column(rows, "charts/success_rate")
        if train:
            axes[2].plot(*zip(*smooth(train, 20), strict=True), color=color, label=label)
        error = column(rows, "losses/action_mse")
        if distils and error:
            axes[3].plot(*zip(*smooth(error, 8), strict=True), color=color, label=label)
    axes[0].set(xlabel="env steps", ylabel="success rate", title="held-out evaluation during training", ylim=(-0.02, 1.02))
    axes[1].set(xlabel="hours of training on 2 cores", ylabel="success rate", title="the same against wall-clock",
                ylim=(-0.02, 1.02))
    axes[2].set(xlabel="env steps", ylabel="success rate",
                title="training episodes (their randomization, mean of 20)", ylim=(-0.02, 1.02))
    if distils:  # smoothed over 8 iterations: the error cycles with the episode's phase (early steps are hardest)
        axes[3].set(xlabel="env steps", ylabel="MSE per action dimension", yscale="log",
                    title="distillation: action error to the teacher (mean of 8)")
    for ax in axes:
        ax.legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)


def labelled_run(text: str) -> tuple[str, list[Path]]:
    label, sep, paths = text.partition("=")
    if not sep or not label or not paths:
        raise argparse.ArgumentTypeError(f"{text!r} is not allowed: expected 'label=a.csv[,b.csv...]'")
    return label, [Path(p) for p in paths.split(",")]


def main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m vitac.runs compare", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", type=labelled_run, action="append", required=True,
                        help="label=metrics CSV(s) of one run, in order (repeat for each run)")
    parser.add_argument("--out", type=output_file, required=True)
    parser.add_argument("--title", default="")
    args = parser.parse_args(argv)
    compare(dict(args.run), args.out, args.title)
    print(f"wrote {args.out}")
