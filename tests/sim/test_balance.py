"""The pads' force balance: the asymmetry measure and its per-episode means in an evaluated episode."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vitac.envs.gym_env import TaskEnv
from vitac.models.symmetry import mirror_pad
from vitac.sim.balance import ForceBalance, mirror_field, step_asymmetries


def test_the_mirror_is_the_symmetry_priors_physical_mirror():
    field = np.random.default_rng(0).normal(size=(3, 32, 32))
    assert np.array_equal(mirror_field(field), mirror_pad(torch.from_numpy(field)).numpy())


def test_a_mirror_image_grasp_is_balanced_one_pad_alone_is_not_and_no_touch_is_not_counted():
    left = np.random.default_rng(1).normal(size=(3, 32, 32))
    assert step_asymmetries(left, mirror_field(left)) == dict(field=0.0, net=0.0)
    assert step_asymmetries(left, np.zeros_like(left)) == dict(field=1.0, net=1.0)
    assert step_asymmetries(np.zeros_like(left), np.zeros_like(left)) == dict(field=None, net=None)
    half = step_asymmetries(left, 0.5 * mirror_field(left))  # |l - l/2| / (|l| + |l/2|) = 1/3
    assert half["field"] == pytest.approx(1 / 3) and half["net"] == pytest.approx(1 / 3)


def test_episode_means_count_the_contact_phase_apart_and_resume_exactly():
    left = np.ones((3, 4, 4))
    meter = ForceBalance()
    meter.add(step_asymmetries(left, mirror_field(left)), in_contact=False)  # 0
    meter.add(step_asymmetries(left, np.zeros_like(left)), in_contact=True)  # 1
    meter.add(step_asymmetries(np.zeros_like(left), np.zeros_like(left)), in_contact=True)  # not counted
    summary = meter.summary()
    assert summary["field_episode"] == pytest.approx(0.5) and summary["field_contact"] == 1.0
    assert summary["contact_steps"] == 1
    again = ForceBalance()
    again.load_state(meter.state())
    assert again.summary() == summary
    meter.reset()
    assert meter.summary()["field_episode"] is None


@pytest.mark.parametrize("task", ["insertion", "screw"])
def test_an_episode_with_the_measure_on_ends_with_its_balance_in_the_info(task):
    config = {"_target_": f"vitac.tasks.{task}.config.{task.capitalize()}Config", "measure_force_balance": True,
              "observations": ["proprio"], "episode_steps": 40}
    env = TaskEnv(config, seed=0)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    done, info = False, {}
    while not done:
        _, _, terminated, truncated, info = env.step(rng.uniform(-1, 1, env.action_space.shape))
        done = terminated or truncated
    balance = info["force_balance"]
    assert 0.0 < balance["field_episode"] < 1.0 and 0.0 < balance["net_episode"] < 1.0  # the pads feel the motion
    state = env.task.get_state(env.physics)["force_balance"]
    assert sum(state["counts"].values()) > 0
    env.close()


def test_the_balance_penalty_is_off_by_default_and_otherwise_takes_its_scale_times_the_field_asymmetry():
    rewards = {}
    for scale in (0.0, 2.0):
        env = TaskEnv({"observations": ["proprio"], "balance_penalty_scale": scale}, seed=0)
        env.reset(seed=0)
        task, physics = env.task, env.physics
        rewards[scale] = []
        for a in np.random.default_rng(1).uniform(-1, 1, (30, 6)):
            _, reward, *_ = env.step(a)
            asymmetry = step_asymmetries(task.tactile_field(physics, 0), task.tactile_field(physics, 1))["field"]
            rewards[scale].append((reward, asymmetry or 0.0))
        env.close()
    unpenalized = np.array(rewards[0.0])
    penalized = np.array(rewards[2.0])
    assert np.array_equal(unpenalized[:, 1], penalized[:, 1])  # the same episode: the penalty does not act
    np.testing.assert_allclose(penalized[:, 0], unpenalized[:, 0] - 2.0 * unpenalized[:, 1], rtol=0, atol=1e-12)
    assert unpenalized[:, 1].max() > 0.01  # and there was an asymmetry to pay for
    with pytest.raises(ValueError, match="balance_penalty_scale"):
        TaskEnv({"balance_penalty_scale": -1.0})


def test_a_symmetric_push_on_a_tilted_peg_is_balanced_and_the_asymmetry_grows_with_a_push_into_one_pad():
    # The socket's push on the peg, staged as a force on the held peg (tilted 0.2 rad in the hand, everything else at
    # its range's midpoint): along its axis both pads feel mirror images; along the fingers' closing axis one pad
    # takes the load.
    env = TaskEnv({"_target_": "vitac.tasks.insertion.config.InsertionConfig", "observations": ["proprio"],
                   "randomization": {"enabled": False, "peg_in_hand_tilt": [0.2, 0.2]}}, seed=0)
    readings = []
    for into_one_pad in (0.0, 0.3, 1.0):
        env.reset(seed=0)
        task, physics = env.task, env.physics
        closing = physics.data.site_xmat[task._ids["tcp"]].reshape(3, 3)[:, 1]
        for _ in range(30):
            physics.data.xfrc_applied[task._ids["held_body"], :3] = [0.0, 0.0, 3.0] + into_one_pad * closing
            env.step(np.zeros(6))
        assert np.linalg.norm(task.tactile_field(physics, 0)) > 0.1  # the pads feel the push
        readings.append(task.pad_asymmetries(physics)["field"])
    env.close()
    assert readings[0] < 0.02 and readings[0] < readings[1] < readings[2], readings
