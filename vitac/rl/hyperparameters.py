"""The `algo` group's values checked before anything is built or simulated: each refusal names the key, the
value and what is allowed. Values that only one component reads (the learning-rate schedule, the curriculum,
the batch layout) are checked by that component's constructor, which train() also runs before simulating."""

from __future__ import annotations

import math
import numbers

from vitac.rl.buffer import check_batch_layout


def _refuse(key: str, value, allowed: str):
    raise ValueError(f"{key}={value!r} is not allowed: expected {allowed}")


def _is_int(value) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _is_number(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)


POSITIVE_INTS = ("num_envs", "horizon", "seq_len", "minibatch_size", "mini_epochs", "iterations", "eval_every",
                 "eval_episodes", "save_every")
POSITIVE_NUMBERS = ("lr", "clip", "grad_norm")
NON_NEGATIVE_NUMBERS = ("critic_coef", "entropy_coef", "bounds_loss_coef")
FRACTIONS = ("gamma", "gae_lambda")  # in [0, 1]
FLAGS = ("step_in_main", "clip_value", "normalize_input", "normalize_value", "normalize_advantage")


def check_algo(algo: dict) -> None:
    """Refuse any out-of-range value of conf/algo/ppo.yaml (as composed), with its key."""
    for name in POSITIVE_INTS:
        if not _is_int(algo[name]) or algo[name] < 1:
            _refuse(f"algo.{name}", algo[name], "a positive integer")
    for name in ("num_workers", "eval_video_every"):
        if not _is_int(algo[name]) or algo[name] < 0:
            _refuse(f"algo.{name}", algo[name], "an integer >= 0")
    if algo["num_workers"] and algo["num_envs"] % algo["num_workers"]:
        _refuse("algo.num_workers", algo["num_workers"], f"0 or a divisor of algo.num_envs={algo['num_envs']}")
    for name in POSITIVE_NUMBERS:
        if not _is_number(algo[name]) or not algo[name] > 0:
            _refuse(f"algo.{name}", algo[name], "a number > 0")
    for name in NON_NEGATIVE_NUMBERS:
        if not _is_number(algo[name]) or algo[name] < 0:
            _refuse(f"algo.{name}", algo[name], "a number >= 0")
    for name in FRACTIONS:
        if not _is_number(algo[name]) or not 0 <= algo[name] <= 1:
            _refuse(f"algo.{name}", algo[name], "a number in [0, 1]")
    for name in FLAGS:
        if not isinstance(algo[name], bool):
            _refuse(f"algo.{name}", algo[name], "true or false")
    check_batch_layout(algo["horizon"], algo["num_envs"], algo["seq_len"], algo["minibatch_size"])


def check_seed(seed) -> None:
    """A run's seed: an integer, or null to leave the generators unseeded."""
    if seed is not None and not _is_int(seed):
        _refuse("seed", seed, "an integer or null")
