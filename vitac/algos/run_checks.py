"""A training run's values, checked before anything is built or simulated: the `algo`, `envs`, `eval`,
`checkpoint`, `curriculum` and `trainer` groups and the seed. Each refusal names the key, the value and what
is allowed. `vitac.evaluate` checks its own keys with the same helpers (`vitac/utils/checks.py`)."""

from __future__ import annotations

import torch

from vitac.algos.buffer import check_batch_layout
from vitac.algos.curriculum import RandomizationCurriculum
from vitac.algos.dagger import check_dagger
from vitac.algos.kickstart import check_kickstart
from vitac.algos.lr_schedule import make_lr_schedule
from vitac.tasks import import_object
from vitac.utils.checkpoint import resolve_checkpoint
from vitac.utils.checks import (
    accepted_keywords,
    check_flag,
    check_int,
    is_int,
    is_number,
    refuse,
    refuse_non_finite,
    resolve_groups,
    resolve_threads,
)

MAX_SEED = 2**31 - 1  # numpy's and Lightning's seeds end at 2^32 - 1, and environment i is seeded with seed + i

# PPO's keys (conf/algo/ppo.yaml) by kind; the schedule's are checked by building it.
POSITIVE_INTS = ("horizon", "seq_len", "minibatch_size", "mini_epochs")
NON_NEGATIVE_INTS = ("critic_warmup_iterations",)
POSITIVE_NUMBERS = ("lr", "clip", "grad_norm")
NON_NEGATIVE_NUMBERS = ("critic_coef", "entropy_coef", "bounds_loss_coef")
FRACTIONS = ("gamma", "gae_lambda")  # in [0, 1]
FLAGS = ("clip_value", "normalize_input", "normalize_value", "normalize_advantage")
SCHEDULE = ("lr_schedule", "kl_threshold", "lr_schedule_every", "lr_min", "lr_max")


def check_ppo(algo: dict, num_envs: int) -> None:
    """Refuse any out-of-range value of conf/algo/ppo.yaml (as composed), with its key."""
    for name in POSITIVE_INTS:
        check_int(f"algo.{name}", algo[name], 1)
    for name in NON_NEGATIVE_INTS:
        check_int(f"algo.{name}", algo[name], 0)
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
    make_lr_schedule(*(algo[name] for name in SCHEDULE), algo["lr"])
    check_batch_layout(algo["horizon"], num_envs, algo["seq_len"], algo["minibatch_size"])


RUN_KEYS = ("seed", "resume", "row", "critic_ckpt", "freeze_critic", "teacher_ckpt", "init_ckpt", "init_exclude",
            "output_dir")
# Groups not built through `_target_`, and their keys (task: its config class refuses unknown keys itself); the
# other groups' keys are their target's parameters.
PLAIN_GROUPS = {"task": None, "obs": ("name", "modalities"), "preset": ("name",), "logger": ("wandb", "project", "name"),
                "trainer": ("accelerator", "rollout_threads", "update_threads", "deterministic", "iterations",
                            "max_nonfinite_iterations")}
TARGET_GROUPS = ("algo", "envs", "curriculum", "eval", "checkpoint", "fusion", "reg", "head", "critic", "residual",
                 "encoder.image", "encoder.vector")


def check_keys(cfg: dict) -> None:
    """Refuse a key the run would silently ignore (`+foo=1`, `+algo.lr_decay=0.9`), naming it and what is allowed:
    top-level keys, plain groups' keys, and each built group's keys against its target's parameters."""
    allowed = set(RUN_KEYS) | set(PLAIN_GROUPS) | {g.split(".")[0] for g in TARGET_GROUPS}
    for key, value in cfg.items():
        if key not in allowed:
            refuse(key, value, f"one of {sorted(allowed)}")
    for group, keys in PLAIN_GROUPS.items():
        for key, value in (cfg[group].items() if keys else ()):
            if key not in keys:
                refuse(f"{group}.{key}", value, f"one of {list(keys)}")
    for group in TARGET_GROUPS:
        node = cfg
        for part in group.split("."):
            node = node[part]
        if node.get("_target_") is None:  # a group switched off (curriculum=none) takes no keys
            for key, value in node.items():
                if key != "_target_":
                    refuse(f"{group}.{key}", value, f"no keys while {group}._target_ is null (that group is off)")
            continue
        params = accepted_keywords(import_object(node["_target_"]))
        if params is None:
            continue  # a target taking **kwargs it does not pass on to a base class accepts any key
        for key, value in node.items():
            if not key.startswith("_") and key not in params:
                refuse(f"{group}.{key}", value, f"one of {sorted(params)} (the parameters of {node['_target_']})")


def check_run(cfg: dict) -> dict:
    """Every group a training run builds from, checked; returns `envs` with `num_workers: auto` resolved."""
    check_keys(cfg)
    refuse_non_finite(cfg)
    check_flag("freeze_critic", cfg["freeze_critic"])
    check_flag("logger.wandb", cfg["logger"]["wandb"])
    if not isinstance(cfg["init_exclude"], list):
        refuse("init_exclude", cfg["init_exclude"], "a list of parameter-name prefixes")
    if cfg["init_exclude"] and not cfg["init_ckpt"]:  # e.g. a fine-tuning experiment run without its student
        refuse("init_ckpt", cfg["init_ckpt"], f"a checkpoint to start from (init_ckpt=<run>/checkpoints/last.ckpt), "
               f"since init_exclude={cfg['init_exclude']} leaves parts of one out")
    for key in ("init_ckpt", "critic_ckpt"):
        if cfg[key] and not resolve_checkpoint(cfg[key]).is_file():
            raise FileNotFoundError(f"{key}={cfg[key]!r}: no such checkpoint file")
    seed = cfg["seed"]
    if seed is not None and (not is_int(seed) or not 0 <= seed <= MAX_SEED):
        refuse("seed", seed, f"an integer in [0, {MAX_SEED}] or null")
    check_flag("trainer.deterministic", cfg["trainer"]["deterministic"])
    envs = dict(cfg["envs"])
    envs["num_workers"] = resolve_groups(envs["num_envs"], envs["num_workers"], prefix="envs.")
    check_flag("envs.step_in_main", envs["step_in_main"])
    check_int("envs.max_restarts", envs["max_restarts"], 0)
    algo = cfg["algo"]
    for name in ("horizon", "seq_len"):
        check_int(f"algo.{name}", algo[name], 1)
    if algo["_target_"] == "vitac.algos.dagger.DAgger":
        check_dagger({k: v for k, v in algo.items() if not k.startswith("_") and k not in ("horizon", "seq_len")},
                     algo["horizon"], envs["num_envs"], algo["seq_len"])
    else:
        check_ppo(algo, envs["num_envs"])
    if algo["_target_"] == "vitac.algos.kickstart.KickstartPPO":
        check_kickstart(algo.get("imitation_coef", 1.0), algo.get("imitation_iterations", 50))
    check_int("trainer.iterations", cfg["trainer"]["iterations"], 1)
    check_int("trainer.max_nonfinite_iterations", cfg["trainer"]["max_nonfinite_iterations"], 1)
    check_int("eval.every", cfg["eval"]["every"], 1)
    check_int("eval.episodes", cfg["eval"]["episodes"], 1)
    check_int("eval.video_every", cfg["eval"]["video_every"], 0)
    check_int("checkpoint.every_n_epochs", cfg["checkpoint"]["every_n_epochs"], 1)
    check_int("checkpoint.save_top_k", cfg["checkpoint"]["save_top_k"], -1)
    curriculum = {k: v for k, v in cfg["curriculum"].items() if k != "_target_"}
    if cfg["curriculum"].get("_target_"):
        RandomizationCurriculum(**curriculum)  # its constructor refuses a bad value by key
    return envs


def resolve_trainer_threads(rollout_threads, update_threads, deterministic) -> tuple[int, int]:
    """The rollout and update thread counts, `auto` resolved to the usable cores."""
    check_flag("trainer.deterministic", deterministic)
    return (resolve_threads("trainer.rollout_threads", rollout_threads),
            resolve_threads("trainer.update_threads", update_threads))


ACCELERATORS = ("cpu", "gpu", "auto")


def check_accelerator(accelerator: str) -> str:
    """The Lightning accelerator for `trainer.accelerator`, refusing a GPU that torch cannot see."""
    if accelerator not in ACCELERATORS:
        raise ValueError(f"trainer.accelerator={accelerator!r} is not allowed: expected one of {list(ACCELERATORS)}")
    if accelerator == "gpu" and not torch.cuda.is_available():
        raise ValueError("trainer.accelerator='gpu' is not allowed here: torch sees no CUDA device "
                         f"(torch {torch.__version__}); use cpu or auto")
    return accelerator
