"""How evaluated episodes ended: outcome counts and where the held part was, from `vitac.evaluate` JSON reports.

    python -m vitac.runs outcomes docs/data/results/privileged_cpu_stage1_eval_paper.json [more.json ...] [--paired]

For each report and outcome (inserted, on or above the socket, screwed down, ...): the number of episodes and
the quartiles of what the task's `outcome()` measures at the episode's end, as a markdown table: for insertion
the peg's horizontal offset from the hole axis (mm), its height above the hole floor (mm) and its tilt
(degrees); for the screw task the thread turns still to go, the nut's offset from the bolt's axis and its tilt.

`--paired` compares two reports of the same held-out episodes (same seed, count and randomization): how
many episodes only the first inserted, how many only the second, and the exact two-sided McNemar p-value; then
the mean steps to succeed of each over the episodes both inserted, with the Wilcoxon signed-rank p-value; and,
for reports that measured it, the pads' force balance (vitac/sim/balance.py) of each, paired by episode.

`--by-factor` shows, for each report, success by randomized factor (grasp depth, in-hand tilt, socket noise,
start pose, ...) and which factors the failures (or, with `--outcome LABEL`, the episodes of one outcome)
differ in (vitac.analysis.factors).

`--pooled` adds up reports of one checkpoint under one setting on different episodes (seed ranges that do
not overlap, e.g. `episodes=100` then `episodes=300 seed=2000100`): the success rate over all of them with
its 95% Wilson interval.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
from pathlib import Path

import numpy as np

from vitac.algos.evaluation import wilson_interval
from vitac.analysis.factors import factor_table
from vitac.utils.cli import stop_quietly_when_the_reader_closes
from vitac.utils.records import read_whole


def quartiles(values) -> str:
    if not values:  # a column of another task's report
        return ""
    q1, q2, q3 = np.percentile(values, [25, 50, 75])
    return f"{q2:.1f} ({q1:.1f}-{q3:.1f})"


SAME_EPISODES = ("seed", "episodes", "randomization_scale", "socket_obs_noise", "randomize_only")


def mcnemar_exact(only_first: int, only_second: int) -> float:
    """Two-sided exact McNemar p-value: a binomial(n, 1/2) test on the discordant episodes."""
    n = only_first + only_second
    tail = sum(math.comb(n, k) for k in range(min(only_first, only_second) + 1)) / 2 ** n
    return min(1.0, 2 * tail)


def discordant(first: list, second: list) -> tuple[int, int]:
    """Episodes (paired by position) that succeeded only in `first`, and only in `second`."""
    only_first = sum(bool(x) and not y for x, y in zip(first, second, strict=True))
    only_second = sum(bool(y) and not x for x, y in zip(first, second, strict=True))
    return only_first, only_second


def episode_steps(success: list[int] | None, steps: list[int] | None) -> list[int | None] | None:
    """Each episode's steps to succeed (None where it failed): vitac.evaluate lists the steps of the successes in
    episode order; None when the two lists do not line up (an older report)."""
    if success is None or steps is None or len(steps) != sum(success):
        return None
    taken = iter(steps)
    return [next(taken) if ok else None for ok in success]


def steps_compared(first: dict, second: dict, names: tuple[str, str]) -> str | None:
    """Steps to succeed on the episodes both inserted, with the two-sided Wilcoxon signed-rank p-value (paired by
    episode); None when a report does not list its steps per success."""
    a, b = (episode_steps(r.get("episode_success"), r.get("steps_to_success")) for r in (first, second))
    if a is None or b is None:
        return None
    both = [(x, y) for x, y in zip(a, b, strict=True) if x is not None and y is not None]
    if not both:
        return None
    from scipy.stats import wilcoxon

    x, y = np.array(both, float).T
    p = wilcoxon(x, y).pvalue if np.any(x != y) else 1.0
    return (f"steps to succeed on the {len(both)} episodes both inserted: {names[0]} {x.mean():.1f}, "
            f"{names[1]} {y.mean():.1f}, Wilcoxon signed-rank two-sided p = {p:.3f}")


BALANCE = {"field_contact": "field asymmetry in contact", "net_contact": "net-force asymmetry in contact",
           "field_episode": "field asymmetry over the episode", "net_episode": "net-force asymmetry over the episode"}


def balance_compared(first: dict, second: dict, names: tuple[str, str]) -> list[str]:
    """The pads' force balance (vitac/sim/balance.py: 0 balanced, 1 one pad alone) of the two reports on the
    episodes both measured, with the two-sided Wilcoxon signed-rank p-value (paired by episode)."""
    if not first.get("force_balance") or not second.get("force_balance"):
        return []
    from scipy.stats import wilcoxon

    lines = []
    for key, label in BALANCE.items():
        both = [(a[key], b[key]) for a, b in zip(first["force_balance"], second["force_balance"], strict=True)
                if a.get(key) is not None and b.get(key) is not None]
        if not both:
            continue
        x, y = np.array(both, float).T
        p = wilcoxon(x, y).pvalue if np.any(x != y) else 1.0
        lines.append(f"{label} (0 balanced, 1 one pad alone), mean over the {len(both)} episodes both measured: "
                     f"{names[0]} {x.mean():.3f}, {names[1]} {y.mean():.3f}, Wilcoxon signed-rank two-sided p = {p:.3f}")
    return lines


def discordant_pair(first: dict, second: dict, names: tuple[str, str]) -> tuple[int, int]:
    """Episodes only the first report's policy inserted and only the second's; refused unless the same episodes."""
    differ = [k for k in SAME_EPISODES if first.get(k) != second.get(k)]
    if differ:
        raise SystemExit(f"--paired: {names[0]} and {names[1]} are not the same episodes ({differ} differ)")
    a, b = (successes(r) for r in (first, second))
    return discordant(a, b)


def successes(report: dict) -> list[bool]:
    """Each episode's success: the report's own flags (any task), or for an older insertion report its outcomes."""
    if report.get("episode_success") is not None:
        return [bool(s) for s in report["episode_success"]]
    return [e["outcome"] == "inserted" for e in final_states(report)]


def paired(first: dict, second: dict, names: tuple[str, str]) -> str:
    only_first, only_second = discordant_pair(first, second, names)
    line = (f"paired: inserted only by {names[0]}: {only_first}, only by {names[1]}: {only_second}, "
            f"exact McNemar two-sided p = {mcnemar_exact(only_first, only_second):.3f}")
    steps = steps_compared(first, second, names)
    return "\n".join([line, *([steps] if steps else []), *balance_compared(first, second, names)])


def refuse_shared_episodes(reports: list, what: str) -> None:
    """Reports on disjoint episode sets pass; ones whose seed ranges overlap are refused, naming `what`."""
    spans = sorted((r["seed"], r["seed"] + r["episodes"]) for r in reports)
    if any(later[0] < earlier[1] for earlier, later in itertools.pairwise(spans)):
        raise SystemExit(f"{what} share episodes (their seed ranges {spans} overlap)")


def paired_summed(reports: list, names: list) -> str:
    """One exact McNemar over several pairs (A B A' B' ...): the same two policies on disjoint episode sets."""
    firsts, seconds = reports[0::2], reports[1::2]
    refuse_shared_episodes(firsts, f"--paired: the pairs {names}")
    counts = [discordant_pair(a, b, (names[2 * i], names[2 * i + 1]))
              for i, (a, b) in enumerate(zip(firsts, seconds, strict=True))]
    only_first, only_second = sum(c[0] for c in counts), sum(c[1] for c in counts)
    episodes = sum(r["episodes"] for r in firsts)
    return (f"summed over the {len(firsts)} pairs ({episodes} episodes): inserted only by the first of each pair: "
            f"{only_first}, only by the second: {only_second}, exact McNemar two-sided p = "
            f"{mcnemar_exact(only_first, only_second):.3f}")


POOLED_SAME = ("ckpt", "randomization_scale", "socket_obs_noise", "randomize_only", "policy")


def pooled(reports: list, names: list) -> str:
    differ = [k for k in POOLED_SAME if len({json.dumps(r.get(k)) for r in reports}) > 1]
    if differ:
        raise SystemExit(f"--pooled: {names} are not evaluations of one checkpoint under one setting ({differ} differ)")
    refuse_shared_episodes(reports, f"--pooled: {names}")
    successes = sum(round(r["success_rate"] * r["episodes"]) for r in reports)  # TacSL's success check
    episodes = sum(r["episodes"] for r in reports)
    low, high = wilson_interval(successes, episodes)
    return (f"pooled: {successes} of {episodes} episodes succeeded = {100 * successes / episodes:.1f}% "
            f"(95% Wilson interval {100 * low:.1f}-{100 * high:.1f}%)")


def read_report(path: Path) -> dict:
    """One `vitac.evaluate` report; a file that is not one is refused with its name, before any table is printed."""
    report = read_whole(path, json.load, "a vitac.evaluate report")
    if not isinstance(report, dict) or not {"episodes", "success_rate", "seed"} <= report.keys():
        raise SystemExit(f"{path}: not a vitac.evaluate report (no episodes, success_rate and seed)")
    if "final_state" not in report and "final_peg" not in report:
        raise SystemExit(f"{path}: no 'final_state' entries (written by an older vitac.evaluate); evaluate again")
    return report


# What a task's outcome() measures, as the table shows it: (column, factor from SI units).
COLUMNS = {"peg_offset_xy": ("offset from axis, mm", 1000.0), "peg_height": ("height above floor, mm", 1000.0),
           "peg_tilt": ("tilt, deg", math.degrees(1.0)), "grasp_depth": ("peg bottom below fingertips, mm", 1000.0),
           "fingers_on_socket": ("finger links on the socket", 1.0), "turns_to_go": ("thread turns to go", 1.0),
           "nut_offset_xy": ("offset from axis, mm", 1000.0), "nut_tilt": ("tilt, deg", math.degrees(1.0))}
# Reports written before 'final_state' held the peg's values converted already, under these names.
OLD_COLUMNS = {"offset_xy_mm": "offset from axis, mm", "height_mm": "height above floor, mm", "tilt_deg": "tilt, deg"}


def final_states(report: dict) -> list[dict]:
    """Each episode's end: its outcome and the task's measurements, keyed by table column (a measurement this
    module does not know keeps its own name and unit)."""
    if "final_peg" in report:
        return [{OLD_COLUMNS.get(k, k): v for k, v in e.items()} for e in report["final_peg"]]
    ends = []
    for e in report["final_state"]:
        end = dict(outcome=e["outcome"])
        for key, value in e.items():
            if key != "outcome":
                column, factor = COLUMNS.get(key, (key, 1.0))
                end[column] = factor * value
        ends.append(end)
    return ends


def report_name(path: Path) -> str:
    """A report's name in tables: its file's, or for a run's `checkpoints/last.eval.json` the run's."""
    if path.name == "last.eval.json" and path.parent.name == "checkpoints":
        return path.parents[1].name
    return path.stem


def main(argv=None):
    stop_quietly_when_the_reader_closes()
    parser = argparse.ArgumentParser(prog="python -m vitac.runs outcomes", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("reports", type=Path, nargs="+")
    parser.add_argument("--paired", action="store_true", help="compare two reports of the same episodes; with pairs "
                        "A B A' B' ... (one policy's first, on disjoint episodes), each pair and all summed")
    parser.add_argument("--pooled", action="store_true", help="success over reports of one checkpoint on other episodes")
    parser.add_argument("--by-factor", action="store_true",
                        help="success by randomized factor, and which factors the failures differ in (each report)")
    parser.add_argument("--outcome", metavar="LABEL",
                        help="with --by-factor: compare the episodes that ended so (e.g. 'stuck part-way in the "
                             "hole') with the others, instead of the failures with the successes")
    args = parser.parse_args(argv)
    if args.outcome is not None and not args.by_factor:
        parser.error("--outcome goes with --by-factor")
    if args.paired and len(args.reports) % 2:
        parser.error("--paired takes pairs of reports: A B, or A B A' B' ... on disjoint episodes")
    reports = [read_report(path) for path in args.reports]
    by_factor = [f"\n{report_name(path)}: " + factor_table(report, args.outcome)
                 for path, report in zip(args.reports, reports, strict=True)] if args.by_factor else []
    ends = [final_states(report) for report in reports]
    columns = list(dict.fromkeys(k for episodes in ends for e in episodes for k in e if k != "outcome"))
    print("| report | outcome | episodes | " + " | ".join(f"{c}: median (quartiles)" if i == 0 else c
                                                     for i, c in enumerate(columns)) + " |")
    print("|---|---|---|" + "---|" * len(columns))
    for path, episodes_of_report in zip(args.reports, ends, strict=True):
        by_outcome: dict[str, list] = {}
        for episode in episodes_of_report:
            by_outcome.setdefault(episode["outcome"], []).append(episode)
        for outcome, episodes in sorted(by_outcome.items(), key=lambda item: -len(item[1])):
            cells = [quartiles([e[c] for e in episodes if c in e]) for c in columns]
            print(f"| {report_name(path)} | {outcome} | {len(episodes)} | " + " | ".join(cells) + " |")
    if args.paired:
        names = [report_name(path) for path in args.reports]
        for i in range(0, len(reports), 2):
            print("\n" + paired(reports[i], reports[i + 1], names=(names[i], names[i + 1])))
        if len(reports) > 2:
            print("\n" + paired_summed(reports, names))
    if args.pooled:
        print("\n" + pooled(reports, [report_name(path) for path in args.reports]))
    for table in by_factor:
        print(table)

