"""How evaluated episodes ended: outcome counts and where the peg was, from `vitac.evaluate` JSON reports.

    python tools/outcomes.py docs/data/results/privileged_cpu_stage1_eval_paper.json [more.json ...]

For each report and outcome (inserted, on or above the socket, ...): the number of episodes and the
quartiles of the peg's final horizontal offset from the hole axis (mm), its height above the hole floor
(mm) and its tilt (degrees), as a markdown table.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def quartiles(values) -> str:
    q1, q2, q3 = np.percentile(values, [25, 50, 75])
    return f"{q2:.1f} ({q1:.1f}-{q3:.1f})"


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("reports", type=Path, nargs="+")
    args = parser.parse_args()
    print("| report | outcome | episodes | offset from axis, mm: median (quartiles) | height above floor, mm | tilt, deg |")
    print("|---|---|---|---|---|---|")
    for path in args.reports:
        report = json.loads(path.read_text())
        if "final_peg" not in report:
            raise SystemExit(f"{path}: no 'final_peg' entries (written by an older vitac.evaluate); evaluate again")
        by_outcome: dict[str, list] = {}
        for episode in report["final_peg"]:
            by_outcome.setdefault(episode["outcome"], []).append(episode)
        for outcome, episodes in sorted(by_outcome.items(), key=lambda item: -len(item[1])):
            cells = [quartiles([e[k] for e in episodes]) for k in ("offset_xy_mm", "height_mm", "tilt_deg")]
            print(f"| {path.stem} | {outcome} | {len(episodes)} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
