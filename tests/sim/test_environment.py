"""The shared simulation: the lean control step against composer's, and the hand's pose helpers."""

from __future__ import annotations

import numpy as np
import pytest

from vitac.envs.gym_env import TaskEnv
from vitac.tasks.insertion.config import InsertionConfig


def test_lean_control_step_gives_composers_trajectory_and_observations_bit_for_bit():
    from dm_control import composer

    from vitac.sim.environment import LeanEnvironment
    from vitac.tasks.insertion.task import InsertionTask

    settings = InsertionConfig.from_dict({"observations": ["proprio", "critic_state"]})
    kwargs = dict(random_state=3, time_limit=float("inf"), strip_singleton_obs_buffer_dim=True,
                  raise_exception_on_physics_error=False, recompile_mjcf_every_episode=False)
    ours, composers = (cls(InsertionTask(settings), **kwargs) for cls in (LeanEnvironment, composer.Environment))
    rng = np.random.default_rng(0)
    ours.reset()
    composers.reset()
    # The critic state's contact forces differ by design: ours are the last substep's solve, composer's a
    # solve for the final state (test_contact_forces_are_the_last_substeps_solve_and_a_fresh_one_after_reset).
    forces = slice(-13, -4)  # before the peg-to-socket offset (3) and the keypoint distance (1)
    for t in range(300):  # random and straight-down actions, across an episode's end and reset
        action = rng.uniform(-1, 1, 6) if t % 2 else np.array([0, 0, -1.0, 0, 0, 0])
        a, b = ours.step(action), composers.step(action)
        assert a.step_type == b.step_type and a.reward == b.reward
        for k in a.observation:
            if k == "critic_state":
                a.observation[k][forces] = b.observation[k][forces] = 0.0
            np.testing.assert_array_equal(a.observation[k], b.observation[k])
    np.testing.assert_array_equal(ours.physics.get_state(), composers.physics.get_state())
    ours.close()
    composers.close()


def test_lean_control_step_refuses_substep_hooks_and_buffered_observables():
    from vitac.sim.environment import LeanEnvironment
    from vitac.tasks.insertion.task import InsertionTask

    env = LeanEnvironment(InsertionTask(InsertionConfig.from_dict({"observations": ["proprio"]})))
    with pytest.raises(ValueError, match="hook_name='after_substep' is not allowed"):
        env.add_extra_hook("after_substep", lambda physics, random_state: None)
    env.close()
    task = InsertionTask(InsertionConfig.from_dict({"observations": ["proprio"]}))
    task.observables["proprio"].buffer_size = 3
    with pytest.raises(ValueError, match=r"buffer, delay or transform observables \['proprio'\]"):
        LeanEnvironment(task)


def test_rotation_helpers_match_scipy_and_an_action_turns_the_hand_about_world_axes():
    from scipy.spatial.transform import Rotation

    from vitac.sim.poses import DOWN, axis_angle_matrix, euler_zyx_from_matrix, matrix_from_euler_zyx

    rng = np.random.default_rng(0)
    for _ in range(50):
        rotvec, euler = rng.normal(size=3) * 0.5, rng.uniform(-1.2, 1.2, 3)
        np.testing.assert_allclose(axis_angle_matrix(rotvec), Rotation.from_rotvec(rotvec).as_matrix(), atol=1e-12)
        matrix = matrix_from_euler_zyx(*euler)
        np.testing.assert_allclose(matrix, Rotation.from_euler("ZYX", euler).as_matrix(), atol=1e-12)
        np.testing.assert_allclose(euler_zyx_from_matrix(matrix), euler, atol=1e-12)
    # The rotation part of an action is an axis-angle delta in the world frame applied to the hand's orientation.
    e = TaskEnv({"observations": ["proprio"]}, seed=0)
    e.reset(seed=4)
    task, physics = e.task, e.physics
    action = np.array([0.0, 0.0, 0.0, 0.7, -0.4, 0.9])
    hinges = physics.data.qpos[task._ids["hand_qpos"]][3:].copy()
    task.before_step(physics, action, None)
    target = physics.data.ctrl[task._ids["hand_act"]][3:]
    expected = axis_angle_matrix(action[3:] * task.config.rot_action_scale) @ DOWN @ matrix_from_euler_zyx(*hinges)
    np.testing.assert_allclose(DOWN @ matrix_from_euler_zyx(*target), expected, atol=1e-12)
    e.close()
