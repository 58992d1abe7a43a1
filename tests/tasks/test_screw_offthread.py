"""The screw task from off the thread (task=screw_offthread): the nut starts above the bolt's tip, not engaged, and
must be aligned and turned onto the thread; the outcome labels say how an episode that did not get there ended.
Insert-then-screw (task=screw_insert) is the same task with the nut started well away from the bolt."""

from __future__ import annotations

import collections
import math

import numpy as np
import pytest

from vitac.api import task_settings
from vitac.envs.gym_env import TaskEnv


def offthread_settings(task: str = "screw_offthread", **randomization) -> dict:
    return task_settings(task, randomization=randomization, observations=["proprio", "peg_state"])


STILL, TIGHTEN = -1.0, 1.0  # the off-thread tasks' rotation action turns only the tightening way (Factory's)


def constant_action_episode(env, seed: int, action: list) -> dict:
    """An episode of one action held throughout: its last step's info."""
    env.reset(seed=seed)
    done, info = False, {}
    while not done:
        _, _, terminated, truncated, info = env.step(np.array(action))
        done = terminated or truncated
    return info


def test_the_nut_starts_above_the_bolts_tip_off_its_axis_with_the_bolt_observed_off_its_place():
    env = TaskEnv(offthread_settings(), seed=0)
    for seed in range(3):
        obs, _ = env.reset(seed=seed)
        task, physics = env.task, env.physics
        assert task.thread_gap(physics) > 0  # not engaged
        factors = task.episode_factors
        assert {"hover", "start_offset", "start_yaw", "bolt_obs_noise"} <= factors.keys()
        assert 0.002 <= factors["hover"] <= 0.005 and np.all(np.abs(factors["start_offset"]) <= 0.002)
        error = task.observed_goal_pos(physics) - task.goal_pos(physics)
        assert np.all(np.abs(error[:2]) <= 0.001) and error[2] == 0 and np.any(error != 0)
        # the policy sees the noisy bolt: the proprio's goal block is the observed one
        np.testing.assert_allclose(obs["proprio"][7:10], task.observed_goal_pos(physics), atol=1e-6)
    env.close()


def test_every_start_has_the_nut_squarely_between_the_pads():
    # Placed exactly on the flats, a pad that MuJoCo saw no contact for closed at full speed into the nut: 6 of these
    # 30 held-out starts began with the nut 4-7 mm off the pads' centre or turned up to 40 deg in the grasp.
    env = TaskEnv(offthread_settings(), seed=0)
    for seed in range(2_000_000, 2_000_030):
        env.reset(seed=seed)
        task, physics = env.task, env.physics
        tcp = task._ids["tcp"]
        hand_yaw = math.atan2(physics.data.site_xmat[tcp][3], physics.data.site_xmat[tcp][0])
        closing = np.array([-math.sin(hand_yaw), math.cos(hand_yaw)])  # the fingers close along the hand's y axis
        off_centre = (task.nut_pos(physics) - physics.data.site_xpos[tcp])[:2] @ closing
        # A flat faces each pad: the nut's yaw is the hand's modulo 60 deg.
        twist = (task.nut_yaw(physics) - hand_yaw + math.pi / 6) % (math.pi / 3) - math.pi / 6
        assert abs(off_centre) < 0.0005 and abs(math.degrees(twist)) < 2.0, (seed, off_centre, math.degrees(twist))
    env.close()


@pytest.mark.parametrize("seed", [0, 1])
def test_a_pure_push_without_turning_ends_on_the_crest(seed):
    # Centred on the bolt, the nut pressed straight down at full action never passes the bolt's thread.
    env = TaskEnv(offthread_settings(start_offset_low=[0.0, 0.0], start_offset_high=[0.0, 0.0], grasp_offset=[0, 0]),
                  seed=seed)
    assert env.task.config.unidirectional_rotation
    info = constant_action_episode(env, seed, [0.0, 0.0, -1.0, 0.0, 0.0, STILL])
    assert info["outcome"] == "jammed on the crest" and info["turns_to_go"] > 0.5  # seated: within 0.375
    env.close()


@pytest.mark.parametrize(("offset", "seats"), [(0.001, True), (0.003, False)])
def test_a_nut_offset_past_the_threads_capture_range_does_not_seat(offset, seats):
    # The bolt's tip guides a nut 1 mm off its axis onto the thread (1.5 mm did too, 2026-12-05); 3 mm off it never is.
    env = TaskEnv(offthread_settings(start_offset_low=[offset, 0.0], start_offset_high=[offset, 0.0], grasp_offset=[0, 0]),
                  seed=0)
    label = constant_action_episode(env, 0, [0.0, 0.0, -0.1, 0.0, 0.0, TIGHTEN])["outcome"]  # turn and press, never centre
    env.close()
    assert (label == "threaded on and seated") == seats, label


def test_a_nut_tilted_in_the_grasp_starts_tilted_and_past_the_threads_capture_range_jams_rather_than_seats():
    tilt = math.radians(4.0)  # the oracle seats 10 of 10 at 0.5 deg, 6 of 10 at 1 deg, none at 4 (2026-12-05)
    env = TaskEnv(offthread_settings(grasp_tilt=[tilt, tilt]), seed=0)
    for seed in (0, 1):
        env.reset(seed=seed)
        assert env.task.outcome(env.physics)["nut_tilt"] == pytest.approx(tilt, abs=math.radians(0.3))
        assert env.run_oracle_episode(seed=seed)["outcome"] in {"jammed on the crest", "cross-threaded"}
    env.close()


def oracle_outcomes(episodes: int, task: str = "screw_offthread", **settings) -> collections.Counter:
    env = TaskEnv(dict(offthread_settings(task), **settings), seed=0)
    outcomes = collections.Counter(env.run_oracle_episode(seed=2_000_000 + k)["outcome"] for k in range(episodes))
    env.close()
    return outcomes


def test_the_oracle_aligns_the_nut_finds_the_thread_and_threads_it_on_with_each_failure_labelled():
    outcomes = oracle_outcomes(20)
    assert outcomes["threaded on and seated"] >= 18, outcomes  # 20 of these 20 on 2026-12-06, 100 of 100 (docs/screw.md)
    assert set(outcomes) <= {"threaded on and seated", "jammed on the crest", "on the thread, not down yet",
                             "cross-threaded", "missed the bolt", "slipped in the grasp", "fell off the bolt"}


def test_with_both_rotation_ways_open_the_oracle_turns_the_nut_to_the_threads_phase_and_threads_it_on():
    outcomes = oracle_outcomes(5, unidirectional_rotation=False)
    assert outcomes["threaded on and seated"] >= 4, outcomes  # 99 of 100 on 2026-12-05 (docs/screw.md)


def test_insert_then_screw_starts_the_nut_well_away_from_the_bolt_and_the_oracle_brings_it_over_and_threads_it_on():
    env = TaskEnv(offthread_settings("screw_insert"), seed=0)
    for seed in range(3):
        env.reset(seed=seed)
        factors = env.task.episode_factors
        assert 0.015 <= factors["hover"] <= 0.03 and np.all(np.abs(factors["start_offset"]) <= 0.03)
        assert env.task.thread_gap(env.physics) > 0.015
    env.close()
    outcomes = oracle_outcomes(6, "screw_insert")
    assert outcomes["threaded on and seated"] >= 5, outcomes  # 6 of these 6 on 2026-12-06, 100 of 100 (docs/screw.md)


@pytest.mark.slow
@pytest.mark.parametrize("task", ["screw_offthread", "screw_insert"])
def test_the_oracle_threads_on_at_least_95_of_100_held_out_episodes(task):
    outcomes = oracle_outcomes(100, task)
    assert outcomes["threaded on and seated"] >= 95, outcomes


def episode_return(env, seed: int, action: list) -> tuple[float, dict]:
    env.reset(seed=seed)
    total, done, info = 0.0, False, {}
    while not done:
        _, reward, terminated, truncated, info = env.step(np.array(action))
        total, done = total + reward, terminated or truncated
    return total, info


@pytest.mark.parametrize("charged", [False, True])
def test_knocking_the_nut_off_the_bolt_pays_only_without_the_failure_charge(charged):
    """The reward is below 0 at every step, so an episode a failure ends early collects less of it than one held
    still to the time limit, unless the failure is charged with its reward for every step left (the off-thread
    default): PPO's first off-thread policy learned exactly that, knocking the nut off the bolt in every episode."""
    settings = offthread_settings()
    settings["charge_failures_to_time_limit"] = charged
    env = TaskEnv(settings, seed=0)
    held, held_info = episode_return(env, 0, [0, 0, 0, 0, 0, STILL])
    knocked, knocked_info = episode_return(env, 0, [1, 0, -1, 0, 0, STILL])  # sideways and down, past the bolt
    env.close()
    assert held_info["outcome"] == "missed the bolt" and knocked_info["outcome"] == "fell off the bolt"
    assert (knocked < held) == charged
