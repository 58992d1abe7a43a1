"""The figures docs/results.md quotes for a training run, from its metrics CSV(s).

    python -m vitac.runs summary <run>/csv/metrics.csv [<resumed run>/csv/metrics.csv ...] [--window 1e6]
        [--max-steps 8e6]   # only the iterations up to that many env steps, to compare runs at one budget

Prints env steps covered, iterations, median env steps/s and hours of training, the learning rate (median and
10th-90th percentile), median approximate KL, entropy at the first and last iteration (PPO), the action error to
the teacher (DAgger: first and last 8 iterations), training success (mean per `--window` env steps and
overall), the range of the held-out evaluations, the learning rate's extremes and the explained variance of
the value targets (first iteration and median). A figure a run did not log is said to be missing. Segments are
read as vitac/analysis/curves.py reads them.
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

import numpy as np

from vitac.analysis.compare import wall_clock_hours
from vitac.analysis.curves import column, read_segments
from vitac.utils.cli import number_above, stop_quietly_when_the_reader_closes


def main(argv=None):
    stop_quietly_when_the_reader_closes()
    parser = argparse.ArgumentParser(prog="python -m vitac.runs summary", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("metrics", type=Path, nargs="+", help="metrics CSV(s) of one run, in order")
    parser.add_argument("--window", type=number_above(0), default=1e6, help="env steps per training-success mean")
    parser.add_argument("--max-steps", type=number_above(0), default=None,
                        help="summarize up to this many env steps (compare runs at one budget)")
    args = parser.parse_args(argv)
    rows = read_segments(args.metrics, args.max_steps)[0]
    values = lambda key: [v for _, v in column(rows, key)]  # noqa: E731
    steps, lr, entropy = values("charts/env_steps"), values("charts/lr"), values("losses/entropy")
    success, evals = column(rows, "charts/success_rate"), values("eval/success_rate")
    explained = values("losses/explained_variance")
    missing = "not logged by this run (another algorithm or an older version)"
    print(f"env steps: {steps[0]:,.0f} -> {steps[-1]:,.0f} ({len(values('losses/loss'))} iterations)")
    hours = wall_clock_hours(rows)
    print(f"median env steps/s: {statistics.median(values('charts/SPS')):.0f}; "
          f"{hours[-1][1] if hours else 0.0:.2f} hours of training")
    if lr:
        p10, p50, p90 = np.percentile(lr, [10, 50, 90])
        print(f"learning rate: median {p50:.2g} (10th-90th percentile {p10:.2g} to {p90:.2g})")
    else:
        print(f"learning rate: {missing}")
    kl, error = values("losses/approx_kl"), values("losses/action_mse")
    print(f"median approx KL: {statistics.median(kl):.3f}" if kl else f"median approx KL: {missing}")
    print(f"entropy: {entropy[0]:.2f} -> {entropy[-1]:.2f}" if entropy else f"entropy: {missing}")
    if error:  # the mean of 8 iterations: the error cycles with the episodes' phase
        print(f"action error to the teacher (MSE per dimension, mean of 8 iterations): first "
              f"{statistics.mean(error[:8]):.3f}, last {statistics.mean(error[-8:]):.3f}")
    start = success[0][0]
    windows: dict[int, list] = {}
    for s, v in success:
        windows.setdefault(int((s - start) // args.window), []).append(v)
    means = ", ".join(f"{100 * statistics.mean(v):.0f}%" for _, v in sorted(windows.items()))
    print(f"training success, mean per {args.window:,.0f} env steps: {means}; overall "
          f"{100 * statistics.mean(v for _, v in success):.0f}%")
    if evals:
        print(f"held-out evaluations: {len(evals)}, {100 * min(evals):.1f}-{100 * max(evals):.1f}%")
    print(f"learning rate range: {min(lr):.2g} to {max(lr):.2g}" if lr else f"learning rate range: {missing}")
    print(f"explained variance: first {explained[0]:.2f}, median {statistics.median(explained):.2f}" if explained
          else f"explained variance: {missing}")

