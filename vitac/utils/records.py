"""Benchmark records: a tool's results written as JSON together with the command line that reproduces them."""

from __future__ import annotations

import json
import sys
from pathlib import Path


def write_record(path: Path, **fields) -> None:
    """Write `fields` plus `command` (this process's command line, as a tool in tools/ is run) to `path`."""
    command = " ".join([f"python tools/{Path(sys.argv[0]).name}", *sys.argv[1:]])
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(dict(fields, command=command), indent=2) + "\n")
