"""Environment tier: the composer task, its gymnasium adapters, the oracle and the sensors in simulation."""

from __future__ import annotations

import json
from dataclasses import asdict

import numpy as np
import pytest

from vitac.envs.gym_env import TaskEnv
from vitac.tasks.insertion.config import InsertionConfig, Randomization

ALL = ["proprio", "peg_state", "contact_forces", "wrist", "tactile_left", "tactile_right", "critic_state"]


@pytest.fixture(scope="module")
def env():
    e = TaskEnv({"observations": ALL}, seed=0)
    yield e
    e.close()


def test_observations_match_spaces(env):
    obs, info = env.reset(seed=1)
    assert set(obs) == set(ALL)
    for k, v in obs.items():
        assert env.observation_space[k].contains(v), k
    assert obs["wrist"].dtype == np.uint8 and obs["wrist"].shape == (3, 64, 64)
    assert obs["tactile_left"].shape == (3, 32, 32)
    assert obs["wrist"].std() > 5, "the wrist camera sees a scene, not a blank frame"


def test_vector_observations_end_with_their_offset_to_the_socket(env):
    obs, _ = env.reset(seed=5)
    for _ in range(3):
        obs, *_ = env.step(np.full(6, 0.3))
    task, physics = env.task, env.physics
    seen_socket = obs["proprio"][7:10]
    assert np.allclose(seen_socket, task.socket_pos(physics) + task._socket_noise, atol=1e-6)
    assert np.abs(task._socket_noise).max() > 0, "the actor sees the noisy socket position"
    assert np.allclose(obs["proprio"][-3:], seen_socket - obs["proprio"][:3], atol=1e-6)
    assert np.allclose(obs["peg_state"][-3:], seen_socket - obs["peg_state"][:3], atol=1e-6)
    # The critic's offset is to the true socket, and it ends with the keypoint distance the reward uses.
    critic = obs["critic_state"]
    assert np.allclose(critic[-4:-1], task.socket_pos(physics) - obs["peg_state"][:3], atol=1e-6)
    assert critic[-1] == pytest.approx(task.keypoint_distance(physics), abs=1e-6)


def test_reset_keeps_the_compiled_model():
    # The task randomizes model fields in place and never edits the MJCF: recompiling it at each reset
    # (composer's default) would only cost ~25 ms an episode.
    e = TaskEnv({"observations": ["proprio"]}, seed=0)
    e.reset(seed=0)
    model = e.physics.model.ptr
    e.reset(seed=1)
    assert e.physics.model.ptr is model
    e.close()


def test_episode_ends_by_truncation_after_255_steps(env):
    env.reset(seed=2)
    for step in range(255):
        _, reward, terminated, truncated, info = env.step(np.zeros(6))
        assert np.isfinite(reward)
        if step < 254:
            assert not (terminated or truncated)
    assert truncated and not terminated
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(6))


def test_same_seed_same_episode():
    a, b = TaskEnv({"observations": ["proprio"]}, seed=0), TaskEnv({"observations": ["proprio"]}, seed=0)
    oa, _ = a.reset(seed=11)
    ob, _ = b.reset(seed=11)
    rng = np.random.default_rng(0)
    for _ in range(20):
        act = rng.uniform(-1, 1, 6)
        oa, ra, *_ = a.step(act)
        ob, rb, *_ = b.step(act)
    np.testing.assert_array_equal(oa["proprio"], ob["proprio"])
    assert ra == rb
    a.close()
    b.close()


def test_keypoint_distance_is_the_mean_distance_between_matching_keypoints():
    from scipy.spatial.transform import Rotation

    from vitac.tasks.insertion.task import keypoint_offsets, mean_keypoint_distance

    rng = np.random.default_rng(1)
    offsets = keypoint_offsets(4, 0.5)
    for _ in range(20):
        peg_pos, goal_pos = rng.normal(size=3) * 0.05, rng.normal(size=3) * 0.05
        peg_rot = Rotation.from_rotvec(rng.normal(size=3) * 0.3).as_matrix()
        peg_points = peg_pos + offsets[:, None] * peg_rot[:, 2]
        goal_points = goal_pos + offsets[:, None] * np.array([0.0, 0.0, 1.0])
        expected = np.linalg.norm(peg_points - goal_points, axis=1).mean()
        assert mean_keypoint_distance(peg_pos, peg_rot.ravel(), goal_pos, offsets) == pytest.approx(expected, rel=1e-12)


def test_state_round_trip_continues_exactly():
    e = TaskEnv({"observations": ["proprio", "tactile_left", "contact_forces"]}, seed=0)
    e.reset(seed=5)
    for _ in range(10):
        e.step(np.full(6, 0.3))
    state, saved = e.get_state(), e.observation()
    ref = [e.step(np.full(6, -0.2))[0]["proprio"] for _ in range(5)]
    e.set_state(state)
    restored = e.observation()
    for k in saved:  # the contact forces too: the last substep's solve travels with the state
        np.testing.assert_array_equal(restored[k], saved[k])
    again = [e.step(np.full(6, -0.2))[0]["proprio"] for _ in range(5)]
    e.close()
    np.testing.assert_array_equal(np.array(ref), np.array(again))


def test_a_state_restored_into_a_fresh_environment_continues_bit_for_bit():
    # A fresh environment has no constraint-solver warm start of its own: the state carries MuJoCo's
    # qacc_warmstart, so a resumed run's contacts solve exactly as the uninterrupted run's (without it, every
    # step of these 60 differed).
    for seed in range(3):
        a = TaskEnv({"observations": ["proprio", "contact_forces"]}, seed=seed)
        a.reset(seed=seed)
        rng = np.random.default_rng(seed)
        for _ in range(40):
            a.step(rng.uniform(-1, 1, 6))
        state, actions = a.get_state(), rng.uniform(-1, 1, (60, 6))
        ref = [a.step(x)[:2] for x in actions]
        b = TaskEnv({"observations": ["proprio", "contact_forces"]}, seed=seed + 100)
        b.set_state(state)
        again = [b.step(x)[:2] for x in actions]
        a.close()
        b.close()
        for (obs, reward), (obs_b, reward_b) in zip(ref, again, strict=True):
            assert reward == reward_b
            for k in obs:
                np.testing.assert_array_equal(obs[k], obs_b[k])


def test_oracle_inserts_and_random_policy_does_not():
    e = TaskEnv({"observations": ["proprio"]}, seed=0)
    rng = np.random.default_rng(0)
    oracle_success, random_success = [], []
    for ep in range(4):
        info = e.run_oracle_episode(seed=100 + ep)
        oracle_success.append(info["success"])
        assert info["steps_to_success"] > 0
        e.reset(seed=100 + ep)
        done = False
        while not done:
            _, _, te, tr, info = e.step(rng.uniform(-1, 1, 6))
            done = te or tr
        random_success.append(info["success"])
    e.close()
    assert all(oracle_success) and not any(random_success)


def test_lateral_reward_shaping_subtracts_the_pegs_distance_from_the_hole_axis():
    rewards = []
    for scale in (0.0, 2.0):
        e = TaskEnv({"observations": ["proprio"], "lateral_reward_scale": scale}, seed=0)
        e.reset(seed=5)
        _, reward, *_ = e.step(np.zeros(6))
        task, physics = e.task, e.physics
        offset = np.linalg.norm(physics.data.xpos[task._ids["held_body"]][:2] - task.socket_pos(physics)[:2])
        e.close()
        rewards.append(reward)
    assert offset > 0.01 and rewards[1] == pytest.approx(rewards[0] - 2.0 * offset)
    with pytest.raises(ValueError, match=r"task\.lateral_reward_scale"):
        InsertionConfig.from_dict({"lateral_reward_scale": -1.0})


def test_keypoint_reward_is_tacsls_formula_and_stays_finite_when_the_peg_is_far_away():
    import mujoco

    e = TaskEnv({"observations": ["proprio"], "success_reward_scale": 0.0}, seed=0)
    e.reset(seed=5)
    task, physics = e.task, e.physics
    m, d = physics.model.ptr, physics.data.ptr
    adr = task._ids["held_qpos"]
    for height in (0.03, 0.2, 50.0):  # above the hole (no x10 penalty); 50 m: exp(50 d) overflows a float
        d.qpos[adr:adr + 3] = task.socket_pos(physics) + (0.0, 0.0, height)
        mujoco.mj_forward(m, d)
        distance = task.keypoint_distance(physics)
        with np.errstate(over="ignore"):
            expected = 0.1 * (-distance + 1.0 / (np.exp(-50.0 * distance) + 0.0001 + np.exp(50.0 * distance)))
        assert task.get_reward(physics) == pytest.approx(expected, rel=1e-9) and np.isfinite(task.get_reward(physics))
    e.close()


def test_randomizing_one_factor_only_varies_that_factor_between_episodes():
    only = Randomization().only(["ee_pos"])
    assert only.ee_pos_low == [0.4, -0.1, 0.1] and only.socket_pos_low == only.socket_pos_high == [0.5, 0.0, 0.01]
    assert only.socket_obs_noise == 0.0 and only.peg_in_hand_tilt == [0.0, 0.0]
    assert Randomization().only(["socket_obs_noise"]).socket_obs_noise == 0.005
    e = TaskEnv({"observations": ["proprio"], "randomization": asdict(only)}, seed=0)
    starts = []
    for seed in (1, 2):
        obs, _ = e.reset(seed=seed)
        starts.append(obs["proprio"])
    e.close()
    hand, socket = slice(0, 3), slice(7, 10)  # proprio: tcp position, hand quaternion, observed socket position...
    assert np.abs(starts[0][hand] - starts[1][hand]).max() > 0.005
    np.testing.assert_array_equal(starts[0][socket], starts[1][socket])
    np.testing.assert_allclose(starts[0][socket], [0.5, 0.0, 0.01], atol=1e-6)
    with pytest.raises(ValueError, match="randomize_only"):
        Randomization().only(["ee_position"])


def test_success_reward_is_paid_exactly_at_the_steps_where_the_success_check_holds():
    from vitac.tasks.insertion.oracle import OracleController

    runs = []
    for scale in (0.0, 0.5):
        e = TaskEnv({"observations": ["proprio"], "success_reward_scale": scale}, seed=0)
        e.reset(seed=3)
        oracle, rewards, held = OracleController(e.task), [], []
        for _ in range(150):  # the oracle inserts within ~100 steps (test above)
            _, reward, *_, info = e.step(oracle(e.physics))
            rewards.append(reward)
            held.append(info["keypoint_distance"] < e.task.config.success_threshold)
        e.close()
        runs.append((np.array(rewards), np.array(held)))
    (plain, held), (bonus, held_again) = runs
    np.testing.assert_array_equal(held, held_again)  # the bonus does not change the simulation
    assert held.any() and not held.all()
    np.testing.assert_allclose(bonus - plain, 0.5 * held, atol=1e-12)
    with pytest.raises(ValueError, match=r"task\.success_reward_scale"):
        InsertionConfig.from_dict({"success_reward_scale": -0.1})


def test_diverged_physics_ends_the_episode_as_a_failed_termination():
    e = TaskEnv({"observations": ["proprio"]}, seed=0)
    e.reset(seed=1)
    e.step(np.zeros(6))
    e.physics.data.qvel[:] = 1e12  # what a blown-up contact leaves behind
    _, reward, terminated, truncated, info = e.step(np.zeros(6))
    assert terminated and not truncated and reward == 0.0
    assert info["outcome"] == "physics diverged" and not info["success"]
    obs, _ = e.reset(seed=1)  # and the next episode is healthy
    _, _, terminated, _, _ = e.step(np.zeros(6))
    e.close()
    assert np.isfinite(obs["proprio"]).all() and not terminated


def test_env_refuses_bad_config_at_construction():
    with pytest.raises(ValueError, match=r"task\.peg_shape='star'"):
        TaskEnv({"peg_shape": "star"})
    with pytest.raises(ValueError, match=r"task\.socket_contact_timeconst=0\.001 .*2 physics timesteps"):
        TaskEnv({"socket_contact_timeconst": 0.001})
    with pytest.raises(ValueError, match=r"task\.randomization\.bogus"):
        InsertionConfig.from_dict({"randomization": {"bogus": 1}})


@pytest.mark.parametrize("shape,size", [("rectangular", 16), ("round", 8), ("round", 12)])
def test_other_pegs_build_and_oracle_inserts(shape, size):
    e = TaskEnv({"observations": ["proprio"], "peg_shape": shape, "peg_size": size}, seed=0)
    info = e.run_oracle_episode(seed=21)
    e.close()
    assert info["success"], info


def test_observed_socket_oracle_aims_at_the_noisy_socket():
    from vitac.tasks.insertion.oracle import OracleController

    env = TaskEnv({"observations": ["proprio"], "pos_action_scale": 1.0}, seed=0)  # 1 m: nothing clips
    env.reset(seed=7)
    task, physics = env.task, env.physics
    peg_xy = physics.data.xpos[task._ids["held_body"]][:2]
    true_xy = OracleController(task)(physics)[:2]
    seen_xy = OracleController(task, observed_socket=True)(physics)[:2]
    scale = task.config.pos_action_scale
    expected_true = np.clip((task.socket_pos(physics)[:2] - peg_xy) / scale, -1, 1)
    expected_seen = np.clip((task.observed_socket_pos(physics)[:2] - peg_xy) / scale, -1, 1)
    env.close()
    assert np.allclose(true_xy, expected_true) and np.allclose(seen_xy, expected_seen)
    assert np.abs(seen_xy - true_xy).max() > 1e-4


@pytest.mark.slow
def test_oracle_success_over_200_episodes_is_at_least_95_percent():
    e = TaskEnv({"observations": ["proprio"]}, seed=0)
    successes = [e.run_oracle_episode(seed=s)["success"] for s in range(200)]
    e.close()
    assert np.mean(successes) >= 0.95


def test_evaluate_runs_the_scripted_oracle_and_random_actions_on_any_task_settings(tmp_path):
    from vitac.evaluate import evaluate_scripted

    oracle = evaluate_scripted("oracle", {"peg_size": 12}, episodes=2, seed=3, out=tmp_path / "o.json")
    assert oracle["success_rate"] == 1.0 and oracle["outcomes"] == {"inserted": 2}
    assert json.loads((tmp_path / "o.json").read_text())["policy"] == "oracle"
    random = evaluate_scripted("random", {}, episodes=1, seed=3, out=tmp_path / "r.json")
    assert random["success_rate"] == 0.0 and len(random["final_state"]) == 1
    with pytest.raises(ValueError, match=r"policy='scripted' is not allowed: expected one of \['ckpt', 'oracle', 'random'\]"):
        evaluate_scripted("scripted", {}, episodes=1, seed=0, out=tmp_path / "x.json")
