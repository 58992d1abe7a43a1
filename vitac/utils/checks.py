"""Refusing a configuration value: every refusal names the key, the value and what is allowed."""

from __future__ import annotations

import math
import numbers


class ConfigError(ValueError):
    """A configuration value is not allowed; the message names the key, the value and what is allowed."""


def refuse(key: str, value, allowed: str):
    raise ConfigError(f"{key}={value!r} is not allowed: expected {allowed}")


def is_int(value) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def is_number(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)


def check_int(key: str, value, minimum: int) -> None:
    if not is_int(value) or value < minimum:
        refuse(key, value, "a positive integer" if minimum == 1 else f"an integer >= {minimum}")


def check_flag(key: str, value) -> None:
    if not isinstance(value, bool):
        refuse(key, value, "true or false")


def check_groups(num_envs: int, num_workers: int, prefix: str = "algo.") -> None:
    """Environments split into equal worker groups."""
    check_int(f"{prefix}num_envs", num_envs, 1)
    check_int(f"{prefix}num_workers", num_workers, 0)
    if num_workers and num_envs % num_workers:
        refuse(f"{prefix}num_workers", num_workers, f"0 or a divisor of {prefix}num_envs={num_envs}")
