"""A run's summary, small enough to commit, that `vitac.report` and `vitac.runs status` read as the run itself.

    python -m vitac.runs archive <run dir> --out docs/data/table1_runs/<row>_seed<k>

Keeps what the report reads (the resolved `config.yaml`, every metrics file of the run's attempts, the evaluation
of its last checkpoint and, where the run has one, its evaluation on unseen seeds, `unseen_seeds_eval.json`), a
distilled run's `teacher.json` (its teacher by content) and, in `run.json`, the iterations its last checkpoint
held, so Table I can be regenerated from the repository after the run directory and
its checkpoints (150 MB for a camera student) are gone. An archive cannot be resumed: it holds no checkpoint.
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

from vitac.run_dirs import (
    ARCHIVE_RECORD,
    EVALUATION,
    TEACHER_RECORD,
    UNSEEN_EVALUATION,
    completed_iterations,
    last_checkpoint,
)
from vitac.utils.cli import tool_entry
from vitac.utils.records import write_json


def archive(run: Path, out: Path) -> Path:
    """Copy run directory `run`'s summary into `out` (created; refused if it holds anything) and return `out`."""
    run, out = Path(run), Path(out)
    for needed in (run / "config.yaml", last_checkpoint(run)):
        if not needed.is_file():
            raise SystemExit(f"{run}: not a run directory to archive, it has no {needed.relative_to(run)}")
    if out.exists() and any(out.iterdir()):
        raise SystemExit(f"--out={str(out)!r} is not allowed: it is not empty")
    (out / "csv").mkdir(parents=True, exist_ok=True)
    for record in ("config.yaml", TEACHER_RECORD, UNSEEN_EVALUATION):
        if (run / record).is_file():
            shutil.copyfile(run / record, out / record)
    for metrics in sorted((run / "csv").glob("metrics*.csv")):  # every attempt's file, as read_metrics joins them
        shutil.copyfile(metrics, out / "csv" / metrics.name)
    if (run / EVALUATION).is_file():
        (out / EVALUATION).parent.mkdir(exist_ok=True)
        shutil.copyfile(run / EVALUATION, out / EVALUATION)
    write_json(out / ARCHIVE_RECORD, dict(iterations=completed_iterations(run), source=str(run)))
    return out


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m vitac.runs archive", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    print(f"archived {args.run} in {archive(args.run, args.out)}")


if __name__ == "__main__":
    tool_entry(main)()
