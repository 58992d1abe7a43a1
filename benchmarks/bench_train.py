"""End-to-end training throughput (env steps/s, rollout + update) for Table I configurations.

    python benchmarks/bench_train.py [--iterations 6] [--only NAME ...] [--json docs/data/bench_train.json] [overrides...]

Runs each configuration at the default `cpu` preset for a few iterations (evaluation off) and reports
the median over iterations after the first of `charts/SPS` (whole iteration) and `charts/rollout_SPS`.
The image policy runs twice, with the conv encoders in bfloat16 (the default) and in float32, so the
ratio between them is measured in the same run.
"""

from __future__ import annotations

import argparse
import csv
import statistics
import tempfile
from pathlib import Path

from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from omegaconf import open_dict

from vitac.training import train
from vitac.utils.cli import int_at_least, output_file
from vitac.utils.records import write_record

PRIVILEGED = ["experiment=table1/privileged"]
# DAgger with the student acting: its defaults (4 passes of 256, as PPO at the cpu preset), and one pass of 1,024
# (the cheap update that did not learn, docs/results.md).
DAGGER = ["algo=dagger", "algo.beta_start=0.0"]
DAGGER_1X1024 = DAGGER + ["algo.mini_epochs=1", "algo.minibatch_size=1024"]
# One pass of 256 (4 gradient steps) drawn from the last 4 rollouts: a quarter of the default's update.
DAGGER_1X256_KEPT4 = DAGGER + ["algo.mini_epochs=1", "algo.dataset_rollouts=4"]
# The same 1,024 transitions an update in 16 minibatches of 64 (the default's 16 gradient steps, a quarter of its
# samples).
DAGGER_1X64_KEPT4 = DAGGER_1X256_KEPT4 + ["algo.minibatch_size=64"]
# The image rows force their precision (the default, auto, picks float32 on CPUs without native bfloat16), so that
# bfloat16 vs float32 means the same on every machine; docs/benchmarks.md measured bfloat16 rows.
CMT_SYM = ["obs=wrist_tactile", "fusion=cmt", "reg=sym"]
CMT_SYM_BF16 = CMT_SYM + ["encoder.image.bf16=true"]
CONFIGS = {"privileged": PRIVILEGED,
           "privileged_workers_only": PRIVILEGED + ["envs.step_in_main=false"],
           "privileged_horizon128": PRIVILEGED + ["algo.horizon=128", "algo.minibatch_size=512"],
           # The rollout and minibatch of the 93.7% segment of docs/results.md, and the same 8,192-transition
           # iteration from twice the environments.
           "privileged_horizon512": PRIVILEGED + ["algo.horizon=512", "algo.minibatch_size=2048"],
           "privileged_32envs_horizon256": PRIVILEGED + ["envs.num_envs=32", "algo.horizon=256", "algo.minibatch_size=2048"],
           "wrist_tactile_cmt_sym": CMT_SYM_BF16 + ["algo=ppo"],
           "wrist_tactile_cmt_sym_workers_only": CMT_SYM_BF16 + ["algo=ppo", "envs.step_in_main=false"],
           "wrist_tactile_cmt_sym_fp32": CMT_SYM + ["encoder.image.bf16=false", "algo=ppo"],
           "wrist_tactile_cmt_sym_dagger": CMT_SYM_BF16 + DAGGER,
           "wrist_tactile_cmt_sym_dagger_1x1024": CMT_SYM_BF16 + DAGGER_1X1024,
           "wrist_tactile_cmt_sym_dagger_1x256_kept4": CMT_SYM_BF16 + DAGGER_1X256_KEPT4,
           "wrist_tactile_cmt_sym_dagger_1x64_kept4": CMT_SYM_BF16 + DAGGER_1X64_KEPT4}


def untrained_teacher(out: str) -> str:
    """A privileged policy's checkpoint after one smoke iteration: a teacher for timing distillation (the
    labels' quality does not change the work per step)."""
    return train(_compose(PRIVILEGED + ["preset=smoke", "trainer.iterations=1"], out))["checkpoint"]


def _compose(overrides: list, out: str):
    GlobalHydra.instance().clear()
    with initialize_config_dir(version_base="1.3", config_dir=str(Path(__file__).resolve().parents[1] / "conf")):
        cfg = compose("config", overrides=overrides)
    with open_dict(cfg):
        cfg.output_dir = out
    return cfg


def run(name: str, overrides: list, iterations: int) -> dict:
    with tempfile.TemporaryDirectory() as out:
        cfg = _compose(overrides + ["logger=csv", f"trainer.iterations={iterations}", "eval.every=100000",
                                    "checkpoint.every_n_epochs=100000"], out)
        result = train(cfg)
        with open(result["metrics_csv"]) as f:
            rows = [r for r in csv.DictReader(f) if r.get("charts/SPS")]
    sps = [float(r["charts/SPS"]) for r in rows[1:]]
    rollout = [float(r["charts/rollout_SPS"]) for r in rows[1:]]
    return dict(config=name, overrides=overrides, preset=cfg.preset.name, num_envs=cfg.envs.num_envs,
                workers=cfg.envs.num_workers, iterations=iterations, env_steps_per_s=statistics.median(sps),
                rollout_env_steps_per_s=statistics.median(rollout))


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--iterations", type=int_at_least(2), default=6,
                        help="iterations per configuration; the first (start-up) is left out of the median")
    parser.add_argument("--only", nargs="+", choices=sorted(CONFIGS), default=list(CONFIGS))
    parser.add_argument("--json", type=output_file, default=None)
    parser.add_argument("overrides", nargs="*", help="extra Hydra overrides for every configuration")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as teacher_dir:
        teacher = untrained_teacher(teacher_dir) if any("algo=dagger" in CONFIGS[n] for n in args.only) else None
        rows = [run(name, CONFIGS[name] + args.overrides
                    + ([f"teacher_ckpt={teacher}"] if "algo=dagger" in CONFIGS[name] else []), args.iterations)
                for name in args.only]
    print("| config | preset | envs / workers | env steps/s (rollout + update) | rollout only |\n|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['config']} | {r['preset']} | {r['num_envs']} / {r['workers']} | {r['env_steps_per_s']:.0f} | "
              f"{r['rollout_env_steps_per_s']:.0f} |")
    if args.json:
        write_record(args.json, rows=rows)


if __name__ == "__main__":
    main()
