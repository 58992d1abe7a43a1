"""Read training runs and their evaluations: `python -m vitac.runs <command> ...` (`--help` after a command).

    python -m vitac.runs plot <run>/csv/metrics.csv [<resumed run>/csv/metrics.csv] --out curves.png
    python -m vitac.runs compare --run "seed 0=<run>/csv/metrics.csv" --run "seed 1=..." --out runs.png
    python -m vitac.runs summary <run>/csv/metrics.csv            # env steps/s, learning rate, KL, success
    python -m vitac.runs outcomes <run>/checkpoints/last.eval.json [--paired | --pooled]
    python -m vitac.runs log-std <run>/checkpoints/last.ckpt      # is the action noise stuck at its bound?
    python -m vitac.runs status outputs/table1 [--seeds 0 1 2]    # a sweep's cells: done, partial, missing
    python -m vitac.runs archive <run> --out docs/data/table1_runs/<name>  # a run's summary to commit, read as the run
"""

from __future__ import annotations

import sys
from importlib import import_module

from vitac.utils.cli import tool_entry

COMMANDS = {"plot": "vitac.analysis.curves", "compare": "vitac.analysis.compare", "summary": "vitac.analysis.summary",
            "outcomes": "vitac.analysis.outcomes", "log-std": "vitac.analysis.log_std", "status": "vitac.analysis.status",
            "archive": "vitac.analysis.archive"}


def main(argv=None) -> None:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] in (["-h"], ["--help"]):
        print(__doc__)
        return
    if not argv or argv[0] not in COMMANDS:
        given = repr(argv[0]) if argv else "nothing"
        raise SystemExit(f"{__doc__}\ncommand={given} is not allowed: expected one of {list(COMMANDS)}")
    import_module(COMMANDS[argv[0]]).main(argv[1:])


if __name__ == "__main__":
    tool_entry(main)()
