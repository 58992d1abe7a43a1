"""Evaluate a checkpoint: `python -m vitac.evaluate ckpt=outputs/.../checkpoints/last.ckpt [episodes=100]`.

Prints (and writes next to the checkpoint) a JSON report: success rate with its 95% Wilson interval
and the steps-to-succeed distribution, on held-out seeded episodes with the deterministic policy (the
mean action, as rl_games evaluates), or with sampled actions (`deterministic=false`).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import hydra
import torch
from omegaconf import DictConfig, OmegaConf

from vitac.algos.evaluation import run_episodes
from vitac.envs.vector_env import TaskVectorEnv
from vitac.run_config import build_policy_from_config, task_settings
from vitac.tasks import make_task_config
from vitac.utils.checkpoint import load_checkpoint
from vitac.utils.checks import check_flag, check_int, resolve_groups
from vitac.utils.records import write_json

log = logging.getLogger(__name__)


def load_policy(ckpt: str | Path):
    """Rebuild the policy from the resolved config stored in the checkpoint, then load its weights."""
    checkpoint = load_checkpoint(ckpt)
    cfg = OmegaConf.create(checkpoint["vitac_config"])
    settings = task_settings(cfg)
    task_config = make_task_config(settings)
    if all(task_config.observation_specs()[k].kind != "image" for k in cfg.obs.modalities):
        # Runs from before fusion and reg were checked against obs recorded the defaults (cmt, sym) beside
        # image-free observations, where neither was ever built: the same policy as naive and none.
        cfg.fusion, cfg.reg.lambda_sym = {"_target_": "vitac.models.fusion.NaiveFusion", "_partial_": True}, 0.0
    policy = build_policy_from_config(cfg, task_config)
    weights = {k[len("policy."):]: v for k, v in checkpoint["state_dict"].items() if k.startswith("policy.")}
    policy.load_state_dict(weights)
    return policy, cfg, settings


def evaluate(ckpt: str, episodes: int, num_envs: int, num_workers: int | str, seed: int, out: str | None = None,
             randomization_scale: float | None = None, deterministic: bool = True,
             socket_obs_noise: float | None = None, randomize_only: list | None = None,
             step_in_main: bool = True) -> dict:
    """Success statistics of the checkpoint's policy, deterministic (mean action) unless `deterministic` is
    false; the paper's randomization unless `randomization_scale` shrinks it (e.g. to the level a
    curriculum reached) or `socket_obs_noise` replaces the socket observation noise (0: what the noise costs);
    `randomize_only` (names from RANDOMIZED_FACTORS) randomizes those factors alone, every other at its midpoint."""
    check_int("episodes", episodes, 1)
    num_workers = resolve_groups(num_envs, num_workers, prefix="")
    check_int("seed", seed, 0)
    check_flag("deterministic", deterministic)
    check_flag("step_in_main", step_in_main)
    policy, cfg, settings = load_policy(ckpt)
    settings = dict(settings, randomization=dict(settings["randomization"]))
    if randomization_scale is not None:
        settings["randomization"]["scale"] = randomization_scale
    if socket_obs_noise is not None:
        settings["randomization"]["socket_obs_noise"] = socket_obs_noise
    if randomize_only is not None:
        task_config = make_task_config(settings)
        settings["randomization"] = task_config.randomization.only(list(randomize_only)).__dict__
    make_task_config(settings)  # refuse a bad override before any simulation
    # One thread for batch-4 inference: the env workers need the cores. Beside a training run, 16 episodes took
    # 203 s with torch's default 2 threads (OpenMP spinning against the workers) and 25 s with 1.
    torch.set_num_threads(1)
    envs = TaskVectorEnv(settings, num_envs=num_envs, num_workers=num_workers, seed=seed, step_in_main=step_in_main)
    try:
        summary = run_episodes(policy, envs, episodes, seed, deterministic=deterministic, progress=True)
    finally:
        envs.close()
    report = dict(ckpt=str(ckpt), preset=cfg.preset.name, obs=cfg.obs.name, seed=seed,
                  randomization_scale=settings["randomization"]["scale"],
                  socket_obs_noise=settings["randomization"].get("socket_obs_noise"),
                  randomize_only=list(randomize_only) if randomize_only is not None else None,
                  policy="deterministic" if deterministic else "stochastic",
                  **{k: v for k, v in summary.items() if k != "episodes_detail"},
                  final_keypoint_distance_mm=[round(1000 * e["keypoint_distance"], 3) for e in summary["episodes_detail"]],
                  # How each episode ended, as the task's outcome() reports it (SI units: m, rad).
                  final_state=[{k: round(v, 6) if isinstance(v, float) else v for k, v in e.items()
                                if k not in ("success", "steps_to_success", "keypoint_distance")}
                               for e in summary["episodes_detail"]])
    only = "" if randomize_only is None else ".only-" + "-".join(randomize_only)
    target = Path(out) if out else Path(ckpt).with_suffix(f".eval{only}.json")
    write_json(target, report)
    return report


@hydra.main(version_base="1.3", config_path="../conf", config_name="evaluate")
def main(cfg: DictConfig) -> None:
    if not cfg.ckpt:
        raise ValueError("ckpt=None is not allowed: pass ckpt=<run dir>/checkpoints/last.ckpt")
    report = evaluate(cfg.ckpt, cfg.episodes, cfg.num_envs, cfg.num_workers, cfg.seed, cfg.out,
                      cfg.randomization_scale, cfg.deterministic, cfg.socket_obs_noise, cfg.randomize_only,
                      cfg.step_in_main)
    print(json.dumps({k: v for k, v in report.items() if k not in ("steps_to_success", "final_keypoint_distance_mm", "final_state")},
                     indent=2))


if __name__ == "__main__":
    main()
