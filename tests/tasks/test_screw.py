"""The screw task: threads that behave as threads, Factory's episode, sensing, the oracle and exact state."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vitac.envs.gym_env import TaskEnv
from vitac.tasks import make_task_config
from vitac.tasks.screw import props
from vitac.tasks.screw.oracle import OracleController
from vitac.utils.checks import ConfigError

ALL = ["proprio", "peg_state", "contact_forces", "wrist", "tactile_left", "tactile_right", "critic_state"]
SCREW = "vitac.tasks.screw.config.ScrewConfig"


def screw_env(observations=("proprio", "peg_state"), **settings) -> TaskEnv:
    return TaskEnv({"_target_": SCREW, "observations": list(observations), **settings}, seed=0)


@pytest.fixture(scope="module")
def env():
    e = screw_env(ALL)
    yield e
    e.close()


class NutTracker:
    """The nut's height above its goal and its yaw unwrapped over steps (rad, positive counter-clockwise)."""

    def __init__(self, env: TaskEnv):
        self.env, self.turned = env, 0.0
        self.height0, self._yaw = self.height, self.yaw

    @property
    def height(self) -> float:
        task, physics = self.env.task, self.env.physics
        return float(task.nut_pos(physics)[2] - task.goal_pos(physics)[2])

    @property
    def yaw(self) -> float:
        xmat = self.env.physics.data.xmat[self.env.task._ids["held_body"]]
        return math.atan2(xmat[3], xmat[0])

    def update(self) -> None:
        yaw = self.yaw
        self.turned += (yaw - self._yaw + math.pi) % (2 * math.pi) - math.pi
        self._yaw = yaw

    @property
    def thread_phase(self) -> float:
        """Height change less what the turning explains: constant while the threads stay engaged (m)."""
        return (self.height - self.height0) - props.PITCH * self.turned / (2 * math.pi)


def test_thread_geometry_matches_docs_table():
    # docs/screw.md's table: 0.10 mm of play between neighbouring capsules, more than a 24-capsule turn's chord sags
    # (so the nut turns freely), and 0.72 mm of radial overlap, more than the 0.2 mm the bolt's core lets the nut
    # move sideways (so it cannot be pulled straight off).
    sag = props.NUT_THREAD_RADIUS * (1 - math.cos(math.pi / make_task_config({"_target_": SCREW}).segments_per_turn))
    overlap = 2 * props.THREAD_TUBE - (props.NUT_THREAD_RADIUS - props.BOLT_THREAD_RADIUS)
    lateral_play = props.NUT_THREAD_RADIUS - props.THREAD_TUBE - props.BOLT_CORE_RADIUS
    assert props.THREAD_CLEARANCE == pytest.approx(0.10e-3, abs=0.005e-3)
    assert sag == pytest.approx(0.066e-3, abs=0.005e-3) and sag < props.THREAD_CLEARANCE
    assert overlap == pytest.approx(0.72e-3) and lateral_play == pytest.approx(0.2e-3) and overlap > lateral_play
    assert props.BOLT_THREAD_RADIUS + props.THREAD_TUBE == pytest.approx(0.008)  # crest at the M16 major radius


def test_one_revolution_advances_one_pitch():
    e = screw_env()
    e.reset(seed=3)
    oracle, nut = OracleController(e.task), NutTracker(e)
    while nut.turned > -2 * math.pi:
        _, _, terminated, truncated, info = e.step(oracle(e.physics))
        nut.update()
        assert not (terminated or truncated), info
    advance = (nut.height0 - nut.height) * 2 * math.pi / -nut.turned  # per exact revolution
    assert advance == pytest.approx(props.PITCH, rel=0.10)
    e.close()


def test_pulled_straight_up_the_nut_stays_on_the_thread():
    e = screw_env()
    e.reset(seed=4)
    nut = NutTracker(e)
    nut_body = e.task._ids["held_body"]
    # Pull by the hand (the z action's full step up), then with 20 N on the nut itself (about 65 times its weight).
    for step in range(120):
        if step == 60:
            e.physics.data.xfrc_applied[nut_body, 2] = 20.0
        _, _, terminated, truncated, info = e.step(np.array([0, 0, 1.0, 0, 0, 0]))
        nut.update()
        if terminated or truncated:
            break
    assert abs(nut.turned) < 0.2, "pulling did not turn the nut"
    assert nut.height - nut.height0 < 0.0005, "the nut rose only by the thread's play"
    assert abs(nut.thread_phase) < 0.0005
    e.close()


def _random_action_episodes(episodes: int, seed: int = 0) -> int:
    """Random-action episodes checked at every step: no NaN, no divergence, no thread skipped or crossed (the
    height stays what the turning explains) and the nut on the bolt's axis within its play. Returns the steps."""
    e = screw_env()
    rng = np.random.default_rng(seed)
    steps = 0
    for episode in range(episodes):
        e.reset(seed=seed * 100_000 + episode)
        nut, done = NutTracker(e), False
        while not done:
            _, reward, terminated, truncated, info = e.step(rng.uniform(-1, 1, 6))
            steps += 1
            nut.update()
            done = terminated or truncated
            assert np.isfinite(reward) and np.all(np.isfinite(e.physics.data.qpos)), (episode, steps)
            assert abs(nut.thread_phase) < 0.0005, (episode, steps, nut.thread_phase)
            assert info["keypoint_distance"] < 0.1
        assert info["outcome"] != "physics diverged", episode
        assert info["nut_offset_xy"] < 0.001, episode
    e.close()
    return steps


def test_random_actions_keep_the_threads_engaged_and_the_state_finite():
    assert _random_action_episodes(8) >= 2000


@pytest.mark.slow
def test_two_thousand_random_action_episodes():
    # MuJoCo issues report segfaults and penetration with SDF nuts and bolts under some settings: this model
    # is checked over 2,000 episodes (about 600,000 steps; ~25 min on one core).
    assert _random_action_episodes(2000, seed=1) > 0


def test_oracle_screws_the_nut_down(env):
    for seed in range(3):
        info = env.run_oracle_episode(seed=seed)
        assert info["success"] and info["outcome"] == "screwed down", info
        assert info["turns_to_go"] < 2.0
        assert 0 < info["steps_to_success"] < env.config.episode_steps


def test_success_and_failure_terminate_and_the_time_limit_truncates():
    e = screw_env(episode_steps=20)
    e.reset(seed=0)
    for _ in range(20):
        _, _, terminated, truncated, info = e.step(np.zeros(6))
    assert truncated and not terminated and info["outcome"] == "on the thread, not down yet"
    e.reset(seed=0)
    e.task._hold_target[:2] += 0.05  # the hand pulled 7 cm sideways: the nut slips out of the grasp or off the bolt
    done = False
    while not done:
        _, _, terminated, truncated, info = e.step(np.zeros(6))
        done = terminated or truncated
    assert terminated and info["outcome"] in ("slipped in the grasp", "fell off the bolt"), info
    e.close()


def test_observations_match_spaces_and_the_pads_feel_the_nut(env):
    obs, _ = env.reset(seed=1)
    assert set(obs) == set(ALL)
    for k, v in obs.items():
        assert env.observation_space[k].contains(v), k
    raw = env.task.raw_tactiles(env.physics)
    assert raw[0, 2].max() > 0 and raw[1, 2].max() > 0, "both pads press on the nut's flats"
    assert obs["wrist"].std() > 5
    task, physics = env.task, env.physics
    goal, nut = task.goal_pos(physics), task.nut_pos(physics)
    assert np.allclose(obs["proprio"][-3:], goal - obs["proprio"][:3], atol=1e-6)
    assert np.allclose(obs["peg_state"][:3], nut, atol=1e-6)
    assert np.allclose(obs["critic_state"][-4:-1], goal - nut, atol=1e-6)


def test_policy_drives_only_the_configured_axes():
    e = screw_env()
    e.reset(seed=2)
    tcp0 = e.physics.data.site_xpos[e.task._ids["tcp"]].copy()
    for _ in range(10):
        e.step(np.array([1.0, 1.0, 0.0, 1.0, 1.0, 0.0]))  # only the ignored axes
    tcp = e.physics.data.site_xpos[e.task._ids["tcp"]]
    assert np.abs(tcp - tcp0).max() < 0.0005
    e.close()


def test_unidirectional_rotation_only_tightens():
    e = screw_env(unidirectional_rotation=True)
    e.reset(seed=2)
    nut = NutTracker(e)
    for _ in range(30):
        e.step(np.array([0, 0, 0, 0, 0, -1.0]))  # the loosening end of the action: no turn at all
        nut.update()
    assert abs(nut.turned) < 0.05
    for _ in range(30):
        e.step(np.array([0, 0, 0, 0, 0, 1.0]))
        nut.update()
    assert nut.turned < -0.5, "the other end tightens (clockwise seen from above)"
    e.close()


def test_state_round_trip_is_exact(env):
    env.reset(seed=7)
    for _ in range(5):
        env.step(np.array([0, 0, -0.1, 0, 0, -1.0]))
    state = env.get_state()
    after = [env.step(np.array([0, 0, -0.1, 0, 0, -1.0]))[:2] for _ in range(3)]
    env.set_state(state)
    again = [env.step(np.array([0, 0, -0.1, 0, 0, -1.0]))[:2] for _ in range(3)]
    for (obs_a, r_a), (obs_b, r_b) in zip(after, again, strict=True):
        assert r_a == r_b
        for k in obs_a:
            assert np.array_equal(obs_a[k], obs_b[k]), k


@pytest.mark.parametrize(("key", "value"), [("action_axes", [0, 0, 0, 0, 0, 0]), ("segments_per_turn", 4),
                                            ("success_pitches", 0), ("randomization", {"start_turns": [1.0, 3.0]}),
                                            ("randomization", {"grasp_depth": [0.0, 0.03]})])
def test_bad_values_are_refused_by_name(key, value):
    with pytest.raises(ConfigError, match=f"task.{key}"):
        make_task_config({"_target_": SCREW, key: value})


def test_the_papers_screw_policies_train_and_distil_and_a_teacher_of_another_task_is_refused(tmp_path):
    import torch

    from tests.conftest import compose_config
    from vitac.training import train

    teacher = train(compose_config(["preset=smoke", "experiment=screw/privileged_contact"], output_dir=tmp_path / "t"))
    for row in ("tactile", "wrist"):
        student = train(compose_config(["preset=smoke", f"experiment=screw/{row}", f"teacher_ckpt={teacher['checkpoint']}"],
                                       output_dir=tmp_path / row))
        assert math.isfinite(student["metrics"]["losses/action_mse"])
    checkpoint = torch.load(teacher["checkpoint"], weights_only=False)
    checkpoint["vitac_config"]["task"]["_target_"] = "vitac.tasks.insertion.config.InsertionConfig"
    checkpoint["vitac_config"]["task"] = {k: v for k, v in checkpoint["vitac_config"]["task"].items()
                                          if k in ("_target_", "episode_steps", "observations")}
    torch.save(checkpoint, tmp_path / "insertion_teacher.ckpt")
    with pytest.raises(ValueError, match="trained on vitac.tasks.insertion.config.InsertionConfig"):
        train(compose_config(["preset=smoke", "experiment=screw/tactile", f"teacher_ckpt={tmp_path / 'insertion_teacher.ckpt'}"],
                             output_dir=tmp_path / "refused"))
