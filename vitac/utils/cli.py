"""What the tools share on the command line: argparse types for their counts (a bad value is refused by
argparse, naming the flag, before any work) and for their outputs (probed before the work that fills them), a
one-line refusal of a file they cannot read or write, and a quiet stop when their output is piped into a reader
that closes early."""

from __future__ import annotations

import argparse
import functools
import os
import re
import signal
import sys
from contextlib import contextmanager
from pathlib import Path

from vitac.utils.records import check_writable_dir


def _checked(convert, kind: str, accept, allowed: str):
    def parse(text: str):
        try:
            value = convert(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {kind}") from None
        if not accept(value):
            raise argparse.ArgumentTypeError(f"{value} is not allowed: expected {allowed}")
        return value

    parse.__name__ = allowed  # argparse names the type in its messages
    return parse


def int_at_least(minimum: int):
    """An argparse `type` accepting integers >= `minimum`."""
    return _checked(int, "an integer", lambda value: value >= minimum, f"an integer >= {minimum}")


def number_above(bound: float):
    """An argparse `type` accepting numbers > `bound`."""
    return _checked(float, "a number", lambda value: value > bound, f"a number > {bound}")


def _probe(text: str, folder: Path) -> None:
    try:
        check_writable_dir(folder)
    except OSError as err:
        raise argparse.ArgumentTypeError(f"{text} is not allowed: the folder {folder} cannot be created or written "
                                         f"({err.strerror or err})") from None


def output_file(text: str) -> Path:
    """An argparse `type` for a file written at the end (a benchmark's `--json`, a figure): its folder is created
    and a file made and removed there now, so an unwritable path is refused, naming the flag, before minutes of
    work that could not be saved."""
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} is not allowed: it is a directory; expected a file name")
    _probe(text, path.parent)
    return path


def output_dir(text: str) -> Path:
    """An argparse `type` for a folder written at the end (a report's `--out`), probed as `output_file` is."""
    path = Path(text)
    _probe(text, path)
    return path


def stop_quietly_when_the_reader_closes() -> None:
    """End at once, without a BrokenPipeError traceback, when stdout's reader goes away (`tool ... | head`),
    as Unix tools do; Python otherwise ignores SIGPIPE and fails on its next write or at exit."""
    if hasattr(signal, "SIGPIPE"):  # POSIX only
        signal.signal(signal.SIGPIPE, signal.SIG_DFL)


@contextmanager
def refuse_bad_files():
    """Within it, a missing, corrupt or unwritable file (the OSError or ValueError that names it) ends the tool
    with that message (a refusal, see `tool_entry`) instead of a traceback."""
    try:
        yield
    except (OSError, ValueError) as err:
        raise SystemExit(str(err)) from err


def tool_entry(main):
    """A tool's command-line entry: a refusal, raised as SystemExit(<message>) (a file it cannot read, a value it does
    not take), prints `error: <message>` and exits with status 2, as argparse does for a bad flag; other exits and
    errors pass unchanged. Called as a function (tests, other tools), `main` raises the SystemExit itself."""

    @functools.wraps(main)
    def run(*args, **kwargs):
        try:
            return main(*args, **kwargs)
        except SystemExit as err:
            if not isinstance(err.code, str):
                raise
            exit_refused(err.code)

    return run


def exit_refused(message: str) -> None:
    """End the command as every refusal ends it: `error: <message>` on one line on stderr, exit status 2."""
    print(f"error: {message}", file=sys.stderr, flush=True)
    sys.exit(2)


# A refusal names what it refuses first: `key=value ...` (vitac.utils.checks.refuse and every check of a run's values).
REFUSAL = re.compile(r"^[+\w.\[\]/-]+=")


def refusals_in_one_line(main):
    """An entry point whose refusals of a value print `error: <key>=<value> ...: <what is allowed>` on one line and
    exit with status 2, without the stack; any other error (a crash) keeps its stack, and HYDRA_FULL_ERROR=1
    shows the stack of a refusal too."""

    @functools.wraps(main)
    def run(*args, **kwargs):
        try:
            return main(*args, **kwargs)
        except (ValueError, FileNotFoundError) as err:
            if os.environ.get("HYDRA_FULL_ERROR") == "1" or not REFUSAL.match(str(err)):
                raise
            exit_refused(str(err))

    return run


OUTPUT_FOLDER_KEYS = ("hydra.run.dir", "hydra.sweep.dir", "hydra.sweep.subdir")


def refuse_unusable_output_folders(argv: list[str]) -> None:
    """Hydra makes its output folder before an entry point's code runs, and a name the file system cannot hold then
    fails as an OSError naming no key: a Hydra entry point checks its command line's output folders first, and
    refuses one on a line, with status 2."""
    name_max, path_max = os.pathconf("/", "PC_NAME_MAX"), os.pathconf("/", "PC_PATH_MAX")
    for arg in argv:
        key, sep, value = arg.partition("=")
        if not sep or key.lstrip("+~") not in OUTPUT_FOLDER_KEYS:
            continue
        too_long = [part for part in Path(value).parts if len(os.fsencode(part)) > name_max]
        room = 200  # for what a run writes inside it (checkpoints/iter_00050.ckpt, wandb/...)
        if too_long:
            problem = f"a folder name of {len(os.fsencode(too_long[0]))} bytes is not allowed: at most {name_max}"
        elif len(os.fsencode(os.path.abspath(value))) + room > path_max:
            problem = f"a path this long is not allowed: at most {path_max - room} bytes, leaving room for the run's files"
        else:
            continue
        shown = value if len(value) <= 80 else f"{value[:40]}...{value[-20:]}"
        exit_refused(f"{key}={shown}: {problem}")
