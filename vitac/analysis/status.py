"""Which cells of a sweep are done, partial or missing: `python -m vitac.runs status <sweep dir> ...`.

    python -m vitac.runs status outputs/table1 [--experiments 'table1/*'] [--seeds 0 1 2]

A cell is one experiment (a row) and one seed. Expected cells are every experiment matching `--experiments`
(conf/experiment/) times every seed; each run directory found under the sweep directories (a `config.yaml`)
fills its cell: done (its last checkpoint holds the whole budget), partial (some iterations), or missing.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import yaml

from vitac.run_dirs import run_status
from vitac.utils.cli import tool_entry

CONF = Path(__file__).resolve().parents[2] / "conf"


def expected_rows(pattern: str) -> list[str]:
    """The `row` labels of the experiments matching `pattern` (relative to conf/experiment): Table I's rows in the
    paper's order, any others after them in name order."""
    from vitac.analysis.table1 import ROWS  # imported here: table1 builds on this module

    files = sorted((CONF / "experiment").glob(f"{pattern}.yaml"))
    if not files:
        raise SystemExit(f"--experiments={pattern!r} is not allowed: no conf/experiment/{pattern}.yaml")
    rows = [yaml.safe_load(f.read_text()).get("row") or f.stem for f in files]
    paper_order = {r.label: i for i, r in enumerate(ROWS)}
    return sorted(rows, key=lambda row: paper_order.get(row, len(paper_order)))  # stable: the others keep name order


def run_statuses(dirs: list[Path]) -> list[dict]:
    """run_status() of every run under the given directories."""
    for d in dirs:
        if not d.is_dir():
            raise SystemExit(f"{d}: no such directory")
    return [run_status(config.parent) for d in dirs for config in sorted(d.rglob("config.yaml"))
            if config.parent.name != ".hydra"]


def cells_of(statuses: list[dict], rows: list[str], seeds: list[int]) -> dict:
    """{(row, seed): run status} for every expected cell; of several runs of a cell the furthest trained; a missing
    cell has status "missing" and no run."""
    cells = {(row, seed): dict(row=row, seed=seed, status="missing", iterations=0, budget=None, env_steps=0, run=None)
             for row in rows for seed in seeds}
    for status in statuses:
        key = (status["row"], status["seed"])
        if key in cells and (cells[key]["run"] is None or status["iterations"] > cells[key]["iterations"]):
            cells[key] = status
    return cells


def markdown(cells: dict, rows: list[str], seeds: list[int]) -> str:
    lines = ["| row | " + " | ".join(f"seed {s}" for s in seeds) + " |", "|---|" + "---|" * len(seeds)]
    for row in rows:
        entries = []
        for seed in seeds:
            c = cells[(row, seed)]
            entries.append("missing" if c["status"] == "missing" and c["run"] is None else
                           f"{c['status']}: {c['iterations']}/{c['budget']} it, {c['env_steps'] / 1e6:.2f} M steps")
        lines.append(f"| {row} | " + " | ".join(entries) + " |")
    return "\n".join(lines)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m vitac.runs status", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dirs", nargs="+", type=Path)
    parser.add_argument("--experiments", default="table1/*")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    args = parser.parse_args(argv)
    rows = expected_rows(args.experiments)
    cells = cells_of(run_statuses(args.dirs), rows, args.seeds)
    print(markdown(cells, rows, args.seeds))
    counts = {s: sum(c["status"] == s for c in cells.values()) for s in ("done", "partial", "missing")}
    print(f"\n{counts['done']} done, {counts['partial']} partial, {counts['missing']} missing of {len(cells)} cells")


if __name__ == "__main__":
    tool_entry(main)()
