"""The paper's computation table for the whole policy (encoders + fusion + LSTM head), naive / gated / CMT.

    python benchmarks/bench_policy.py [--passes 1000] [--threads 2] [--json docs/data/bench_policy.json] [overrides...]

Latency: mean of `passes` single-step forward passes (inference mode) after warm-up, batch 1 and 256; throughput
= 1000 / latency (ms). Memory: parameters + buffers, plus the peak memory torch allocates during one
batch-1 forward (torch.profiler on CPU, max_memory_allocated on CUDA). CUDA rows when a GPU is present.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from vitac.tasks.insertion.config import InsertionConfig
from vitac.utils.cli import int_at_least, output_file
from vitac.utils.records import write_record

PAPER = {"naive": (5.42, 19.24, 184.50), "gated": (5.51, 17.43, 181.49), "cmt": (6.52, 21.45, 153.37)}


def policy_from_overrides(overrides: list):
    """The policy `python -m vitac.train <overrides>` would train, freshly initialised."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    from vitac.run_config import build_policy_from_config, task_settings

    GlobalHydra.instance().clear()
    with initialize_config_dir(version_base="1.3", config_dir=str(Path(__file__).resolve().parents[1] / "conf")):
        cfg = compose("config", overrides=overrides)
    return build_policy_from_config(cfg, InsertionConfig.from_dict(task_settings(cfg)))


def make_policy(fusion: str, overrides: list = ()):
    return policy_from_overrides(["obs=wrist_tactile", f"fusion={fusion}", "reg=sym", "critic=none",
                                  *overrides]).eval()


def inputs(batch: int, device):
    shapes = InsertionConfig().observation_shapes()
    obs = {k: torch.rand(1, batch, *shapes[k], device=device) for k in ("proprio", "tactile_left", "tactile_right")}
    obs["wrist"] = torch.randint(0, 255, (1, batch, *shapes["wrist"]), dtype=torch.uint8, device=device)
    return obs


@torch.inference_mode()
def latency_ms(policy, batch: int, passes: int, device) -> float:
    obs, starts = inputs(batch, device), torch.zeros(1, batch, device=device)
    state = policy.initial_state(batch, device)
    for _ in range(max(20, passes // 20)):  # warm-up
        policy(obs, state, starts)
    if device.type == "cuda":
        torch.cuda.synchronize()
    start = time.perf_counter()
    for _ in range(passes):
        _, _, _, state = policy(obs, state, starts)
    if device.type == "cuda":
        torch.cuda.synchronize()
    return (time.perf_counter() - start) / passes * 1000.0


@torch.no_grad()
def memory_mb(policy, device) -> tuple[float, float]:
    weights = sum(t.numel() * t.element_size() for t in list(policy.parameters()) + list(policy.buffers())) / 2**20
    obs, starts = inputs(1, device), torch.zeros(1, 1, device=device)
    state = policy.initial_state(1, device)
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats()
        base = torch.cuda.memory_allocated()
        policy(obs, state, starts)
        return weights, (torch.cuda.max_memory_allocated() - base) / 2**20
    with torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU], profile_memory=True) as prof:
        policy(obs, state, starts)
    events = sorted(((e.time_range.start, e.cpu_memory_usage) for e in prof.events() if e.cpu_memory_usage),
                    key=lambda x: x[0])
    current = peak = 0
    for _, delta in events:
        current += delta
        peak = max(peak, current)
    return weights, peak / 2**20


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--passes", type=int_at_least(1), default=1000)
    parser.add_argument("--threads", type=int_at_least(1), default=2)
    parser.add_argument("--json", type=output_file, default=None)
    parser.add_argument("overrides", nargs="*", help="Hydra overrides for every policy (encoder.image.bf16=true)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    devices = [torch.device("cpu")] + ([torch.device("cuda")] if torch.cuda.is_available() else [])
    rows = []
    for device in devices:
        for fusion in ("naive", "gated", "cmt"):
            torch.manual_seed(0)
            policy = make_policy(fusion, args.overrides).to(device)
            lat1 = latency_ms(policy, 1, args.passes, device)
            lat256 = latency_ms(policy, 256, max(args.passes // 20, 20), device)
            weights, activations = memory_mb(policy, device)
            rows.append(dict(device=device.type, fusion=fusion, latency_ms=lat1, throughput_fps=1000.0 / lat1,
                             latency_b256_ms=lat256, samples_per_s_b256=256 * 1000.0 / lat256,
                             weights_mb=weights, peak_forward_mb=activations, memory_mb=weights + activations,
                             paper_latency_ms=PAPER[fusion][0], paper_memory_mb=PAPER[fusion][1],
                             paper_fps=PAPER[fusion][2]))
    for device in devices:
        naive = next(r for r in rows if r["device"] == device.type and r["fusion"] == "naive")
        for r in rows:
            if r["device"] == device.type:
                r["latency_vs_naive"] = r["latency_ms"] / naive["latency_ms"]
    header = ("| device | fusion | latency b1 (ms) | fps | vs naive | latency b256 (ms) | samples/s b256 | memory (MB) "
              "| paper latency / memory / fps |")
    print(header + "\n|" + "---|" * 9)
    for r in rows:
        print(f"| {r['device']} | {r['fusion']} | {r['latency_ms']:.2f} | {r['throughput_fps']:.0f} | "
              f"{r['latency_vs_naive']:.2f}x | {r['latency_b256_ms']:.1f} | {r['samples_per_s_b256']:.0f} | "
              f"{r['memory_mb']:.2f} ({r['weights_mb']:.2f} weights + {r['peak_forward_mb']:.2f} forward) | "
              f"{r['paper_latency_ms']} / {r['paper_memory_mb']} / {r['paper_fps']} |")
    if args.json:
        meta = dict(threads=args.threads, passes=args.passes, overrides=args.overrides, torch=torch.__version__)
        write_record(args.json, meta=meta, rows=rows)


if __name__ == "__main__":
    main()
