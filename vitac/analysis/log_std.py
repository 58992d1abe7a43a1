"""The actor's log-std layer output before its bound, on a checkpoint's own deterministic episodes: is the
exploration noise stuck past the bound (where a hard clamp passes no gradient)? With `head.log_std_mode`
param or fixed, the log-std is one value per action dimension and is printed as it is.

    python -m vitac.runs log-std <run>/checkpoints/last.ckpt [--episodes 3]

Prints the 5th, 50th and 95th percentile per action dimension and the fraction past `head.log_std_max`.
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from vitac.envs.gym_env import TaskEnv
from vitac.run_config import load_policy
from vitac.utils.cli import int_at_least, refuse_bad_files, stop_quietly_when_the_reader_closes


def main(argv=None):
    stop_quietly_when_the_reader_closes()
    parser = argparse.ArgumentParser(prog="python -m vitac.runs log-std", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("ckpt")
    parser.add_argument("--episodes", type=int_at_least(1), default=3)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    with refuse_bad_files():
        policy, cfg, settings = load_policy(args.ckpt)
    policy.eval()
    if policy.head.log_std_mode != "state":  # one value per action dimension, whatever the state
        print(f"log-std ({policy.head.log_std_mode}, before its bound): " +
              "  ".join(f"{v:6.2f}" for v in policy.head.log_std.tolist()))
        return
    raw = []
    policy.head.log_std.register_forward_hook(lambda module, inputs, output: raw.append(output.reshape(-1, output.shape[-1])))
    env = TaskEnv(settings)
    with torch.inference_mode():
        for seed in range(args.episodes):
            obs, _ = env.reset(seed=seed)
            state, starts, done = policy.initial_state(1), torch.ones(1, 1), False
            while not done:
                mean, _, _, state = policy({k: torch.as_tensor(v)[None, None] for k, v in obs.items()}, state, starts)
                obs, _, terminated, truncated, _ = env.step(mean[0, 0].clamp(-1, 1).numpy())
                starts, done = torch.zeros(1, 1), terminated or truncated
    env.close()
    values = torch.cat(raw).numpy()
    print("log-std layer output per action dimension, percentiles 5 / 50 / 95:")
    for q, row in zip((5, 50, 95), np.percentile(values, [5, 50, 95], axis=0), strict=True):
        print(f"  {q:>2}%: " + "  ".join(f"{v:6.2f}" for v in row))
    print(f"past head.log_std_max={cfg.head.log_std_max}: {float((values > cfg.head.log_std_max).mean()):.1%} "
          f"(bound: {cfg.head.get('log_std_bound', 'clamp')})")

