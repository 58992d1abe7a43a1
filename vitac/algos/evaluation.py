"""Run a policy on seeded episodes and summarise success and steps to succeed."""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import torch
from tqdm.auto import tqdm


@torch.inference_mode()
def run_episodes(policy, envs, episodes: int, seed: int, deterministic: bool = True, progress: bool = False) -> dict:
    """Run `episodes` episodes (a multiple of envs.num_envs) with the mean action, or with actions sampled
    from the policy's Gaussian (noise from a generator seeded with `seed`, on the CPU whatever the policy's
    device); returns per-episode results. `progress` shows a bar of finished episodes with rate and ETA."""
    policy.eval()
    device = policy.device
    generator = torch.Generator().manual_seed(seed)
    n = envs.num_envs
    results = []
    rounds = math.ceil(episodes / n)
    bar = tqdm(total=episodes, desc="evaluate", unit="ep", disable=not progress)
    for r in range(rounds):
        obs, _ = envs.reset(seed=seed + r * n)
        state, starts = policy.initial_state(n, device), torch.ones(n)
        done = np.zeros(n, dtype=bool)
        while not done.all():
            obs_t, starts_t = policy.step_inputs(obs, starts)
            mean, log_std, _, state = policy(obs_t, state, starts_t)
            action = mean[0].cpu()
            if not deterministic:
                action = action + log_std[0].cpu().exp() * torch.randn(action.shape, generator=generator)
            obs, _, terminated, truncated, info = envs.step(action.clamp(-1, 1).numpy())
            starts = torch.zeros(n)
            for i in np.flatnonzero((terminated | truncated) & ~done):
                env_info = info["env_infos"][i]
                # The episode's end as the task reports it: success, steps to success, goal distance, outcome.
                results.append(dict(env_info, success=bool(env_info["success"]),
                                    steps_to_success=int(env_info["steps_to_success"]), episode=r * n + int(i)))
            done |= terminated | truncated
            bar.update(min(len(results), episodes) - bar.n)
    bar.close()
    # In episode order (env i of round r runs episode r n + i, seeded seed + r n + i), whatever order they ended in:
    # two evaluations with the same seed and episodes are paired episode by episode.
    return summarize(sorted((e for e in results if e["episode"] < episodes), key=lambda e: e["episode"]))


def wilson_interval(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95% Wilson score interval of a success rate."""
    if n == 0:
        return float("nan"), float("nan")
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return centre - half, centre + half


def summarize(results: list[dict]) -> dict:
    successes = sum(r["success"] for r in results)
    steps = [r["steps_to_success"] for r in results if r["success"] and r["steps_to_success"] >= 0]
    low, high = wilson_interval(successes, len(results))
    outcomes = Counter(r["outcome"] for r in results if "outcome" in r)
    return dict(episodes=len(results), success_rate=successes / max(len(results), 1), success_ci95=[low, high],
                outcomes=dict(outcomes.most_common()),
                steps_to_success_mean=float(np.mean(steps)) if steps else None,
                steps_to_success=steps, episodes_detail=results)
