"""The insertion task's sensors in simulation: the pads' force fields against the grasped peg, their mirror
symmetry, and the contact-force readout against MuJoCo's own."""

from __future__ import annotations

import numpy as np
import pytest

from vitac.envs.gym_env import TaskEnv


def test_grasp_holds_and_residual_field_starts_near_zero():
    env = TaskEnv({"observations": ["tactile_left", "contact_forces"]}, seed=0)
    obs, _ = env.reset(seed=3)
    raw_left = env.task.raw_tactile(env.physics, 0)
    assert raw_left[2].max() > 0, "the pads squeeze the peg at the start"
    assert np.abs(obs["tactile_left"]).max() < 0.5 * raw_left[2].max()  # residual against f_ref (eq. 2)
    forces = obs["contact_forces"].reshape(3, 3)
    env.close()
    assert np.linalg.norm(forces[1]) > 0.5 and np.linalg.norm(forces[2]) > 0.5  # both pads push on the peg


@pytest.mark.parametrize("tilt", [0.3, -0.3])
def test_tilted_peg_squeeze_right_mirrored_into_the_left_frame_equals_left_in_every_channel(tilt):
    # A peg tilted about the closing axis is held mirror-symmetrically, and its rows are not symmetric: the row
    # flip matters (unflipped, the normal maps differ) and so does the sign of the shear along the rows.
    import torch

    from vitac.models.symmetry import flip_vertical, mirror_pad

    cfg = {"observations": ["proprio"], "randomization": {"enabled": True, "peg_in_hand_tilt": [tilt, tilt],
                                                          "ee_rot_low": [0, 0, 0], "ee_rot_high": [0, 0, 0]}}
    e = TaskEnv(cfg, seed=0)
    e.reset(seed=4)
    left, right = (torch.as_tensor(e.task.raw_tactile(e.physics, side)) for side in (0, 1))
    e.close()
    scale = left.abs().amax(dim=(1, 2))  # per channel
    assert (scale > 0).all()
    assert ((mirror_pad(right) - left).abs().amax(dim=(1, 2)) <= 0.02 * scale).all()
    assert (left - right).abs()[2].max() > 0.5 * scale[2]  # no flip: the normal maps differ
    assert (flip_vertical(right) - left).abs()[0].max() > 1.5 * scale[0]  # the image flip: shear_x twice apart


def test_centred_symmetric_squeeze_right_flipped_equals_left():
    cfg = {"observations": ["proprio"], "randomization": {"enabled": True, "peg_in_hand_tilt": [0.0, 0.0],
                                                          "ee_rot_low": [0, 0, 0], "ee_rot_high": [0, 0, 0]}}
    e = TaskEnv(cfg, seed=0)
    e.reset(seed=4)
    left, right = e.task.raw_tactile(e.physics, 0), e.task.raw_tactile(e.physics, 1)
    e.close()
    assert left[2].max() > 0
    np.testing.assert_allclose(right[2][::-1], left[2], atol=0.05 * left[2].max())


def _peg_forces_by_mj_contact_force(m, d) -> np.ndarray:
    """Each slot (socket, left pad, right pad): mj_contactForce's world-frame sum of the forces on the peg."""
    import mujoco

    slot_of = {"gripper/left_pad": 1, "gripper/right_pad": 2}
    expected = np.zeros((3, 3))
    for i in range(d.ncon):
        c = d.contact[i]
        names = m.geom(c.geom1).name, m.geom(c.geom2).name
        peg_second = names[1].startswith("peg")
        if peg_second == names[0].startswith("peg"):
            continue
        other = names[0] if peg_second else names[1]
        slot = 0 if other.startswith("socket") else slot_of.get(other)
        if slot is None:
            continue
        f = np.zeros(6)
        mujoco.mj_contactForce(m, d, i, f)
        world = c.frame.reshape(3, 3).T @ f[:3]
        expected[slot] += world if peg_second else -world
    return expected


def test_contact_forces_are_the_last_substeps_solve_and_a_fresh_one_after_reset():
    import copy

    import mujoco

    from vitac.tasks.insertion.oracle import OracleController

    e = TaskEnv({"observations": ["proprio", "contact_forces"]}, seed=0)
    obs, _ = e.reset(seed=20)  # no substep yet: solved for the state
    m, d, substeps = e.physics.model.ptr, e.physics.data.ptr, e.task.physics_steps_per_control_step
    rng, oracle = np.random.default_rng(0), OracleController(e.task)

    def fresh_solve():
        fresh = copy.copy(d)
        mujoco.mj_forward(m, fresh)
        return _peg_forces_by_mj_contact_force(m, fresh)

    def step_and_replay(action):
        """One env step, and the same substeps replayed on a copy, stopped after the last substep's solve."""
        before = copy.copy(d)
        obs, *_ = e.step(action)
        replay = copy.copy(before)
        replay.ctrl[:] = d.ctrl  # the action's targets
        mujoco.mj_step2(m, replay)
        mujoco.mj_step(m, replay, substeps - 2)
        mujoco.mj_step1(m, replay)
        mujoco.mj_step2(m, replay)
        last_solve = _peg_forces_by_mj_contact_force(m, replay)
        mujoco.mj_step1(m, replay)
        np.testing.assert_array_equal(replay.qpos, d.qpos)  # the replay is the env's own step
        return obs["contact_forces"].reshape(3, 3), last_solve

    np.testing.assert_allclose(obs["contact_forces"].reshape(3, 3), fresh_solve(), rtol=1e-5, atol=1e-6)
    for _ in range(40):  # the hand swings the grasped peg about: the pads' forces change from substep to substep
        observed, last_solve = step_and_replay(rng.uniform(-1, 1, 6))
        assert np.all(np.isfinite(observed))
        np.testing.assert_allclose(observed, last_solve, rtol=1e-5, atol=1e-6)
    assert np.linalg.norm(observed[1:]) > 1.0  # the pads hold the peg
    assert not np.allclose(observed, fresh_solve(), rtol=1e-3, atol=1e-3)  # a solve for the final state differs
    e.reset(seed=22)
    for _ in range(120):  # the oracle presses the peg into the socket
        observed, last_solve = step_and_replay(oracle(e.physics))
    assert np.linalg.norm(observed[0]) > 0.1  # the socket pushes on the peg
    np.testing.assert_allclose(observed, last_solve, rtol=1e-5, atol=1e-6)
    e.close()
