"""A second task written the way a user adds one: a box part into a box hole, defined only in this file (a config,
two props and a task on the shared base), trained for one smoke iteration and evaluated, with no change to
vitac/sim, vitac/algos or the entry points."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest
from dm_control import composer, mjcf
from omegaconf import OmegaConf, open_dict

from tests.conftest import compose_config
from vitac.envs.gym_env import TaskEnv
from vitac.evaluate import evaluate
from vitac.sim import collision
from vitac.sim.poses import DOWN
from vitac.sim.tactile import box
from vitac.tasks.base import GraspedPartTask
from vitac.tasks.config import GraspTaskConfig, ObservationSpec
from vitac.training import train

HALF, LENGTH, HOLE_HALF, WALL = 0.008, 0.05, 0.0095, 0.006


class Box(composer.Entity):
    def _build(self):
        self._mjcf_root = mjcf.RootElement(model="box")
        self.body = self._mjcf_root.worldbody.add("body", name="body")
        self.geom = self.grasp_geom = self.body.add(
            "geom", name="geom", type="box", size=(HALF, HALF, 0.5 * LENGTH), pos=(0, 0, 0.5 * LENGTH),
            density=2000, contype=collision.PEG | collision.PEG_GRASP, conaffinity=collision.PEG_AFFINITY, condim=4)

    @property
    def mjcf_model(self):
        return self._mjcf_root


class BoxHole(composer.Entity):
    def _build(self):
        self._mjcf_root = mjcf.RootElement(model="box_hole")
        self.body = self._mjcf_root.worldbody.add("body", name="body")
        common = dict(type="box", contype=collision.WORLD, conaffinity=collision.WORLD_AFFINITY)
        self.body.add("geom", name="floor", size=(0.03, 0.03, 0.002), pos=(0, 0, -0.002), **common)
        for k, (sx, sy, px, py) in enumerate([(WALL, 0.03, HOLE_HALF + WALL, 0), (WALL, 0.03, -HOLE_HALF - WALL, 0),
                                              (HOLE_HALF, WALL, 0, HOLE_HALF + WALL), (HOLE_HALF, WALL, 0, -HOLE_HALF - WALL)]):
            self.body.add("geom", name=f"wall_{k}", size=(sx, sy, 0.01), pos=(px, py, 0.01), **common)

    @property
    def mjcf_model(self):
        return self._mjcf_root


@dataclass
class BoxConfig(GraspTaskConfig):
    TASK = f"{__name__}.BoxTask"
    episode_steps: int = 12

    def task_observation_specs(self):
        return dict(proprio=ObservationSpec((6,)), critic_state=ObservationSpec((6,), critic_only=True))


class BoxTask(GraspedPartTask):
    def _build_parts(self):
        self.held_shape = box(HALF, HALF, LENGTH)
        self._attach_parts(Box(), BoxHole())

    def initialize_episode(self, physics, random_state):
        ids = self._ids
        physics.data.mocap_pos[ids["fixed_mocap"]] = (0.5 + random_state.uniform(-0.01, 0.01), 0.0, 0.0)
        pos = np.array([0.5, 0.0, 0.08])
        physics.data.qpos[:] = physics.model.qpos0
        physics.data.qvel[:] = 0.0
        physics.data.qpos[ids["hand_qpos"]] = physics.data.ctrl[ids["hand_act"]] = np.concatenate([pos, np.zeros(3)])
        part_pos = pos + DOWN @ np.array([0.0, 0.0, 0.035])  # its bottom 35 mm below the fingertips
        physics.data.qpos[ids["held_qpos"]:ids["held_qpos"] + 7] = np.concatenate([part_pos, [1.0, 0, 0, 0]])
        self._settle_grasp(physics, HALF)

    def keypoint_distance(self, physics):
        return float(np.linalg.norm(physics.data.xpos[self._ids["held_body"]] - self.fixed_pos(physics)))

    def is_success(self, physics):
        return self.keypoint_distance(physics) < 0.004

    def get_reward(self, physics):
        return -self.keypoint_distance(physics)

    def outcome(self, physics):
        return dict(outcome="inserted" if self.is_success(physics) else "not inserted",
                    distance=self.keypoint_distance(physics))

    def _observation_sources(self):
        def proprio(physics):
            return np.concatenate([physics.data.site_xpos[self._ids["tcp"]], self.fixed_pos(physics)]).astype(np.float32)

        def critic_state(physics):
            part = physics.data.xpos[self._ids["held_body"]]
            return np.concatenate([part, self.fixed_pos(physics) - part]).astype(np.float32)

        return dict(proprio=proprio, critic_state=critic_state)


def test_a_new_task_runs_with_the_shared_robot_and_sensors():
    env = TaskEnv(BoxConfig(), seed=0)
    obs, _ = env.reset(seed=0)
    specs = env.config.observation_specs()
    assert list(specs) == ["proprio", "critic_state", "contact_forces", "wrist", "tactile_left", "tactile_right"]
    assert {k: v.shape for k, v in obs.items()} == {k: s.shape for k, s in specs.items()}
    # The pads hold the box after the settle: both squeeze it (normal force) and it stays in the hand.
    raw = env.task.raw_tactiles(env.physics)
    assert (raw[:, 2].max(axis=(1, 2)) > 0).all()
    for _ in range(12):
        obs, reward, terminated, truncated, info = env.step(np.zeros(6))
    assert truncated and not terminated and math.isfinite(reward)
    assert info["outcome"] == "not inserted" and 0.02 < info["distance"] < 0.08
    env.close()


@pytest.mark.parametrize("obs", ["tactile", "wrist_tactile"])
def test_a_new_task_trains_one_smoke_iteration_and_evaluates(obs, tmp_path):
    fusion = "cmt" if obs == "wrist_tactile" else "naive"
    cfg = compose_config(["preset=smoke", f"obs={obs}", f"fusion={fusion}", "reg=sym", "trainer.iterations=1"],
                         output_dir=tmp_path / "run")
    with open_dict(cfg):
        cfg.task = OmegaConf.create({k: v for k, v in BoxConfig().to_dict().items() if k != "observations"})
    run = train(cfg)
    assert run["metrics"]["charts/env_steps"] == 32 and math.isfinite(run["metrics"]["losses/loss"])
    report = evaluate(run["checkpoint"], episodes=2, num_envs=2, num_workers=0, seed=5, out=str(tmp_path / "e.json"))
    assert report["episodes"] == 2 and sum(report["outcomes"].values()) == 2
    assert {e["outcome"] for e in report["final_state"]} <= {"inserted", "not inserted"}
