"""The `algo` group's values, the trainer's threads and the seed, checked before anything is built or simulated:
each refusal names the key, the value and what is allowed. Values that only one component reads (the
learning-rate schedule, the curriculum) are checked by that component's constructor, which train() also runs
before simulating. `vitac.evaluate` checks its own keys with the same helpers (`vitac/utils/checks.py`)."""

from __future__ import annotations

from vitac.rl.buffer import check_batch_layout
from vitac.utils.checks import check_flag, check_groups, check_int, is_int, is_number, refuse, resolve_threads

POSITIVE_INTS = ("horizon", "seq_len", "minibatch_size", "mini_epochs", "iterations", "eval_every",
                 "eval_episodes", "save_every")
POSITIVE_NUMBERS = ("lr", "clip", "grad_norm")
NON_NEGATIVE_NUMBERS = ("critic_coef", "entropy_coef", "bounds_loss_coef")
FRACTIONS = ("gamma", "gae_lambda")  # in [0, 1]
FLAGS = ("step_in_main", "clip_value", "normalize_input", "normalize_value", "normalize_advantage")


def check_algo(algo: dict) -> None:
    """Refuse any out-of-range value of conf/algo/ppo.yaml (as composed), with its key."""
    check_groups(algo["num_envs"], algo["num_workers"])
    for name in POSITIVE_INTS:
        check_int(f"algo.{name}", algo[name], 1)
    check_int("algo.eval_video_every", algo["eval_video_every"], 0)
    for name in POSITIVE_NUMBERS:
        if not is_number(algo[name]) or not algo[name] > 0:
            refuse(f"algo.{name}", algo[name], "a number > 0")
    for name in NON_NEGATIVE_NUMBERS:
        if not is_number(algo[name]) or algo[name] < 0:
            refuse(f"algo.{name}", algo[name], "a number >= 0")
    for name in FRACTIONS:
        if not is_number(algo[name]) or not 0 <= algo[name] <= 1:
            refuse(f"algo.{name}", algo[name], "a number in [0, 1]")
    for name in FLAGS:
        check_flag(f"algo.{name}", algo[name])
    check_batch_layout(algo["horizon"], algo["num_envs"], algo["seq_len"], algo["minibatch_size"])


def check_seed(seed) -> None:
    """A run's seed: an integer, or null to leave the generators unseeded."""
    if seed is not None and not is_int(seed):
        refuse("seed", seed, "an integer or null")


def resolve_trainer_threads(rollout_threads, update_threads, deterministic) -> tuple[int, int]:
    """The rollout and update thread counts, `auto` resolved to the usable cores."""
    check_flag("trainer.deterministic", deterministic)
    return (resolve_threads("trainer.rollout_threads", rollout_threads),
            resolve_threads("trainer.update_threads", update_threads))
