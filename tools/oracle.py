"""Scripted-oracle success rate: proof that physics, clearance and the success check agree.

    python tools/oracle.py --episodes 200 [--peg-shape round --peg-size 16] [--json docs/data/oracle.json]
    python tools/oracle.py --episodes 50 --observed-socket   # aims at the noisy socket position the actor sees
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from vitac.algos.evaluation import summarize
from vitac.envs.gym_env import TaskEnv
from vitac.utils.cli import int_at_least
from vitac.utils.records import write_record


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int_at_least(1), default=200)
    parser.add_argument("--seed", type=int_at_least(0), default=0)
    parser.add_argument("--peg-shape", default="round")
    parser.add_argument("--peg-size", type=int, default=16)
    parser.add_argument("--random", action="store_true", help="uniform random actions instead of the oracle")
    parser.add_argument("--observed-socket", action="store_true",
                        help="aim at the observed (noisy) socket position instead of the true one")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    env = TaskEnv({"observations": ["proprio"], "peg_shape": args.peg_shape, "peg_size": args.peg_size},
                       seed=args.seed)
    rng = np.random.default_rng(args.seed)
    results, start = [], time.perf_counter()
    for episode in tqdm(range(args.episodes), desc="random" if args.random else "oracle", unit="ep"):
        if args.random:
            env.reset(seed=args.seed + episode)
            done = False
            while not done:
                _, _, te, tr, info = env.step(rng.uniform(-1, 1, 6))
                done = te or tr
        else:
            info = env.run_oracle_episode(seed=args.seed + episode, observed_socket=args.observed_socket)
        results.append(info)
    env.close()
    summary = summarize(results)
    policy = "random" if args.random else "oracle, observed socket" if args.observed_socket else "oracle"
    report = dict(policy=policy, peg=f"{args.peg_shape}-{args.peg_size}mm",
                  **{k: summary[k] for k in ("episodes", "success_rate", "success_ci95", "steps_to_success_mean", "outcomes")},
                  final_keypoint_distance_mm_median=1000 * float(np.median([r["keypoint_distance"] for r in results])),
                  seconds=time.perf_counter() - start)
    print(json.dumps(report, indent=2))
    if args.json:
        write_record(args.json, **report)


if __name__ == "__main__":
    main()
