"""Table I from a sweep: every row and seed as a cell, success on the same held-out episodes, paired tests.

A cell counts when its run finished and its last checkpoint was evaluated (`checkpoints/last.eval.json`, at least
`min_episodes` episodes); a row's value is the mean and standard deviation over its counted seeds, with the
difference to its block's baseline in parentheses, as in the paper. Rows evaluated on the same episodes (same
evaluation seed and count) are compared episode by episode: exact McNemar tests over every seed's pairs.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

from vitac.analysis.compare import wall_clock_hours
from vitac.analysis.outcomes import discordant, episode_steps, mcnemar_exact
from vitac.analysis.status import cells_of
from vitac.run_dirs import EVALUATION, TEACHER_RECORD, UNSEEN_EVALUATION, read_metrics
from vitac.utils.records import read_whole


@dataclass(frozen=True)
class Row:
    label: str
    paper: float  # the paper's success (%), mean and std over its seeds
    paper_std: float
    baseline: str | None  # the row the paper's parenthesis compares with
    inputs: str  # the paper's check marks: Privileged, Reduced, Contact forces, Wrist, Tactile


NAIVE = "Fusion - Naive"
ROWS = [
    Row("Privileged", 96.74, 1.63, None, "P"), Row("+ Contact forces", 98.96, 0.83, "Privileged", "PC"),
    Row("Tactile", 91.41, 5.51, None, "RT"), Row("Wrist", 93.23, 2.00, None, "RW"),
    Row("Wrist + Contact forces", 96.09, 1.41, "Wrist", "RCW"), Row(NAIVE, 92.97, 1.41, None, "RWT"),
    Row("Fusion - Gated (lambda_sym=0)", 94.53, 2.73, NAIVE, "RWT"),
    Row("Fusion - CMT (lambda_sym=0)", 96.22, 0.98, NAIVE, "RWT"),
    Row("Fusion - Gated + Symmetry (lambda_sym=1)", 95.05, 1.76, NAIVE, "RWT"),
    Row("Fusion - CMT + Symmetry (lambda_sym=1)", 96.59, 2.11, NAIVE, "RWT"),
]
BLOCK_ENDS = {"+ Contact forces", "Wrist + Contact forces", "Fusion - CMT (lambda_sym=0)"}  # the paper's rules
# The paired comparisons behind the paper's claims, besides each row against its baseline.
CLAIMS = [("Fusion - CMT (lambda_sym=0)", "Fusion - Gated (lambda_sym=0)"),
          ("Fusion - CMT + Symmetry (lambda_sym=1)", "Fusion - CMT (lambda_sym=0)"),
          ("Fusion - Gated + Symmetry (lambda_sym=1)", "Fusion - Gated (lambda_sym=0)"),
          ("Fusion - CMT + Symmetry (lambda_sym=1)", "Wrist + Contact forces"),  # "nearly matching" it
          ("Fusion - CMT (lambda_sym=0)", "Wrist + Contact forces"), ("Tactile", "Wrist")]


def mean_std(values: list[float]) -> tuple[float | None, float | None]:
    """Mean and sample standard deviation; one value has no spread to report (None, not 0)."""
    if not values:
        return None, None
    mean = sum(values) / len(values)
    return mean, math.sqrt(sum((v - mean) ** 2 for v in values) / (len(values) - 1)) if len(values) > 1 else None


def evaluated(cell: dict, min_episodes: int) -> dict:
    """The cell with its evaluation (when its run finished and was evaluated on enough episodes), its success on
    unseen seeds (where `unseen_seeds_eval.json` holds enough episodes) and wall-clock."""
    cell = dict(cell, success=None, episodes=0, ci95=None, hours=None, steps_to_success=None, teacher=None,
                unseen_success=None)
    if cell["run"] is None:
        return cell
    run = Path(cell["run"])
    if (run / TEACHER_RECORD).is_file():  # a distilled run: which teacher, by content
        record = read_whole(run / TEACHER_RECORD, json.load, "a distilled run's teacher record")
        cell["teacher"] = dict(sha256=record["sha256"], env_steps=record.get("env_steps"))
    hours = wall_clock_hours(read_metrics(run))
    cell["hours"] = round(hours[-1][1], 3) if hours else None
    report = run / EVALUATION
    if cell["status"] == "done" and report.is_file():
        data = read_whole(report, json.load, "a vitac.evaluate report")
        if data["episodes"] >= min_episodes:
            cell.update(success=data["success_rate"], episodes=data["episodes"], ci95=data["success_ci95"],
                        eval_seed=data["seed"], episode_success=data.get("episode_success"),
                        steps_to_success=data.get("steps_to_success_mean"),
                        episode_steps=episode_steps(data.get("episode_success"), data.get("steps_to_success")))
        if (run / UNSEEN_EVALUATION).is_file():
            unseen = read_whole(run / UNSEEN_EVALUATION, json.load, "a vitac.evaluate report")
            if unseen["episodes"] >= min_episodes:
                cell["unseen_success"] = unseen["success_rate"]
    return cell


def trials(cell: dict, size: int) -> list[tuple[float, float]]:
    """The paper's trials from one evaluated cell: consecutive blocks of `size` held-out episodes, each as (success
    %, mean steps to succeed over its successes); a block without a success has no steps and is left out."""
    steps = cell.get("episode_steps")
    if not steps:
        return []
    points = []
    for start in range(0, len(steps) - size + 1, size):
        block = steps[start:start + size]
        done = [s for s in block if s is not None]
        if done:
            points.append((100 * len(done) / size, sum(done) / len(done)))
    return points


def build(statuses: list[dict], seeds: list[int], min_episodes: int = 400) -> dict:
    """Table I as data from one scan of the runs (status.run_statuses()): per row the paper's value, every seed's
    cell, ours (mean, std, seeds counted) and the difference to the baseline; then the paired tests."""
    cells = cells_of(statuses, [r.label for r in ROWS], seeds)
    rows = []
    for r in ROWS:
        per_seed = {seed: evaluated(cells[(r.label, seed)], min_episodes) for seed in seeds}
        mean, std = mean_std([100 * c["success"] for c in per_seed.values() if c["success"] is not None])
        rows.append(dict(row=r.label, inputs=r.inputs, paper=r.paper, paper_std=r.paper_std, baseline=r.baseline,
                         mean=mean, std=std, seeds_counted=sum(c["success"] is not None for c in per_seed.values()),
                         seeds=per_seed))
    by_label = {row["row"]: row for row in rows}
    for row in rows:
        base = by_label.get(row["baseline"]) if row["baseline"] else None
        row["improvement"] = row["mean"] - base["mean"] if base and None not in (row["mean"], base["mean"]) else None
    pairs = [(r.label, r.baseline) for r in ROWS if r.baseline] + CLAIMS
    return dict(rows=rows, paired=[t for a, b in pairs if (t := paired_test(by_label[a], by_label[b]))],
                min_episodes=min_episodes, seeds=seeds)


def summed_discordant(pairs) -> tuple[int, int, int]:
    """Episodes only the first cell inserted, only the second, and episodes compared, summed over (first, second)
    pairs of evaluated cells; a pair not evaluated on the same episodes (evaluation seed) is skipped."""
    only_first = only_second = episodes = 0
    for a, b in pairs:
        if not (a.get("episode_success") and b.get("episode_success")) or a["eval_seed"] != b["eval_seed"]:
            continue
        n = min(len(a["episode_success"]), len(b["episode_success"]))
        first_only, second_only = discordant(a["episode_success"][:n], b["episode_success"][:n])
        only_first, only_second, episodes = only_first + first_only, only_second + second_only, episodes + n
    return only_first, only_second, episodes


def paired_test(first: dict, second: dict) -> dict | None:
    """Exact McNemar over the episodes both rows were evaluated on, seed by seed; None without any."""
    only_first, only_second, episodes = summed_discordant((a, second["seeds"][seed]) for seed, a in first["seeds"].items())
    if not episodes:
        return None
    return dict(first=first["row"], second=second["row"], episodes=episodes, only_first=only_first,
                only_second=only_second, p=mcnemar_exact(only_first, only_second))


def _ours(row: dict, tex: bool = False) -> str:
    if row["mean"] is None:
        started = [c for c in row["seeds"].values() if c["status"] != "missing"]
        return "missing" if not started else f"not evaluated ({len(started)} run{'s' * (len(started) > 1)} started)"
    pm = r" $\pm$ " if tex else " ± "
    text = f"{row['mean']:.2f}" + (f"{pm}{row['std']:.2f}" if row["std"] is not None else "")  # one seed: no spread
    return text + (f" ({row['improvement']:+.2f})" if row["improvement"] is not None else "")


def _seeds(row: dict, expected: int) -> str:
    """Seeds counted of those expected, and how many more are part-way (a run resumable across sittings)."""
    partial = sum(c["status"] == "partial" for c in row["seeds"].values())
    return f"{row['seeds_counted']} of {expected}" + (f", {partial} partial" if partial else "")


def _budget(row: dict) -> tuple[str, str]:
    counted = [c for c in row["seeds"].values() if c["success"] is not None]
    if not counted:
        return "", ""
    steps = sum(c["env_steps"] for c in counted) / len(counted) / 1e6
    hours = [c["hours"] for c in counted if c["hours"] is not None]
    return f"{steps:.2f} M", f"{sum(hours) / len(hours):.1f}" if hours else ""


def _origins(row: dict) -> str:
    """The distinct teachers of a row's counted cells (sha256 prefix, env steps), or the checkpoints they were
    warm-started from (their env steps are not in the cell's): two mean its seeds are not alike."""
    counted = [c for c in row["seeds"].values() if c["success"] is not None]
    teachers = {(c["teacher"]["sha256"][:8], c["teacher"]["env_steps"]) for c in counted if c.get("teacher")}
    starts = {f"warm start: {c['init_ckpt']}" for c in counted if c.get("init_ckpt")}
    return ", ".join([f"{sha} ({steps / 1e6:.2f} M)" if steps else sha for sha, steps in sorted(teachers)] +
                     sorted(starts))


def markdown(table: dict) -> str:
    lines = ["| Method | ours: success (%) | seeds | 95% CI of each seed | env steps / seed | hours / seed | paper (%) | "
             "teacher (its env steps) or warm start |", "|---|---|---|---|---|---|---|---|"]
    for row in table["rows"]:
        cis = ", ".join(f"{100 * c['ci95'][0]:.1f}-{100 * c['ci95'][1]:.1f}" for c in row["seeds"].values() if c["ci95"])
        steps, hours = _budget(row)
        lines.append(f"| {row['row']} | {_ours(row)} | {_seeds(row, len(table['seeds']))} | {cis} | {steps} | "
                     f"{hours} | {row['paper']:.2f} ± {row['paper_std']:.2f} | {_origins(row)} |")
    if table["paired"]:
        lines += ["", "| paired (same episodes) | episodes | only the first succeeded | only the second | exact McNemar p |",
                  "|---|---|---|---|---|"]
        lines += [f"| {t['first']} vs {t['second']} | {t['episodes']} | {t['only_first']} | {t['only_second']} | "
                  f"{t['p']:.3g} |" for t in table["paired"]]
    return "\n".join(lines)


def versus(now: dict, before: dict) -> list[dict]:
    """Two tables of build() (the same seeds), row by row: each one's mean, seeds and budget, and the paired test of
    the row against itself across them (seed by seed, on the episodes both evaluated). Rows evaluated in neither
    are left out."""
    earlier = {row["row"]: row for row in before["rows"]}
    rows = []
    for row in now["rows"]:
        old = earlier[row["row"]]
        if row["mean"] is None and old["mean"] is None:
            continue
        sides = {name: dict(mean=r["mean"], std=r["std"], seeds_counted=r["seeds_counted"], budget=_budget(r),
                            origins=_origins(r), unseen=_unseen(r)) for name, r in (("now", row), ("before", old))}
        rows.append(dict(row=row["row"], paper=row["paper"], paper_std=row["paper_std"], **sides,
                         paired=paired_test(dict(row, row="now"), dict(old, row="before"))))
    return rows


def _unseen(row: dict) -> dict | None:
    """The mean success (%) on unseen seeds of the counted cells evaluated there, and how many were."""
    unseen = [100 * c["unseen_success"] for c in row["seeds"].values()
              if c["success"] is not None and c["unseen_success"] is not None]
    return dict(mean=sum(unseen) / len(unseen), seeds=len(unseen)) if unseen else None


def versus_markdown(rows: list[dict]) -> str:
    def side(s: dict) -> str:
        if s["mean"] is None:
            return "not evaluated"
        spread = f" ± {s['std']:.2f}" if s["std"] is not None else ""
        steps, hours = s["budget"]
        unseen = s.get("unseen")
        unseen = f"; unseen seeds {unseen['mean']:.2f} ({unseen['seeds']})" if unseen else ""
        return (f"{s['mean']:.2f}{spread} ({s['seeds_counted']} seed{'s' * (s['seeds_counted'] > 1)}; {steps}, {hours} h"
                f"{unseen})")

    lines = ["| Method | paper (%) | before: held-out success (%) (seeds; env steps, hours a seed; unseen seeds' "
             "mean (seeds)) | now | now's teacher | "
             "paired: only now / only before (episodes), exact McNemar p |", "|---|---|---|---|---|---|"]
    for r in rows:
        t = r["paired"]
        test = f"{t['only_first']} / {t['only_second']} ({t['episodes']}), p = {t['p']:.3g}" if t else ""
        lines.append(f"| {r['row']} | {r['paper']:.2f} ± {r['paper_std']:.2f} | {side(r['before'])} | {side(r['now'])} | "
                     f"{r['now']['origins']} | {test} |")
    return "\n".join(lines)


def latex(table: dict) -> str:
    mark = r"\checkmark"
    lines = [r"\begin{tabular}{lccccccc}", r"\hline",
             r"Method & Privileged & Reduced & Contact forces & Wrist & Tactile & Ours (\%) & Paper (\%) \\ \hline \hline"]
    for row in table["rows"]:
        marks = " & ".join(mark if k in row["inputs"] else "" for k in "PRCWT")
        name = row["row"].replace("lambda_sym", r"$\lambda_{\textrm{sym}}$")
        lines.append(f"{name} & {marks} & {_ours(row, tex=True)} & {row['paper']:.2f} $\\pm$ {row['paper_std']:.2f} \\\\"
                     + (r" \hline \hline" if row["row"] in BLOCK_ENDS else ""))
    return "\n".join(lines + [r"\hline", r"\end{tabular}"])
