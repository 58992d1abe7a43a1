"""Files written and read whole: JSON records (a tool's results with the command line that reproduces them,
evaluation reports), each replacing its file only once completely written; and the reading side, which
refuses a file it cannot parse with its path instead of a traceback."""

from __future__ import annotations

import csv
import json
import os
import platform
import sys
import tempfile
from pathlib import Path

import yaml

from vitac.utils.checks import usable_cores


def temporary_beside(path: Path) -> tuple[int, str]:
    """An open temporary file in `path`'s directory, to be renamed over `path` once written whole; with the
    permissions a plainly created file gets (mkstemp's are 0600, which would hide results from collaborators)."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    umask = os.umask(0o022)  # reading the umask means setting it; restored at once
    os.umask(umask)
    os.fchmod(fd, 0o666 & ~umask)
    return fd, tmp


def check_writable_dir(folder: Path) -> None:
    """Create `folder` if needed and make and remove a file there, so a path that could not take a tool's output
    raises its OSError now rather than after the work that fills it."""
    folder.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryFile(dir=folder):
        pass


def write_json(path: Path, data) -> None:
    """Write `data` as indented JSON to `path` through a temporary file beside it, renamed over `path` at the end:
    a run killed while writing leaves the previous file (or none), never half a report."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps(data, indent=2) + "\n"
    fd, tmp = temporary_beside(path)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def describe_cpu(cpuinfo: Path = Path("/proc/cpuinfo")) -> dict:
    """The CPU a record was measured on: its model, the cores this process may use, and its bfloat16 extensions
    (AVX-512 BF16, AMX), which decide how fast the image policy's convolutions run. Machines of one kind differ."""
    model, flags = platform.processor() or platform.machine(), set()
    try:
        for line in cpuinfo.read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name":
                model = value.strip()
            elif key.strip() == "flags":
                flags = set(value.split())
    except OSError:  # not Linux: the model from platform, no flags
        pass
    return dict(model=model, cores=usable_cores(), bfloat16=sorted(flags & {"avx512_bf16", "amx_bf16"}))


def write_record(path: Path, **fields) -> None:
    """Write `fields` plus `command` (this process's command line, as a benchmark in benchmarks/ is run) and
    `cpu` (describe_cpu) to `path`."""
    command = " ".join([f"python benchmarks/{Path(sys.argv[0]).name}", *sys.argv[1:]])
    write_json(path, dict(fields, command=command, cpu=describe_cpu()))


def read_whole(path: Path, parse, what: str = "", hint: str = ""):
    """`parse` of the open file; a file it cannot read (missing, cut short, not text, not the format) stops the
    tool with a message naming the file, `what` it should have been and a `hint`, before anything is printed."""
    try:
        with open(path, newline="") as f:
            return parse(f)
    except (OSError, UnicodeDecodeError, ValueError, csv.Error, yaml.YAMLError) as err:
        as_what = f" as {what}" if what else ""
        raise SystemExit(f"{path}: cannot be read{as_what} ({type(err).__name__}: {err}){hint}") from err
