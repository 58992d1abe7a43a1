"""Success by randomized factor: which start conditions do a policy's failures come from?

    python -m vitac.runs outcomes <run>/checkpoints/last.eval.json --by-factor [--outcome "stuck part-way in the hole"]

A `vitac.evaluate` report lists, per episode, the values its randomization drew (`episode_factors`: socket pose
and observation noise, hand pose, grasp depth and in-hand tilt, pad and joint parameters). For each of them
(each axis of a vector, and the magnitude of a value drawn around zero) this prints the success rate in each
quartile of its values, the median value in the episodes that ended as the chosen outcome (default: every
failure) and in the others, and the two-sided Mann-Whitney U p-value of that difference, most telling first.
A factor whose p-value is small and whose quartiles' success rates fall steadily is where the failures live.
"""

from __future__ import annotations

import numpy as np

AXES = "xyz"


def factor_columns(episode_factors: list[dict]) -> dict[str, np.ndarray]:
    """One column of values per scalar: a factor's own, or `name.x`, `.y`, `.z` for a vector; beside a column
    holding both signs, its magnitude `abs(name)` (a tilt either way about zero is one condition)."""
    names = list(dict.fromkeys(k for e in episode_factors for k in e))
    columns = {}
    for name in names:
        values = np.array([e[name] for e in episode_factors], float)
        parts = {name: values} if values.ndim == 1 else {
            f"{name}.{AXES[i] if values.shape[1] <= 3 else i}": values[:, i] for i in range(values.shape[1])}
        for key, column in parts.items():
            columns[key] = column
            if column.min() < 0 < column.max():
                columns[f"abs({key})"] = np.abs(column)
    return columns


def quartile_success(values: np.ndarray, success: np.ndarray) -> list[float]:
    """Success rate (%) of the episodes in each quartile of `values` (ties kept together by ranking)."""
    order = np.argsort(values, kind="stable")
    return [100.0 * success[part].mean() for part in np.array_split(order, 4) if len(part)]


def factor_table(report: dict, outcome: str | None = None) -> str:
    """The markdown table described in the module docstring, for one report."""
    from scipy.stats import mannwhitneyu

    factors = report.get("episode_factors")
    if not factors or not any(factors):
        raise SystemExit("--by-factor: the report lists no episode_factors (written by an older vitac.evaluate); "
                         "evaluate again")
    success = np.array(report["episode_success"], bool)
    if outcome is None:
        chosen, label = ~success, "failed"
    else:
        outcomes = [e["outcome"] for e in report["final_state"]]
        if outcome not in outcomes:
            raise SystemExit(f"--outcome={outcome!r}: no episode of the report ended so; its outcomes are "
                             f"{sorted(set(outcomes))}")
        chosen, label = np.array([o == outcome for o in outcomes]), outcome
    rows = []
    for name, values in factor_columns(factors).items():
        inside, outside = values[chosen], values[~chosen]
        p = mannwhitneyu(inside, outside).pvalue if len(inside) and len(outside) and np.ptp(values) > 0 else 1.0
        rates = " / ".join(f"{r:.0f}" for r in quartile_success(values, success))
        medians = [f"{np.median(part):.4g}" if len(part) else "" for part in (inside, outside)]
        rows.append((p, f"| {name} | {rates} | {medians[0]} | {medians[1]} | {p:.3g} |"))
    head = (f"{int(chosen.sum())} of {len(success)} episodes {label}\n\n"
            f"| factor | success % by quartile, low to high | median, {label} | median, the others "
            f"| Mann-Whitney p |\n|---|---|---|---|---|")
    return "\n".join([head] + [row for _, row in sorted(rows, key=lambda r: r[0])])
