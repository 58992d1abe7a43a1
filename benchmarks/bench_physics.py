"""Where MuJoCo's time goes, by what the peg is doing: MuJoCo's own timers per substep, one environment.

    python benchmarks/bench_physics.py [--episodes 8] [--ckpt <run>/checkpoints/last.ckpt] [--json docs/data/bench_physics.json]
    python benchmarks/bench_physics.py --ckpt ... --opt cone=0 --disable MULTICCD   # the same under other MuJoCo options

Drives one environment with the privileged observations and the critic state (what `obs=privileged`
trains on) three ways: uniform random actions (the peg mostly in the air, like an untrained policy), the
scripted oracle (the peg aligned, pushed into the hole and held there, like a trained policy), and, given
`--ckpt`, that checkpoint's policy with sampled actions (as in training). For each: control steps/s in
this one process; physics per control step; per substep, the wall time of MuJoCo and its timers for
collision (narrow phase apart) and the constraint solve; contacts, constraint rows and solver iterations
(read after each control step's substeps); and the constraint solve that the contact-force observation
adds (only where no substep has run: the first observation of an episode), per control step. `--opt
NAME=VALUE` (a field of MuJoCo's mjOption) and `--disable FLAG` (an mjtDisableBit without its mjDSBL_ prefix)
time the same drivers under other solver or collision settings; they change the task's physics, so the
successes column says whether the policy still copes.
"""

from __future__ import annotations

import argparse
import time

import mujoco
import numpy as np
import torch

from vitac.envs.gym_env import TaskEnv  # first: it selects headless EGL before mujoco renders
from vitac.tasks.insertion.oracle import OracleController
from vitac.tasks.insertion.task import InsertionTask
from vitac.utils.cli import int_at_least, output_file, refuse_bad_files, tool_entry
from vitac.utils.records import write_record

OBSERVATIONS = ["proprio", "peg_state", "critic_state"]
TIMERS = {"collision": mujoco.mjtTimer.mjTIMER_POS_COLLISION, "narrow_phase": mujoco.mjtTimer.mjTIMER_COL_NARROW,
          "constraint_solve": mujoco.mjtTimer.mjTIMER_CONSTRAINT}


class PhysicsMeter:
    """Sums, over every control step's substeps (InsertionTask.step_physics), wall time, MuJoCo's timers,
    contacts and constraint rows, and the contact-force observation's own solves; patches the class, so
    `close` must undo it."""

    def __init__(self, options: dict | None = None, disable_mask: int = 0):
        self.totals = dict(wall=0.0, substeps=0, calls=0, contacts=0, rows=0, solver_iterations=0, contact_force_solve=0.0,
                           contact_force_calls=0, **{k: 0.0 for k in TIMERS})
        self._step, self._forces = InsertionTask.step_physics, InsertionTask._contact_forces
        meter = self

        def step(task, physics, nstep):
            data, opt = physics.data.ptr, physics.model.ptr.opt
            for name, value in (options or {}).items():  # every call: composer may rebuild the model
                setattr(opt, name, value)
            opt.disableflags |= disable_mask
            for timer in TIMERS.values():  # the timers also run outside steps: count only what happens here
                data.timer[timer].duration = 0.0
            start = time.perf_counter()
            meter._step(task, physics, nstep)
            meter.totals["wall"] += time.perf_counter() - start
            meter.totals["substeps"] += nstep
            meter.totals["calls"] += 1
            meter.totals["contacts"] += data.ncon
            meter.totals["rows"] += data.nefc
            meter.totals["solver_iterations"] += data.solver_niter[0]
            for key, timer in TIMERS.items():
                meter.totals[key] += data.timer[timer].duration

        def contact_forces(task, physics):
            start = time.perf_counter()
            try:
                return meter._forces(task, physics)
            finally:
                meter.totals["contact_force_solve"] += time.perf_counter() - start
                meter.totals["contact_force_calls"] += 1

        InsertionTask.step_physics, InsertionTask._contact_forces = step, contact_forces

    def close(self):
        InsertionTask.step_physics, InsertionTask._contact_forces = self._step, self._forces

    def report(self, control_steps: int, seconds: float) -> dict:
        t = self.totals
        per_substep = {f"{k}_us": 1e6 * t[k] / t["substeps"] for k in TIMERS}
        return dict(control_steps=control_steps, control_steps_per_s=control_steps / seconds,
                    physics_ms_per_control_step=1e3 * t["wall"] / t["calls"],
                    physics_share=t["wall"] / seconds, substep_us=1e6 * t["wall"] / t["substeps"], **per_substep,
                    contacts_per_substep=t["contacts"] / t["calls"], constraint_rows_per_substep=t["rows"] / t["calls"],
                    solver_iterations_per_substep=t["solver_iterations"] / t["calls"],
                    contact_force_solve_us_per_control_step=1e6 * t["contact_force_solve"] / t["calls"])


def drive_scripted(driver: str, episodes: int, seed: int, options: dict, disable_mask: int) -> dict:
    env = TaskEnv({"observations": OBSERVATIONS}, seed=seed)
    rng = np.random.default_rng(seed)
    env.run_oracle_episode(seed=seed - 1)  # warm-up: numba compiles, MuJoCo allocates
    meter, steps, successes = PhysicsMeter(options, disable_mask), 0, 0
    start = time.perf_counter()
    try:
        for episode in range(episodes):
            env.reset(seed=seed + episode)
            oracle = OracleController(env.task) if driver == "oracle" else None
            done = False
            while not done:
                action = oracle(env.physics) if oracle else rng.uniform(-1, 1, 6)
                _, _, terminated, truncated, info = env.step(action)
                steps += 1
                done = terminated or truncated
            successes += bool(info["success"])
        seconds = time.perf_counter() - start
    finally:
        meter.close()
        env.close()
    return dict(driver=driver, episodes=episodes, successes=successes, **meter.report(steps, seconds))


def drive_checkpoint(ckpt: str, policy, settings: dict, episodes: int, seed: int, options: dict,
                     disable_mask: int) -> dict:
    from vitac.algos.evaluation import run_episodes
    from vitac.envs.vector_env import TaskVectorEnv

    torch.set_num_threads(1)
    envs = TaskVectorEnv(settings, num_envs=1, num_workers=0, seed=seed, step_in_main=True)
    try:
        run_episodes(policy, envs, 1, seed - 1, deterministic=False)  # warm-up
        meter = PhysicsMeter(options, disable_mask)
        start = time.perf_counter()
        try:
            summary = run_episodes(policy, envs, episodes, seed, deterministic=False)
            seconds = time.perf_counter() - start
        finally:
            meter.close()
    finally:
        envs.close()
    steps = meter.totals["calls"]
    return dict(driver="checkpoint, sampled actions", ckpt=ckpt, episodes=episodes,
                successes=round(summary["success_rate"] * episodes), **meter.report(steps, seconds))


def parse_options(pairs: list[str]) -> dict:
    """NAME=VALUE pairs naming numeric fields of MuJoCo's mjOption, as values of each field's type; refused
    before any simulation otherwise."""
    default = mujoco.MjOption()
    fields = {name for name in dir(default) if isinstance(getattr(default, name), (int, float))}
    options = {}
    for pair in pairs:
        name, _, value = pair.partition("=")
        if name not in fields or not value:
            raise SystemExit(f"--opt {pair!r} is not allowed: expected NAME=VALUE with NAME a "
                             f"numeric field of mjOption: {sorted(fields)}")
        options[name] = type(getattr(default, name))(float(value))
    return options


def parse_disable(flags: list[str]) -> int:
    """mjtDisableBit names without their mjDSBL_ prefix, as one mask; refused before any simulation otherwise."""
    allowed = [name.removeprefix("mjDSBL_") for name in dir(mujoco.mjtDisableBit) if name.startswith("mjDSBL_")]
    mask = 0
    for flag in flags:
        if flag not in allowed:
            raise SystemExit(f"--disable {flag!r} is not allowed: expected one of {allowed}")
        mask |= int(getattr(mujoco.mjtDisableBit, f"mjDSBL_{flag}"))
    return mask


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int_at_least(1), default=8)
    parser.add_argument("--seed", type=int_at_least(1), default=1000)
    parser.add_argument("--ckpt", default=None, help="also drive with this checkpoint's policy")
    parser.add_argument("--opt", action="append", default=[], metavar="NAME=VALUE", help="set a field of mjOption")
    parser.add_argument("--disable", action="append", default=[], metavar="FLAG", help="set mjDSBL_FLAG")
    parser.add_argument("--json", type=output_file, default=None)
    args = parser.parse_args()
    options, disable_mask = parse_options(args.opt), parse_disable(args.disable)
    if args.ckpt:  # read before the scripted drivers' minutes: a missing or corrupt file stops the tool at once
        from vitac.run_config import load_policy

        with refuse_bad_files():
            policy, _, settings = load_policy(args.ckpt)
    rows = [drive_scripted(d, args.episodes, args.seed, options, disable_mask) for d in ("random", "oracle")]
    if args.ckpt:
        rows.append(drive_checkpoint(args.ckpt, policy, settings, args.episodes, args.seed, options, disable_mask))
    print("| driver | successes | control steps/s | physics ms / control step (share) | us / substep | collision "
          "(narrow phase) us | constraint solve us (solver iterations) | contacts | constraint rows | contact-force solve us / control step |\n"
          "|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['driver']} | {r['successes']}/{r['episodes']} | {r['control_steps_per_s']:.0f} | "
              f"{r['physics_ms_per_control_step']:.3f} ({100 * r['physics_share']:.0f}%) | {r['substep_us']:.1f} | "
              f"{r['collision_us']:.1f} ({r['narrow_phase_us']:.1f}) | {r['constraint_solve_us']:.1f} ({r['solver_iterations_per_substep']:.1f}) | "
              f"{r['contacts_per_substep']:.1f} | {r['constraint_rows_per_substep']:.1f} | "
              f"{r['contact_force_solve_us_per_control_step']:.1f} |")
    if args.json:
        write_record(args.json, rows=rows, options=options, disable=args.disable)


if __name__ == "__main__":
    tool_entry(main)()
