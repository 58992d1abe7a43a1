"""Environment speed: control steps/s of one env (all observations on) with a cost breakdown, and of
N envs vectorised over 1 and 2 worker processes.

    python benchmarks/bench_env.py [--steps 1000] [--tasks insertion screw] [--single] [--driver random oracle] [--json docs/data/bench_env.json]

With several tasks, each gets the one-env figure and its ratio to the first task's, measured in the same run;
the vectorised rows are the first task's (`--single`: none). The one env is driven by uniform random actions
(an untrained policy), or with `--driver random oracle` also by the task's scripted oracle, whose episodes
look like a trained policy's (the part aligned, pushed home or screwed down, the episode ended on success).

Breakdown per control step: physics (the substeps), rendering (64x64 wrist frame), tactile (both
pads' fields), framework (composer, observables, reward, gymnasium adapter: the rest). The tactile
rate is also given in pad-frames/s.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import vitac.api
from vitac.envs.gym_env import TaskEnv  # selects headless EGL before mujoco loads
from vitac.envs.vector_env import TaskVectorEnv
from vitac.utils.cli import int_at_least, output_file
from vitac.utils.records import write_record

WARMUP_STEPS = 50
ALL = ["proprio", "peg_state", "contact_forces", "wrist", "tactile_left", "tactile_right", "critic_state"]


def task_settings(task: str) -> dict:
    """The task config's settings as `python -m vitac.train task=<task>` composes them, every observation on."""
    return vitac.api.task_settings(task, observations=ALL)


def _timed(owner, name: str, totals: dict, key: str):
    """Replace owner.name by a wrapper that adds its wall time to totals[key]."""
    inner = getattr(owner, name)

    def wrapper(*args, **kwargs):
        start = time.perf_counter()
        try:
            return inner(*args, **kwargs)
        finally:
            totals[key] += time.perf_counter() - start

    setattr(owner, name, wrapper)


class Driver:
    """The one env's actions: uniform random, or the task's scripted oracle (a new one each episode)."""

    def __init__(self, env: TaskEnv, kind: str, steps: int):
        self.env, self.kind = env, kind
        # the warm-up replays the first of the timed steps' actions
        self.random_actions = np.random.default_rng(0).uniform(-1, 1, (max(steps, WARMUP_STEPS), 6))
        self.new_episode()

    def new_episode(self) -> None:
        if self.kind == "oracle":
            self.oracle = self.env.new_oracle()

    def action(self, k: int) -> np.ndarray:
        return self.oracle(self.env.physics) if self.kind == "oracle" else self.random_actions[k]


def single_env(steps: int, task: str = "insertion", driver: str = "random") -> dict:
    env = TaskEnv(task_settings(task), seed=0)
    env.reset(seed=0)
    drive = Driver(env, driver, steps)
    for k in range(WARMUP_STEPS):
        _, _, te, tr, _ = env.step(drive.action(k))
        if te or tr:
            env.reset()
            drive.new_episode()
    totals = dict(physics=0.0, render=0.0, tactile=0.0)
    # Time the pieces inside real steps: the substeps, the wrist frame, both pads' fields.
    _timed(env.task, "step_physics", totals, "physics")
    _timed(env.task, "render_wrist", totals, "render")
    _timed(env.task, "raw_tactiles", totals, "tactile")
    resets, successes, contacts = 0, 0, 0
    start = time.perf_counter()
    for k in range(steps):
        _, _, te, tr, info = env.step(drive.action(k))
        contacts += env.physics.data.ncon
        if te or tr:
            successes += bool(info["success"])
            env.reset()
            drive.new_episode()
            resets += 1
    total = time.perf_counter() - start
    env.close()
    per = {k: v / steps for k, v in totals.items()}
    return dict(driver=driver, steps_per_s=steps / total, step_ms=total / steps * 1e3, physics_ms=per["physics"] * 1e3,
                render_ms=per["render"] * 1e3, tactile_ms=per["tactile"] * 1e3,
                framework_ms=(total / steps - sum(per.values())) * 1e3, substeps=env.task.physics_steps_per_control_step,
                tactile_pad_frames_per_s=2.0 / per["tactile"], resets_included=resets, successes=successes,
                mean_contacts=contacts / steps)


def vectorised(num_envs: int, workers: int, steps: int, task: str = "insertion") -> float:
    venv = TaskVectorEnv(task_settings(task), num_envs=num_envs, num_workers=workers, seed=0)
    venv.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-1, 1, (steps, num_envs, 6))
    for a in actions[:20]:
        venv.step(a)
    start = time.perf_counter()
    for a in actions:
        venv.step(a)
    rate = steps * num_envs / (time.perf_counter() - start)
    venv.close()
    return rate


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int_at_least(1), default=1000)
    parser.add_argument("--tasks", nargs="+", choices=vitac.api.task_names(), default=["insertion"])
    parser.add_argument("--single", action="store_true", help="only the one-env figures")
    parser.add_argument("--driver", nargs="+", choices=["random", "oracle"], default=["random"],
                        help="what drives the one env: random actions, the scripted oracle, or each in turn")
    parser.add_argument("--json", type=output_file, default=None)
    args = parser.parse_args()
    by_driver = {driver: {} for driver in args.driver}
    for driver, singles in by_driver.items():
        for task in args.tasks:
            single = singles[task] = single_env(args.steps, task, driver)
            single["vs_first_task"] = single["steps_per_s"] / singles[args.tasks[0]]["steps_per_s"]
            print(f"{task}, one env driven by {driver} actions, all observations: {single['steps_per_s']:.0f} control steps/s "
                  f"({single['step_ms']:.3f} ms, {single['vs_first_task']:.2f}x {args.tasks[0]}): physics "
                  f"{single['physics_ms']:.3f} ms ({single['substeps']} substeps, {single['mean_contacts']:.0f} contacts), "
                  f"render {single['render_ms']:.3f} ms, tactile {single['tactile_ms']:.3f} ms "
                  f"({single['tactile_pad_frames_per_s']:.0f} pad-frames/s), framework {single['framework_ms']:.3f} ms, "
                  f"{single['resets_included']} resets ({single['successes']} on success)")
    singles = by_driver[args.driver[0]]
    if args.single:
        if args.json:
            write_record(args.json, single=singles, **({"by_driver": by_driver} if len(by_driver) > 1 else {}))
        return
    single = singles[args.tasks[0]]
    rows = []
    base = None
    for workers in (1, 2):
        for n in (1, 2, 4, 8):
            if n < workers:
                continue
            rate = vectorised(n, workers, max(args.steps // n, 50), args.tasks[0])
            base = base or rate
            rows.append(dict(num_envs=n, workers=workers, steps_per_s=rate))
    one_worker = {r["num_envs"]: r["steps_per_s"] for r in rows if r["workers"] == 1}
    print("| envs | workers | env steps/s | vs same envs on 1 worker |\n|---|---|---|---|")
    for r in rows:
        r["speedup_vs_one_worker"] = r["steps_per_s"] / one_worker[r["num_envs"]]
        print(f"| {r['num_envs']} | {r['workers']} | {r['steps_per_s']:.0f} | {r['speedup_vs_one_worker']:.2f}x |")
    if args.json:
        write_record(args.json, single=single, vectorised=rows, **({"tasks": singles} if len(singles) > 1 else {}))


if __name__ == "__main__":
    main()
