"""Record the sensor's inputs along episodes of every task, for the tactile fields' fingerprint test.

    python tests/sim/record_tactile_states.py   # writes tests/data/tactile_states.npz

The fixture holds poses and velocities only, so the test reads the force kernel alone: the same inputs on any
machine, whatever MuJoCo's rounding there. Recorded once (2026-12-05, 6428cf5's simulation); rerecording it
changes the digests the test expects.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vitac.envs.gym_env import TaskEnv

TASKS = {"insertion": "vitac.tasks.insertion.config.InsertionConfig", "screw": "vitac.tasks.screw.config.ScrewConfig"}
INPUTS = ("pad_pos", "pad_rot", "pad_lin", "pad_ang", "part_pos", "part_rot", "part_lin", "part_ang")


def record(task: str, steps: int, seed: int) -> dict:
    env = TaskEnv({"_target_": TASKS[task], "observations": ["proprio", "tactile_left", "tactile_right"]}, seed=seed)
    calls = []
    sensor = env.task.tactile
    sensor.fields = lambda shape, *args: calls.append(args) or type(sensor).fields(sensor, shape, *args)
    env.reset(seed=seed)
    actions = np.random.default_rng(seed).uniform(-1, 1, (steps, env.action_space.shape[0]))
    for a in actions:
        if any(env.step(a)[2:4]):
            env.reset()
    shape = env.task.held_shape
    env.close()
    out = {f"{task}_{k}": np.stack([np.asarray(c[i], dtype=np.float64) for c in calls]) for i, k in enumerate(INPUTS)}
    out[f"{task}_shape"] = np.array([shape.length, shape.radius])
    out[f"{task}_normals"] = np.array(shape.normals, dtype=np.float64).reshape(-1, 2)
    out[f"{task}_offsets"] = np.array(shape.offsets, dtype=np.float64)
    return out


if __name__ == "__main__":
    path = Path(__file__).resolve().parents[1] / "data" / "tactile_states.npz"
    np.savez_compressed(path, **record("insertion", 120, 0), **record("screw", 120, 0))
    print(f"wrote {path} ({path.stat().st_size / 1024:.0f} KiB)")
