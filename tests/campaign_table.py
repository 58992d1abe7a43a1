"""docs/reliability.md's fault-campaign table, rendered from the campaign's own tallies.

The slow campaign (`python -m pytest -m slow -s tests/test_fault_campaign.py`) records each tally in
docs/data/fault_campaign.json and rewrites the table; `python -m tests.campaign_table` rewrites it from the
recorded tallies alone; a default test checks that the page shows exactly what was recorded, so no count in the
table is written by hand."""

from __future__ import annotations

import datetime
import json
import os
import platform
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REPORT = ROOT / "docs" / "data" / "fault_campaign.json"
PAGE = ROOT / "docs" / "reliability.md"
BEGIN = "<!-- fault campaign table: rendered by tests/campaign_table.py from docs/data/fault_campaign.json -->"
END = "<!-- end of the fault campaign table -->"

# Each campaign's row: the fault, how often, what survived, what was lost; {fields} come from its tally.
ROWS = {
    "sigkills": ("SIGKILL to a training job (its process group), then `resume=auto`: every other kill at a random moment, "
                 "the rest the instant a new `last.ckpt` lands (an iteration's end)", "{kills}, one run",
                 "every `last.ckpt` loaded whole and held every iteration finished before the kill but the one in "
                 "progress; the run ended with iterations 1-{iterations} all in its metrics, none twice",
                 "at most the iteration in progress, each time"),
    "truncated_checkpoints": ("a training checkpoint (optimizer, environment and RNG states) cut at a random length",
                              "{damages}", "all {refused} refused (`is not a readable vitac checkpoint`)", "nothing read"),
    "bit_flips": ("one random bit flipped anywhere in that checkpoint", "{damages}",
                  "{refused} refused; {unchanged} read back with every value equal to the original (a bit in a zip "
                  "header's padding changes no value)", "nothing read as other values"),
    "worker_kills": ("SIGKILL to a random environment worker at a random step", "{kills} (+1)",
                     "each worker replaced; its 2 environments' episodes ended as truncations (`environment worker "
                     "restarted`), the other worker's went on, observations finite; kill {kills_plus_one}, past "
                     "`envs.max_restarts={kills}`, stopped the run naming the process", "the cut-off episodes, counted"),
}


def record(campaign: str, **tally) -> None:
    """Keep a campaign's tally (with the date and machine) and rewrite the page's table."""
    report = json.loads(REPORT.read_text()) if REPORT.exists() else {}
    report[campaign] = dict(tally, date=datetime.date.today().isoformat(), machine=machine())
    REPORT.write_text(json.dumps(report, indent=2, sort_keys=True) + "\n")
    write_page(report)


def machine() -> str:
    """The CPU's model name and core count, as /proc/cpuinfo gives it (the architecture elsewhere)."""
    cpuinfo = Path("/proc/cpuinfo")
    names = [line.split(":", 1)[1].strip() for line in cpuinfo.read_text().splitlines()
             if line.startswith("model name")] if cpuinfo.exists() else []
    return f"{names[0] if names else platform.machine()}, {os.cpu_count()} cores"


def render(report: dict) -> str:
    """The table's markdown: a row per recorded campaign, in ROWS' order, with its date and machine, and the bad
    configuration values the default run tries (counted from tests/test_faults.py as it is)."""
    from tests.test_faults import BAD_VALUES

    lines = ["| fault injected | times | what survived | lost | run |", "|---|---|---|---|---|"]
    for campaign, (fault, times, survived, lost) in ROWS.items():
        if campaign in report:
            tally = dict(report[campaign], kills_plus_one=report[campaign].get("kills", 0) + 1)
            cells = [fault, times.format(**tally), survived.format(**tally), lost, f"{tally['date']}, {tally['machine']}"]
            lines.append("| " + " | ".join(cells) + " |")
    lines.append(f"| bad config values | {len(BAD_VALUES)} | each refused naming its key before any environment started "
                 "(`test_a_bad_value_is_refused_by_its_key_before_anything_is_built`) | | every default test run |")
    return "\n".join(lines)


def table_on_page(text: str) -> str:
    if BEGIN not in text or END not in text:
        raise ValueError(f"{PAGE} has no fault campaign table between {BEGIN!r} and {END!r}")
    return text.split(BEGIN, 1)[1].split(END, 1)[0].strip()


def write_page(report: dict) -> None:
    text = PAGE.read_text()
    table_on_page(text)  # refuses a page without the markers
    before, rest = text.split(BEGIN, 1)
    PAGE.write_text(f"{before}{BEGIN}\n{render(report)}\n{END}{rest.split(END, 1)[1]}")


if __name__ == "__main__":
    write_page(json.loads(REPORT.read_text()))
    print(f"{PAGE}: the fault campaign table rewritten from {REPORT}")
