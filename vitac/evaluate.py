"""Evaluate a policy: `python -m vitac.evaluate ckpt=outputs/.../checkpoints/last.ckpt [episodes=100]`, or the task's
scripted oracle or uniform random actions: `python -m vitac.evaluate policy=oracle|random [task.peg_size=8]`.

Prints (and writes next to the checkpoint) a JSON report: success rate with its 95% Wilson interval
and the steps-to-succeed distribution, on held-out seeded episodes with the deterministic policy (the
mean action, as rl_games evaluates), or with sampled actions (`deterministic=false`).
"""

from __future__ import annotations

import json
import logging
import sys
from pathlib import Path

import hydra
import numpy as np
import torch
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf
from tqdm.auto import tqdm

from vitac.algos.evaluation import run_episodes, summarize
from vitac.envs.gym_env import TaskEnv
from vitac.envs.vector_env import TaskVectorEnv
from vitac.run_config import load_policy
from vitac.tasks import make_task_config
from vitac.utils.checks import check_flag, check_int, is_int, refuse, refuse_non_finite, resolve_groups
from vitac.utils.cli import refusals_in_one_line, refuse_unusable_output_folders
from vitac.utils.quiet import quiet_third_party
from vitac.utils.records import write_json

log = logging.getLogger(__name__)


def evaluate(ckpt: str, episodes: int, num_envs: int, num_workers: int | str, seed: int, out: str | None = None,
             randomization_scale: float | None = None, deterministic: bool = True,
             socket_obs_noise: float | None = None, randomize_only: list | None = None,
             step_in_main: bool = True, task_overrides: dict | None = None) -> dict:
    """Success statistics of the checkpoint's policy, deterministic (mean action) unless `deterministic` is
    false; the paper's randomization unless `randomization_scale` shrinks it (e.g. to the level a
    curriculum reached) or `socket_obs_noise` replaces the socket observation noise (0: what the noise costs);
    `randomize_only` (names from RANDOMIZED_FACTORS) randomizes those factors alone, every other at its midpoint;
    `task_overrides` replaces keys of the checkpoint's task settings (e.g. the simulation's noslip_iterations)."""
    check_int("episodes", episodes, 1)
    num_workers = resolve_groups(num_envs, num_workers, prefix="")
    check_seed(seed, episodes)
    check_flag("deterministic", deterministic)
    refuse_non_finite(dict(randomization_scale=randomization_scale, socket_obs_noise=socket_obs_noise,
                           task_overrides=task_overrides or {}))
    check_flag("step_in_main", step_in_main)
    policy, cfg, settings = load_policy(ckpt)
    settings = dict(settings, randomization=dict(settings["randomization"]), measure_force_balance=True)
    settings.update(task_overrides or {})  # an override may name any key, measure_force_balance included
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
                  task_overrides=dict(task_overrides or {}),
                  policy="deterministic" if deterministic else "stochastic",
                  **episode_statistics(summary))
    only = "" if randomize_only is None else ".only-" + "-".join(randomize_only)
    target = Path(out) if out else Path(ckpt).with_suffix(f".eval{only}.json")
    write_json(target, report)
    return report


def check_seed(seed, episodes: int) -> None:
    """Episode k is seeded seed + k, and numpy's seeds end at 2^32 - 1."""
    if not is_int(seed) or not 0 <= seed <= 2**32 - 1 - episodes:
        refuse("seed", seed, f"an integer in [0, 2^32 - 1 - episodes] = [0, {2**32 - 1 - episodes}]")


def episode_statistics(summary: dict) -> dict:
    """The report's success statistics, how each episode ended, as the task's outcome() reports it (m, rad), and
    what each started from: the values its randomization drew, by factor (`vitac.runs outcomes --by-factor`), and
    how balanced the pads' fields were (vitac/sim/balance.py; `vitac.runs outcomes --paired` compares them)."""
    detail = summary["episodes_detail"]
    return dict(**{k: v for k, v in summary.items() if k != "episodes_detail"},
                episode_success=[int(e["success"]) for e in detail],
                final_keypoint_distance_mm=[round(1000 * e["keypoint_distance"], 3) for e in detail],
                final_state=[{k: round(v, 6) if isinstance(v, float) else v for k, v in e.items()
                              if k not in ("success", "steps_to_success", "keypoint_distance", "episode", "factors",
                                           "force_balance")}
                             for e in detail],
                force_balance=[{k: v if v is None else round(v, 6) for k, v in e.get("force_balance", {}).items()}
                               for e in detail],
                episode_factors=[{k: np.round(v, 6).tolist() for k, v in e.get("factors", {}).items()} for e in detail])


def evaluate_scripted(policy: str, settings: dict, episodes: int, seed: int, out: str | Path,
                      oracle_options: dict | None = None) -> dict:
    """Success statistics of the task's scripted oracle (it reads the true state: the proof that physics,
    clearance and success check agree) or of uniform random actions, on episodes seeded seed, seed + 1, ..."""
    if policy not in ("oracle", "random"):
        refuse("policy", policy, "one of ['ckpt', 'oracle', 'random']")
    check_int("episodes", episodes, 1)
    check_seed(seed, episodes)
    task_config = make_task_config(settings)
    if policy == "oracle":  # an option the oracle does not take is refused before anything is built
        from vitac.tasks import import_object
        from vitac.utils.checks import accepted_keywords

        accepted = sorted(accepted_keywords(import_object(task_config.ORACLE)) - {"task"})
        for name, value in (oracle_options or {}).items():
            if name not in accepted:
                refuse(f"oracle_options.{name}", value, f"one of {accepted} (the options of {task_config.ORACLE})")
    task_config.measure_force_balance = True
    # One cheap observation: a scripted controller reads the physics, not the observations.
    task_config.observations = [next(k for k, s in task_config.observation_specs().items() if s.kind == "vector")]
    env = TaskEnv(task_config, seed=seed)
    rng = np.random.default_rng(seed)
    results = []
    try:
        for episode in tqdm(range(episodes), desc=policy, unit="ep"):
            if policy == "oracle":
                info = env.run_oracle_episode(seed=seed + episode, **(oracle_options or {}))
            else:
                env.reset(seed=seed + episode)
                done = False
                while not done:
                    _, _, terminated, truncated, info = env.step(rng.uniform(-1.0, 1.0, env.action_space.shape))
                    done = terminated or truncated
            results.append(info)
    finally:
        env.close()
    report = dict(policy=policy, oracle_options=dict(oracle_options or {}), seed=seed,
                  randomization_scale=task_config.randomization.scale, **episode_statistics(summarize(results)))
    write_json(Path(out), report)
    return report


# The report's per-episode lists: in the file, not on the console.
PER_EPISODE = ("steps_to_success", "final_keypoint_distance_mm", "final_state", "episode_factors", "episode_success",
               "force_balance")


@hydra.main(version_base="1.3", config_path="../conf", config_name="evaluate")
@refusals_in_one_line
def main(cfg: DictConfig) -> None:
    quiet_third_party()
    if cfg.policy != "ckpt":
        out = cfg.out or Path(HydraConfig.get().runtime.output_dir) / f"{cfg.policy}.eval.json"
        settings = OmegaConf.to_container(cfg.task, resolve=True)
        report = evaluate_scripted(cfg.policy, settings, cfg.episodes, cfg.seed, out,
                                   OmegaConf.to_container(cfg.oracle_options))
        print(f"report: {out}")
    elif not cfg.ckpt:
        raise ValueError("ckpt=None is not allowed with policy=ckpt: pass ckpt=<run dir>/checkpoints/last.ckpt, "
                         "or policy=oracle or policy=random")
    else:
        report = evaluate(cfg.ckpt, cfg.episodes, cfg.num_envs, cfg.num_workers, cfg.seed, cfg.out,
                          cfg.randomization_scale, cfg.deterministic, cfg.socket_obs_noise, cfg.randomize_only,
                          cfg.step_in_main, OmegaConf.to_container(cfg.task_overrides))
    print(json.dumps({k: v for k, v in report.items() if k not in PER_EPISODE}, indent=2))


if __name__ == "__main__":
    refuse_unusable_output_folders(sys.argv[1:])
    main()
