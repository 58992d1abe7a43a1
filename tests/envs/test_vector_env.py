"""The vector env: worker processes match in-process stepping, autoreset is same-step, failures are named."""

from __future__ import annotations

import os
import signal

import numpy as np
import pytest

from vitac.envs.vector_env import TaskVectorEnv


def test_vector_env_workers_match_in_process_and_autoreset_same_step():
    cfg = {"observations": ["proprio", "critic_state"], "episode_steps": 5}
    actions = np.random.default_rng(0).uniform(-1, 1, (7, 4, 6))
    outputs = []
    for workers, step_in_main in ((0, False), (2, False), (2, True), (1, True)):
        venv = TaskVectorEnv(cfg, num_envs=4, num_workers=workers, seed=7, step_in_main=step_in_main)
        obs, _ = venv.reset(seed=7)
        trace = [obs["proprio"].copy()]
        for t in range(7):
            obs, reward, terminated, truncated, info = venv.step(actions[t])
            trace.append(obs["proprio"].copy())
            if t == 4:
                assert truncated.all() and not terminated.any()
                assert sorted(info["final_obs"]) == [0, 1, 2, 3]
                assert not np.allclose(info["final_obs"][0]["proprio"], obs["proprio"][0])
        venv.close()
        outputs.append(np.array(trace))
    for other in outputs[1:]:
        np.testing.assert_array_equal(outputs[0], other)


def test_a_failing_group_is_reported_and_leaves_the_vector_env_in_step():
    venv = TaskVectorEnv({"observations": ["proprio"]}, num_envs=4, num_workers=2, seed=0, step_in_main=True)
    venv.reset(seed=0)
    bad = np.zeros((4, 6))
    bad[0, 0] = np.nan  # refused by this process's group, while the worker steps its two envs
    with pytest.raises(ValueError, match="finite"):
        venv.step(bad)
    bad = np.zeros((4, 6))
    bad[3, 0] = np.nan  # refused in the worker: named as its group
    with pytest.raises(RuntimeError, match="environment group 1 .*failed in 'step'"):
        venv.step(bad)
    obs, reward, *_ = venv.step(np.zeros((4, 6)))  # every reply was collected: the next step is in order
    venv.close()
    assert obs["proprio"].shape == (4, 19) and np.isfinite(reward).all()


def test_a_dead_worker_is_named_with_its_exit_code_and_close_still_works():
    # With no restarts allowed (tests/test_faults.py restarts one).
    venv = TaskVectorEnv({"observations": ["proprio"]}, num_envs=4, num_workers=2, seed=0, step_in_main=True,
                         max_restarts=0)
    venv.reset(seed=0)
    worker = venv._procs[0]
    os.kill(worker.pid, signal.SIGKILL)  # e.g. the kernel's OOM killer
    worker.join(timeout=10)
    with pytest.raises(RuntimeError, match=rf"worker process {worker.pid} died \(exit code -9\) during 'step'"):
        venv.step(np.zeros((4, 6)))
    venv.close()
