"""One Adam step over a policy's parameters: torch's default implementation against the fused one PPO uses.

    python benchmarks/bench_optimizer.py [--steps 300] [--threads 2] [--json docs/data/bench_optimizer.json]

The update takes one Adam step per minibatch (16 per iteration at `preset=cpu`). Times the step alone,
with fixed random gradients, for the privileged-state policy (asymmetric critic, as trained) and the wrist
+ tactile CMT + sym policy, alternating the two implementations so that both see the same machine load,
and checks that after the same steps they hold the same weights.
"""

from __future__ import annotations

import argparse
import time

import torch
from bench_policy import policy_from_overrides  # benchmarks/ is the script's directory

from vitac.utils.cli import int_at_least, output_file
from vitac.utils.records import write_record

POLICIES = {"privileged": ["obs=privileged"], "wrist_tactile_cmt_sym": ["obs=wrist_tactile", "fusion=cmt", "reg=sym"]}


def copy_with_grads(params: list) -> list:
    copies = [p.detach().clone().requires_grad_(True) for p in params]
    for c, p in zip(copies, params, strict=True):
        c.grad = p.grad.clone()
    return copies


def time_steps(optimizer, steps: int) -> float:
    start = time.perf_counter()
    for _ in range(steps):
        optimizer.step()
    return (time.perf_counter() - start) / steps * 1e3


def compare(params: list, steps: int, rounds: int = 5) -> dict:
    """Median per-step time of each implementation over alternating rounds, and how far their weights drift."""
    weights = {fused: copy_with_grads(params) for fused in (False, True)}
    optimizers = {fused: torch.optim.Adam(w, lr=1e-4, eps=1e-5, fused=fused) for fused, w in weights.items()}
    times = {False: [], True: []}
    for _ in range(rounds):
        for fused, optimizer in optimizers.items():
            times[fused].append(time_steps(optimizer, steps // rounds))
    gap = max(float((a - b).detach().abs().max()) for a, b in zip(weights[False], weights[True], strict=True))
    median = {fused: sorted(t)[len(t) // 2] for fused, t in times.items()}
    return dict(default_ms=median[False], fused_ms=median[True], speedup=median[False] / median[True],
                max_weight_difference=gap)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int_at_least(1), default=300)
    parser.add_argument("--threads", type=int_at_least(1), default=2)
    parser.add_argument("--json", type=output_file, default=None)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    rows = []
    for name, overrides in POLICIES.items():
        params = [p for p in policy_from_overrides(overrides).parameters() if p.requires_grad]
        for p in params:
            p.grad = torch.randn_like(p)
        compare(params, steps=20)  # warm-up
        rows.append(dict(policy=name, parameters=sum(p.numel() for p in params)) | compare(params, args.steps))
    print("| policy | parameters | Adam step, torch default (ms) | fused (ms) | fused vs default | "
          "largest weight difference after the same steps |\n|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['policy']} | {r['parameters']:,} | {r['default_ms']:.2f} | {r['fused_ms']:.2f} | "
              f"{r['speedup']:.2f}x | {r['max_weight_difference']:.1e} |")
    if args.json:
        write_record(args.json, rows=rows, threads=args.threads, steps=args.steps)


if __name__ == "__main__":
    main()
