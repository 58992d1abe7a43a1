"""JSON records written whole: a tool's results with the command line that reproduces them, and evaluation
reports, each replacing its file only once completely written."""

from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path


def write_json(path: Path, data) -> None:
    """Write `data` as indented JSON to `path` through a temporary file beside it, renamed over `path` at the end:
    a run killed while writing leaves the previous file (or none), never half a report."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps(data, indent=2) + "\n"
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_record(path: Path, **fields) -> None:
    """Write `fields` plus `command` (this process's command line, as a tool in tools/ is run) to `path`."""
    command = " ".join([f"python tools/{Path(sys.argv[0]).name}", *sys.argv[1:]])
    write_json(path, dict(fields, command=command))
