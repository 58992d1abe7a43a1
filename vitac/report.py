"""Table I (markdown, LaTeX, JSON) and the paper's figures from your own runs.

    python -m vitac.report outputs/table1 [--out report] [--seeds 0 1 2] [--min-episodes 400] [--evaluate [--unseen]]

Reads every run under the given sweep directories (`python -m vitac.train -m +sweep=table1`) as cells of Table I,
one per row and seed (vitac/analysis/table1.py): a cell counts once its run finished and its last checkpoint was
evaluated on at least --min-episodes held-out episodes (`checkpoints/last.eval.json`; `--evaluate` runs the
missing evaluations first, all on the same episodes, so rows are compared episode by episode; with `--unseen`
also on as many episodes whose seeds no run has used, `unseen_seeds_eval.json`). Missing and unevaluated cells are shown as such, never as zero.
Writes table1.md, table1.tex, table1.json and the figures:
learning curves against env steps, success against steps to succeed per trial (40 held-out episodes) for naive,
gated and CMT fusion with density contours (the paper's Fig. "steps"), and, where the directories hold runs of
experiment=screw/*, the paper's screw figure for each screw task among them (<task>.png and <task>.json: screw,
screw_offthread, screw_insert); and the paper's computation table beside
ours from the policy benchmark's record (computation.md, from --computation, docs/data/bench_policy.json by
default); with `--qual "Naive=<ckpt>" "CMT + sym=<ckpt>"`, both pads' force fields over one held-out episode of
each (force_fields.png, the paper's Fig. "qual"); with `--against <earlier sweep dirs>`, every row beside its
earlier self, with both budgets and the paired test across them (versus.md, versus.json); and, for the wrist +
tactile fusion runs among them, the symmetry prior's configurations (vitac/analysis/symmetry.py: success, force
asymmetry and steps per seed, each against its lambda_sym = 0 twin; symmetry.json, symmetry.png).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from vitac.analysis import symmetry, table1
from vitac.analysis.status import cells_of, run_statuses
from vitac.run_dirs import (
    EVALUATION,
    UNSEEN_EVALUATION,
    UNSEEN_SEED,
    last_checkpoint,
    read_metrics,
)
from vitac.utils.checkpoint import resolve_checkpoint
from vitac.utils.cli import int_at_least, output_dir, stop_quietly_when_the_reader_closes, tool_entry
from vitac.utils.records import read_whole, write_json

EVAL_SEED = 2_000_000  # vitac.evaluate's default: every cell on the same held-out episodes
# The paper's screw figure (its appendix): its three policies' rows and the fusion ones (conf/experiment/screw/*.yaml).
SCREW_ROWS = {"Privileged": "Screw: privileged", "Wrist-camera": "Screw: wrist", "Tactile": "Screw: tactile",
              "CMT": "Screw: CMT", "CMT + sym": "Screw: CMT + sym"}
PAPER_SCREW = ("Privileged", "Wrist-camera", "Tactile")  # shown missing when not run; the fusion ones only when run
TRIAL_EPISODES = 40  # a trial of the paper's Fig. "steps": a block of held-out episodes, one dot
FUSION_ROWS = {"Naive": table1.NAIVE, "Gated": "Fusion - Gated (lambda_sym=0)", "CMT": "Fusion - CMT (lambda_sym=0)"}


def table_cells(table: dict) -> list[dict]:
    """Every cell of Table I, as evaluated() gives it."""
    return [cell for row in table["rows"] for cell in row["seeds"].values()]


def screw_cells(statuses: list[dict], seeds: list[int], min_episodes: int) -> dict[str, dict[str, list[dict]]]:
    """{task: {policy name: its evaluated cells, one per seed}} for the paper's screw figure from one scan of the runs
    (run_statuses()), one figure per screw task (screw, screw_offthread, screw_insert) among runs of experiment=screw/*."""
    rows = list(SCREW_ROWS.values())
    statuses = [s for s in statuses if s["row"] in rows]
    by_task = {task: cells_of([s for s in statuses if s["task"] == task], rows, seeds)
               for task in sorted({s["task"] for s in statuses})}
    return {task: {name: [table1.evaluated(cells[(row, seed)], min_episodes) for seed in seeds]
                   for name, row in SCREW_ROWS.items()} for task, cells in by_task.items()}


def screw_runs(screw: dict[str, dict[str, list[dict]]]) -> list[dict]:
    """Every cell of screw_cells(), as evaluated() gives it."""
    return [cell for cells in screw.values() for seeds in cells.values() for cell in seeds]


def evaluate_missing(cells: list[dict], episodes: int, unseen: bool = False) -> int:
    """Evaluate every finished cell without an evaluation of `episodes` held-out episodes (and, with `unseen`, of
    as many episodes whose seeds no run has used); returns how many evaluations ran."""
    from vitac.evaluate import evaluate

    ran = 0
    for cell in cells:
        run = Path(cell["run"]) if cell["status"] == "done" else None
        if run is None or not last_checkpoint(run).is_file():
            continue  # unfinished, or an archived run (it has no checkpoint)
        wanted = [(EVAL_SEED, run / EVALUATION)] if cell["success"] is None else []
        if unseen and cell.get("unseen_success") is None:
            wanted.append((UNSEEN_SEED, run / UNSEEN_EVALUATION))
        for seed, out in wanted:
            evaluate(str(last_checkpoint(run)), episodes=episodes, num_envs=8, num_workers="auto", seed=seed,
                     out=str(out))
            ran += 1
    return ran


def figures(table: dict, out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fig, ax = plt.subplots(figsize=(7, 4))
    for row in table["rows"]:
        runs = [c["run"] for c in row["seeds"].values() if c["run"]]
        for i, run in enumerate(runs):
            points = [(float(r["charts/env_steps"]), float(r["eval/success_rate"])) for r in read_metrics(Path(run))
                      if r.get("eval/success_rate") and r.get("charts/env_steps")]
            if points:
                ax.plot(*zip(*points, strict=True), "o-", ms=2, lw=1, label=row["row"] if i == 0 else None)
    ax.set(xlabel="env steps", ylabel="held-out success rate", title="training-time evaluation")
    if ax.get_legend_handles_labels()[0]:  # an empty sweep draws an empty figure, without matplotlib's warning
        ax.legend(fontsize=6)
    paths = [_save(fig, out / "learning_curves.png")]
    fig, ax = plt.subplots(figsize=(5, 4))
    for name, label in FUSION_ROWS.items():
        row = next(r for r in table["rows"] if r["row"] == label)
        cells = [c for c in row["seeds"].values() if c["success"] is not None]
        points = [p for c in cells for p in table1.trials(c, TRIAL_EPISODES)]
        if not points:
            continue
        x, y = np.array(points, float).T
        steps = np.mean([c["steps_to_success"] for c in cells if c.get("steps_to_success") is not None])
        dots = ax.scatter(x, y, s=12, alpha=0.7, label=f"{name}: {steps:.1f} steps, {len(cells)} seed(s)")
        if len(points) >= 3 and np.ptp(x) > 0 and np.ptp(y) > 0:  # a density needs spread in both
            from scipy.stats import gaussian_kde

            grid_x, grid_y = np.meshgrid(np.linspace(x.min() - 2, x.max() + 2, 60), np.linspace(y.min() - 5, y.max() + 5, 60))
            density = gaussian_kde(np.vstack([x, y]))(np.vstack([grid_x.ravel(), grid_y.ravel()])).reshape(grid_x.shape)
            ax.contour(grid_x, grid_y, density, levels=4, colors=[dots.get_facecolor()[0]], linewidths=0.8)
    ax.set(xlabel="success rate (%)", ylabel="steps to succeed",
           title=f"one dot per trial of {TRIAL_EPISODES} held-out episodes")
    if ax.get_legend_handles_labels()[0]:  # no fusion row evaluated yet
        ax.legend(fontsize=7)
    paths.append(_save(fig, out / "success_vs_steps.png"))
    return paths


def screw_figure(task: str, cells: dict[str, list[dict]], min_episodes: int, out: Path) -> Path | None:
    """The paper's screw figure for one task from screw_cells(): held-out success per policy, one dot per seed and the
    mean as a bar, and beside it the mean control steps to screw down (where all policies succeed, speed is what
    differs), as <task>.png with its record <task>.json; None when none of the task's runs was evaluated."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cells = {name: seeds for name, seeds in cells.items() if name in PAPER_SCREW or any(c["run"] for c in seeds)}
    done = {name: [c for c in seeds if c["success"] is not None] for name, seeds in cells.items()}
    results = {name: [100 * c["success"] for c in seeds] for name, seeds in done.items()}
    steps = {name: [c["steps_to_success"] for c in seeds if c["steps_to_success"] is not None]
             for name, seeds in done.items()}
    if not any(results.values()):
        return None
    fig, (ax, ax_steps) = plt.subplots(1, 2, figsize=(10, 3.6))
    for i, (values, times) in enumerate(zip(results.values(), steps.values(), strict=True)):
        if values:
            ax.bar(i, sum(values) / len(values), color=f"C{i}", alpha=0.6)
            ax.scatter([i] * len(values), values, color="k", s=12, zorder=3)
        else:
            ax.text(i, 2, "missing", ha="center", fontsize=8)
        if times:
            ax_steps.bar(i, sum(times) / len(times), color=f"C{i}", alpha=0.6)
            ax_steps.scatter([i] * len(times), times, color="k", s=12, zorder=3)
    labels = [f"{n}\n({len(v)} seed{'s' if len(v) != 1 else ''})" for n, v in results.items()]
    ax.set_xticks(range(len(results)), labels)
    ax.set(ylabel="held-out success (%)", ylim=(0, 105), title=f"task={task}")
    ax_steps.set_xticks(range(len(results)), labels)
    ax_steps.set(ylabel="control steps to screw down (mean)", title="how fast, where it succeeds")
    for a in (ax, ax_steps):
        a.tick_params(axis="x", labelsize=8)
    write_json(out / f"{task}.json", dict(task=task, success_percent_per_seed=results,
                                          steps_to_success_per_seed=steps, paired=screw_pairs(cells),
                                          min_episodes=min_episodes))
    return _save(fig, out / f"{task}.png")


def screw_pairs(cells: dict[str, list[dict]]) -> list[dict]:
    """Every pair of screw policies compared on the held-out episodes both were evaluated on, seed by seed (exact
    McNemar over the summed discordant episodes), as Table I's rows are."""
    rows = [dict(row=name, seeds={c["seed"]: c for c in seeds}) for name, seeds in cells.items()]
    return [test for i, first in enumerate(rows) for second in rows[i + 1:] if (test := table1.paired_test(first, second))]


def computation_table(bench: Path) -> str:
    """The paper's computation table beside ours, from a `benchmarks/bench_policy.py --json` record."""
    data = read_whole(bench, json.load, "a benchmarks/bench_policy.py record")
    lines = [f"Policy inference, batch 1 (`{data['meta'].get('command', 'benchmarks/bench_policy.py')}`, "
             f"{data['meta'].get('threads', '?')} threads, {data['rows'][0]['device']}); the paper's on its GPU.", "",
             "| Method | latency (ms) | memory (MB) | throughput (fps) | paper: latency / memory / fps |", "|---|---|---|---|---|"]
    for r in data["rows"]:
        lines.append(f"| {r['fusion']} | {r['latency_ms']:.2f} | {r['memory_mb']:.2f} | {r['throughput_fps']:.0f} | "
                     f"{r['paper_latency_ms']} / {r['paper_memory_mb']} / {r['paper_fps']} |")
    return "\n".join(lines)


def _save(fig, path: Path) -> Path:
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def named_checkpoint(text: str) -> tuple[str, str]:
    """`--qual`'s NAME=CKPT, refused as it is parsed (before any evaluation) unless CKPT names a checkpoint file."""
    name, _, ckpt = text.partition("=")
    if not (name and ckpt):
        raise argparse.ArgumentTypeError(f"{text!r} is not allowed: expected NAME=CKPT")
    if not resolve_checkpoint(ckpt).is_file():
        raise argparse.ArgumentTypeError(f"{text!r} is not allowed: {ckpt} is no checkpoint file")
    return name, ckpt


def main(argv=None):
    stop_quietly_when_the_reader_closes()
    parser = argparse.ArgumentParser(prog="python -m vitac.report", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dirs", nargs="+", type=Path)
    parser.add_argument("--out", type=output_dir, default="report")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--min-episodes", type=int_at_least(1), default=400)
    parser.add_argument("--evaluate", action="store_true", help="evaluate finished, unevaluated cells first")
    parser.add_argument("--unseen", action="store_true",
                        help="with --evaluate, also on as many episodes whose seeds no run has used (seed 3,000,000)")
    parser.add_argument("--qual", nargs="*", type=named_checkpoint, default=[], metavar="NAME=CKPT",
                        help="policies whose force fields over one held-out episode to draw (the paper's Fig. qual)")
    parser.add_argument("--computation", type=Path, default=Path("docs/data/bench_policy.json"),
                        help="the policy benchmark's record, for the paper's computation table")
    parser.add_argument("--against", nargs="+", type=Path, default=[], metavar="DIR",
                        help="an earlier table's sweep directories: each row beside its earlier self, paired")
    args = parser.parse_args(argv)
    if args.unseen and not args.evaluate:
        parser.error("argument --unseen: it is not allowed without --evaluate (it asks the evaluations for more seeds)")
    for d in args.dirs + args.against:
        if not d.is_dir():
            raise SystemExit(f"{d}: no such directory")
    statuses = run_statuses(args.dirs)
    table = table1.build(statuses, args.seeds, args.min_episodes)
    screw = screw_cells(statuses, args.seeds, args.min_episodes)
    if args.evaluate and evaluate_missing(table_cells(table) + screw_runs(screw), args.min_episodes, args.unseen):
        statuses = run_statuses(args.dirs)  # the evaluations wrote new reports
        table = table1.build(statuses, args.seeds, args.min_episodes)
        screw = screw_cells(statuses, args.seeds, args.min_episodes)
    args.out.mkdir(parents=True, exist_ok=True)
    md, tex = table1.markdown(table), table1.latex(table)
    (args.out / "table1.md").write_text(md + "\n")
    (args.out / "table1.tex").write_text(tex + "\n")
    write_json(args.out / "table1.json", table)
    paths = figures(table, args.out)
    if args.computation.is_file():
        (args.out / "computation.md").write_text(computation_table(args.computation) + "\n")
    if args.qual:
        from vitac.analysis import force_fields

        named = dict(args.qual)
        episodes = {name: force_fields.record_fields(ckpt, EVAL_SEED) for name, ckpt in named.items()}
        paths.append(force_fields.figure(episodes, args.out / "force_fields.png"))
    paths += [png for task, cells in screw.items() if (png := screw_figure(task, cells, args.min_episodes, args.out))]
    configurations = symmetry.configurations(statuses, args.min_episodes)
    if configurations:
        write_json(args.out / "symmetry.json", dict(configurations=configurations, min_episodes=args.min_episodes))
        paths += [args.out / "symmetry.json", symmetry.figure(configurations, args.out / "symmetry.png")]
    if args.against:
        rows = table1.versus(table, table1.build(run_statuses(args.against), args.seeds, args.min_episodes))
        versus_md = table1.versus_markdown(rows)
        (args.out / "versus.md").write_text(versus_md + "\n")
        write_json(args.out / "versus.json", dict(rows=rows, now=[str(d) for d in args.dirs],
                                                  before=[str(d) for d in args.against]))
        md += "\n\n" + versus_md
        paths += [args.out / "versus.md", args.out / "versus.json"]
    print(md)
    print(f"\nwrote {args.out / 'table1.md'}, {args.out / 'table1.tex'}, {args.out / 'table1.json'}, "
          + ", ".join(str(p) for p in paths))


if __name__ == "__main__":
    tool_entry(main)()
