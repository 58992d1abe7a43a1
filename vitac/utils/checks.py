"""Refusing a configuration value: every refusal names the key, the value and what is allowed."""

from __future__ import annotations

import inspect
import math
import numbers
import os


class ConfigError(ValueError):
    """A configuration value is not allowed; the message names the key, the value and what is allowed."""


def refuse(key: str, value, allowed: str):
    raise ConfigError(f"{key}={value!r} is not allowed: expected {allowed}")


def is_int(value) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def is_number(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)


def refuse_non_finite(values, key: str = "") -> None:
    """Refuse any NaN or infinite number anywhere in a nested config (dicts and lists), naming its key: no setting
    of this project gives infinity a meaning, and one NaN trains to the end or diverges the physics mid-run."""
    if isinstance(values, dict):
        for name, value in values.items():
            refuse_non_finite(value, f"{key}.{name}" if key else str(name))
    elif isinstance(values, (list, tuple)):
        for i, value in enumerate(values):
            refuse_non_finite(value, f"{key}[{i}]")
    elif isinstance(values, numbers.Real) and not isinstance(values, bool) and not math.isfinite(values):
        refuse(key, values, "a finite number")


def check_int(key: str, value, minimum: int) -> None:
    if not is_int(value) or value < minimum:
        refuse(key, value, "a positive integer" if minimum == 1 else f"an integer >= {minimum}")


def check_flag(key: str, value, auto: bool = False) -> None:
    """A boolean; or with `auto`, also the string "auto" (the code picks, e.g. from the hardware)."""
    if not isinstance(value, bool) and not (auto and value == "auto"):
        refuse(key, value, "true, false or auto" if auto else "true or false")


def usable_cores() -> int:
    """The cores this process may run on (its affinity, which a container or `taskset` narrows)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def check_groups(num_envs: int, num_workers: int, prefix: str = "envs.") -> None:
    """Environments split into equal worker groups."""
    check_int(f"{prefix}num_envs", num_envs, 1)
    if not is_int(num_workers) or num_workers < 0:
        refuse(f"{prefix}num_workers", num_workers, "an integer >= 0 or auto")
    if num_workers and num_envs % num_workers:
        refuse(f"{prefix}num_workers", num_workers, f"0 or a divisor of {prefix}num_envs={num_envs}")


def resolve_groups(num_envs: int, num_workers, prefix: str = "envs.") -> int:
    """`num_workers` checked, or for `auto` the most environment groups the usable cores step at once: the
    largest divisor of `num_envs` not above them (the same trajectories for any split; only the speed differs)."""
    if num_workers == "auto":
        check_int(f"{prefix}num_envs", num_envs, 1)
        cores = usable_cores()
        num_workers = max(d for d in range(1, min(num_envs, cores) + 1) if num_envs % d == 0)
    check_groups(num_envs, num_workers, prefix)
    return num_workers


def resolve_threads(key: str, threads) -> int:
    """A torch thread count checked, or for `auto` the usable cores."""
    if threads == "auto":
        return usable_cores()
    if not is_int(threads) or threads < 1:
        refuse(key, threads, "a positive integer or auto")
    return threads


def check_widths(key: str, value, length: int | None = None) -> None:
    """A list of positive integers (layer widths or sizes), of `length` items when given."""
    if (not isinstance(value, (list, tuple)) or not all(is_int(v) and v >= 1 for v in value)
            or (length is not None and len(value) != length)):
        refuse(key, value, f"a list of {length or 'any number of'} positive integers")


def accepted_keywords(target) -> set | None:
    """The keyword arguments `target` accepts: its own and, for a class whose constructor passes **kwargs on to its
    base class's, that one's too; None when it accepts any."""
    names = set()
    for owner in target.__mro__ if isinstance(target, type) else (target,):
        if isinstance(target, type) and "__init__" not in vars(owner):
            continue
        params = inspect.signature(owner).parameters
        names |= {n for n, p in params.items() if p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL)}
        if not any(p.kind is p.VAR_KEYWORD for p in params.values()):
            return names
    return None
