"""What bounds the image policy's training speed: one PPO minibatch forward+backward, float32 vs bfloat16.

    python benchmarks/bench_update.py [--minibatch 256] [--seq-len 32] [--repeats 5] [--json docs/data/bench_update.json]
    python benchmarks/bench_update.py --profile   # also: where the bfloat16 minibatch's time goes (torch.profiler)

Times forward + backward + Adam step of the wrist + tactile CMT + symmetry policy on one minibatch of
sequences, with the conv encoders in float32 and under bfloat16 autocast, and counts the convolutions'
multiply-accumulates from the encoder shapes. From these: the arithmetic rate the machine sustains, and
the most env steps/s training could reach at `--mini-epochs` if it did nothing but the update (each
transition goes through the encoders forward and backward once per mini-epoch), before a single
environment step is simulated or a rollout action is computed. A large dense matrix product in the
same precision and threads gives the machine's practical ceiling: the env steps/s the update alone
would allow if every convolution ran at that rate, against the rate `--target` env steps/s would need.
"""

from __future__ import annotations

import argparse
import time

import torch

from vitac.tasks.insertion.config import InsertionConfig
from vitac.utils.cli import int_at_least, number_above, output_file
from vitac.utils.records import write_record

FWD_BWD = 3  # backward costs about twice the forward (input and weight gradients)


def conv_macs(encoder, in_shape) -> int:
    """Multiply-accumulates of one image through an encoder's conv layers."""
    macs, x = 0, torch.zeros(1, *in_shape)
    for layer in encoder.conv:
        y = layer(x)
        if isinstance(layer, torch.nn.Conv2d):
            macs += y[0].numel() * layer.in_channels * layer.kernel_size[0] * layer.kernel_size[1] // layer.groups
        x = y
    return macs


def time_minibatch(policy, optimizer, obs, starts, repeats: int) -> float:
    def step():
        mean, log_std, value, _, sym = policy(obs, policy.initial_state(starts.shape[1]), starts, with_aux=True)
        loss = mean.pow(2).mean() + log_std.mean() + value.pow(2).mean() + sym.mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()

    for _ in range(2):  # warm-up (oneDNN picks and caches its kernels)
        step()
    start = time.perf_counter()
    for _ in range(repeats):
        step()
    return (time.perf_counter() - start) / repeats


def matmul_gflops(dtype: torch.dtype, size: int = 2048, repeats: int = 10) -> float:
    """Rate of a large dense matrix product: what the threads do at best, a ceiling for any conv kernel."""
    a, b = torch.randn(size, size, dtype=dtype), torch.randn(size, size, dtype=dtype)
    for _ in range(3):
        a @ b
    start = time.perf_counter()
    for _ in range(repeats):
        a @ b
    return 2 * size ** 3 * repeats / (time.perf_counter() - start) / 1e9


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minibatch", type=int_at_least(1), default=256)
    parser.add_argument("--seq-len", type=int_at_least(1), default=32)
    parser.add_argument("--mini-epochs", type=int_at_least(1), default=4)
    parser.add_argument("--repeats", type=int_at_least(1), default=5)
    parser.add_argument("--threads", type=int_at_least(1), default=2)
    parser.add_argument("--target", type=number_above(0), default=300.0, help="env steps/s to compare the ceiling with")
    parser.add_argument("--json", type=output_file, default=None)
    parser.add_argument("--profile", action="store_true", help="print torch.profiler's top ops of the bfloat16 minibatch")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    from bench_policy import make_policy  # benchmarks/ is the script's directory

    torch.manual_seed(0)
    policy = make_policy("cmt").train()
    optimizer = torch.optim.Adam(policy.parameters(), lr=1e-4)
    shapes = InsertionConfig().observation_shapes()
    T, B = args.seq_len, args.minibatch // args.seq_len
    obs = {k: torch.rand(T, B, *shapes[k]) for k in ("proprio", "tactile_left", "tactile_right")}
    obs["wrist"] = torch.randint(0, 255, (T, B, *shapes["wrist"]), dtype=torch.uint8)
    starts = torch.zeros(T, B)
    wrist = conv_macs(policy.encoders["wrist"], shapes["wrist"])
    tactile = conv_macs(policy.encoders["tactile_left"], shapes["tactile_left"])
    update_macs = wrist + 3 * tactile  # left, right and the flipped right map of the symmetry term
    flop_per_transition = 2 * FWD_BWD * update_macs  # one forward + backward pass through the encoders
    flop_per_env_step = args.mini_epochs * flop_per_transition
    rows = []
    for bf16 in (False, True):
        for k in policy.encoders:
            policy.encoders[k].bf16 = bf16
        seconds = time_minibatch(policy, optimizer, obs, starts, args.repeats)
        gflops = args.minibatch * flop_per_transition / seconds / 1e9
        matmul = matmul_gflops(torch.bfloat16 if bf16 else torch.float32)
        rows.append(dict(precision="bfloat16" if bf16 else "float32", minibatch_ms=1000 * seconds,
                         samples_per_s=args.minibatch / seconds, conv_gflop_per_s=gflops,
                         update_only_env_steps_per_s=args.minibatch / seconds / args.mini_epochs,
                         matmul_gflop_per_s=matmul, update_only_env_steps_per_s_at_matmul_rate=matmul * 1e9 / flop_per_env_step))
    print(f"conv MACs per transition: wrist {wrist / 1e6:.1f} M, each tactile map {tactile / 1e6:.2f} M; "
          f"{flop_per_env_step / 1e9:.2f} GFLOP of update per env step at {args.mini_epochs} mini-epochs")
    print(f"| encoders | minibatch of {args.minibatch} (ms) | samples/s fwd+bwd | conv GFLOP/s | env steps/s, update only "
          "| matmul GFLOP/s (ceiling) | env steps/s, update only, at the ceiling |\n|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['precision']} | {r['minibatch_ms']:.0f} | {r['samples_per_s']:.0f} | {r['conv_gflop_per_s']:.0f} | "
              f"{r['update_only_env_steps_per_s']:.0f} | {r['matmul_gflop_per_s']:.0f} | "
              f"{r['update_only_env_steps_per_s_at_matmul_rate']:.0f} |")
    print(f"bfloat16 vs float32: {rows[0]['minibatch_ms'] / rows[1]['minibatch_ms']:.2f}x")
    needed = args.target * flop_per_env_step / 1e9
    print(f"{args.target:.0f} env steps/s would need {needed:.0f} GFLOP/s for the update alone, before any rollout")
    if args.profile:  # the encoders are still in bfloat16 from the last row
        with torch.profiler.profile() as prof:
            time_minibatch(policy, optimizer, obs, starts, repeats=1)
        print(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=8))
    if args.json:
        write_record(args.json, threads=args.threads,
                     minibatch=args.minibatch, seq_len=args.seq_len, mini_epochs=args.mini_epochs,
                     wrist_conv_macs=wrist, tactile_conv_macs=tactile, flop_per_env_step=flop_per_env_step,
                     target_env_steps_per_s=args.target, gflop_per_s_needed_for_target=needed, rows=rows)


if __name__ == "__main__":
    main()
