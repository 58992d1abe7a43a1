"""Nut-on-bolt screwing as a dm_control composer Task (Factory's NutBoltScrew on the shared robot and sensors)."""

from __future__ import annotations

import functools
import math

import mujoco
import numpy as np

from vitac.sim.gripper import PAD_LENGTH
from vitac.sim.poses import axis_angle_matrix
from vitac.tasks.base import GraspedPartTask
from vitac.tasks.insertion.task import keypoint_offsets
from vitac.tasks.screw import props
from vitac.tasks.screw.config import ScrewConfig, thread_yaw

ROTATION_AXIS = 5  # the action's world z-rotation component (negative: tightening, clockwise seen from above)
ACTION_OF_JOINT = [0, 1, 2, 5, 4, 3]  # the hand's joints (x, y, z, yaw, pitch, roll) against the action's axes
# A nut on the thread tilted past this (rad) has its thread across the bolt's: an engaged one has 0.2 mm of play.
CROSS_THREAD_TILT = math.radians(3.0)
# How far (m) inside the flats the pads start off the thread. Placed exactly on them, a pad whose flat MuJoCo reports no
# contact with at the first step closes freely at full speed and tunnels into the nut: 18 of 100 off-thread starts
# began with the nut 4-7 mm off the pads' centre or turned up to 40 deg in the grasp. The engaged start, its nut held
# by the thread, never did (0 of 100) and keeps its episodes as they were.
OFF_THREAD_SQUEEZE = 0.0001


class ScrewTask(GraspedPartTask):
    """Screw a grasped nut down a fixed bolt; Factory's actions, reward, success and failures.

    The episode ends at success (the nut within `success_pitches` thread pitches of resting on the bolt's
    head) or failure (the nut slipped in the grasp, fell off the bolt or moved `far_distance` away), both
    terminations, or at the time limit, a truncation.

    Args:
        config: validated task settings.
        offscreen_size: offscreen render buffer (pixels); the camera size unless a tool renders larger views.
    """

    config: ScrewConfig

    def __init__(self, config: ScrewConfig, offscreen_size: int | None = None):
        self._keypoints = keypoint_offsets(config.num_keypoints, config.keypoint_length)
        self._axes = np.asarray(config.action_axes, bool)
        self._held_joints = ~self._axes[ACTION_OF_JOINT]
        self._hold_target = np.zeros(6)
        self._bolt_noise = np.zeros(3)  # this episode's error of the bolt's observed position
        # The nut's thread starts this far above its bottom: it meets the bolt's when the nut's bottom is this far
        # below the bolt's tip.
        self._thread_margin = 0.5 * (props.NUT_HEIGHT - config.nut_thread_turns * props.PITCH)
        super().__init__(config, offscreen_size)

    def _build_parts(self):
        config = self.config
        self.nut = props.Nut(friction=config.nut_friction, segments_per_turn=config.segments_per_turn,
                             thread_turns=config.nut_thread_turns)
        self.bolt = props.Bolt(friction=config.bolt_friction, contact_timeconst=config.bolt_contact_timeconst,
                               segments_per_turn=config.segments_per_turn)
        self.held_shape = self.nut.contact_shape()
        self._attach_parts(self.nut, self.bolt)

    def initialize_episode(self, physics, random_state):
        r, ids = self.config.randomization, self._ids
        self.episode_factors = {}
        sample = functools.partial(self._draw, random_state)  # sample(factor name, low, high)
        bolt = np.concatenate([sample("bolt_pos", r.bolt_pos_low, r.bolt_pos_high), [0.0]])
        physics.data.mocap_pos[ids["fixed_mocap"]] = bolt
        stiffness, damping = sample("pad_stiffness", *r.pad_stiffness), sample("pad_damping", *r.pad_damping)
        self._set_pad_compliance(physics, stiffness, damping)
        damping_noise = sample("joint_damping_noise", *r.joint_damping_noise)
        physics.model.dof_damping[ids["hand_dof"]] = self._nominal_damping + damping_noise
        nut_xy = bolt[:2].copy()
        if self.config.start == "engaged":  # on the thread, `start_turns` above its goal: its height fixes its yaw
            height = props.BOLT_HEAD_HEIGHT + float(sample("start_turns", *r.start_turns)) * props.PITCH
            nut_yaw = thread_yaw(height)
        else:  # above the bolt's tip, anywhere in the thread's phase
            height = props.BOLT_HEAD_HEIGHT + props.SHANK_LENGTH + float(sample("hover", *r.hover))
            nut_xy += sample("start_offset", r.start_offset_low, r.start_offset_high)
            nut_yaw = float(sample("start_yaw", *r.start_yaw))
        # The hand grips two opposite flats: its yaw is the nut's modulo a flat (60 deg), nearest to zero.
        flat = math.pi / 3
        grip_yaw = nut_yaw - flat * round(nut_yaw / flat)
        hand_x = np.array([math.cos(grip_yaw), math.sin(grip_yaw), 0.0])
        depth, offset = float(sample("grasp_depth", *r.grasp_depth)), float(sample("grasp_offset", *r.grasp_offset))
        self._bolt_noise, tilt, squeeze = np.zeros(3), 0.0, 0.0
        if self.config.start == "off_thread":  # drawn last: the engaged start's episodes stay as they were
            noise = r.bolt_obs_noise
            self._bolt_noise[:2] = sample("bolt_obs_noise", [-noise] * 2, [noise] * 2)
            tilt = float(sample("grasp_tilt", *r.grasp_tilt))
            squeeze = OFF_THREAD_SQUEEZE
        tcp = np.array([*nut_xy, height - depth]) - offset * hand_x
        # The hand's yaw joint turns about its own z axis, which points down: world yaw is minus the joint's.
        qpos = np.concatenate([tcp, [-grip_yaw, 0.0, 0.0]])
        physics.data.qpos[:] = physics.model.qpos0
        physics.data.qvel[:] = 0.0
        physics.data.qpos[ids["hand_qpos"]] = qpos
        physics.data.ctrl[ids["hand_act"]] = qpos
        self._hold_target = qpos.copy()
        nut_quat = np.array([math.cos(0.5 * nut_yaw), 0.0, 0.0, math.sin(0.5 * nut_yaw)])
        nut_pos = np.array([*nut_xy, height])
        if tilt:  # about the pads' normal through the nut's centre: the flats stay on the pads
            normal = np.array([-hand_x[1], hand_x[0], 0.0])
            centre = np.array([0.0, 0.0, 0.5 * props.NUT_HEIGHT])
            nut_pos = nut_pos + centre - axis_angle_matrix(tilt * normal) @ centre
            tilt_quat = np.concatenate([[math.cos(0.5 * tilt)], math.sin(0.5 * tilt) * normal])
            mujoco.mju_mulQuat(nut_quat, tilt_quat, nut_quat.copy())
        physics.data.qpos[ids["held_qpos"]:ids["held_qpos"] + 7] = np.concatenate([nut_pos, nut_quat])
        self._settle_grasp(physics, props.NUT_APOTHEM - squeeze)

    def before_step(self, physics, action, random_state):
        action = np.clip(np.asarray(action, float), -1.0, 1.0)
        if self.config.unidirectional_rotation:
            action[ROTATION_AXIS] = -0.5 * (action[ROTATION_AXIS] + 1.0)
        super().before_step(physics, np.where(self._axes, action, 0.0), random_state)
        # The axes the policy does not drive hold the episode's start pose (a floating hand would drift).
        physics.data.ctrl[self._ids["hand_act"][self._held_joints]] = self._hold_target[self._held_joints]

    # ------------------------------------------------------------------------------------ task state
    def goal_pos(self, physics) -> np.ndarray:
        """Where the nut's bottom centre should end: screwed down onto the bolt's head (start=engaged), or threaded
        on, its thread's lower end 1.5 pitches below the bolt's thread's upper end (start=off_thread, Factory's
        NutThread target)."""
        if self.config.start == "engaged":
            return self.fixed_pos(physics) + np.array([0.0, 0.0, props.BOLT_HEAD_HEIGHT])
        tip = props.BOLT_HEAD_HEIGHT + props.SHANK_LENGTH  # where the bolt's thread ends
        return self.fixed_pos(physics) + np.array([0.0, 0.0, tip - 1.5 * props.PITCH - self._thread_margin])

    def observed_goal_pos(self, physics) -> np.ndarray:
        """The goal as the policy sees it: off by the episode's bolt observation noise (`bolt_obs_noise`)."""
        return self.goal_pos(physics) + self._bolt_noise

    def nut_pos(self, physics) -> np.ndarray:
        return physics.data.xpos[self._ids["held_body"]]

    def thread_gap(self, physics) -> float:
        """Height (m) of the nut's thread's lower end above the bolt's thread's upper end: below 0 they overlap."""
        tip = self.fixed_pos(physics)[2] + props.BOLT_HEAD_HEIGHT + props.SHANK_LENGTH
        return float(self.nut_pos(physics)[2] + self._thread_margin - tip)

    def nut_yaw(self, physics) -> float:
        xmat = physics.data.xmat[self._ids["held_body"]]
        return math.atan2(xmat[3], xmat[0])

    def _up_keypoints(self, centre: np.ndarray, up: np.ndarray) -> np.ndarray:
        return centre + self._keypoints[:, None] * up

    def keypoint_distances(self, physics) -> tuple[float, float]:
        """Factory's two reward distances (m), each summed over the keypoints: the nut's keypoints to the goal's,
        and the fingertips' to the nut's (how far the nut moved in the grasp)."""
        return self._per_state("keypoint_distances", physics, lambda: self._keypoint_distances(physics))

    def _keypoint_distances(self, physics) -> tuple[float, float]:
        d, ids = physics.data, self._ids
        nut_up = d.xmat[ids["held_body"]].reshape(3, 3)[:, 2]
        nut = self._up_keypoints(self.nut_pos(physics), nut_up)
        goal = self._up_keypoints(self.goal_pos(physics), np.array([0.0, 0.0, 1.0]))
        hand_up = -d.xmat[ids["hand_body"]].reshape(3, 3)[:, 2]  # the hand's z axis points at the fingertips
        fingers = self._up_keypoints(d.site_xpos[ids["tcp"]], hand_up)
        return (float(np.linalg.norm(nut - goal, axis=1).sum()), float(np.linalg.norm(fingers - nut, axis=1).sum()))

    def keypoint_distance(self, physics) -> float:
        """Mean distance (m) between the nut's keypoints and the goal's."""
        return self.keypoint_distances(physics)[0] / len(self._keypoints)

    def get_reward(self, physics):
        cfg = self.config
        nut_to_goal, fingers_to_nut = self.keypoint_distances(physics)
        reward = (-cfg.keypoint_reward_scale * (nut_to_goal + fingers_to_nut)
                  - cfg.action_gradient_penalty_scale * self._action_delta - self.balance_penalty(physics))
        if cfg.charge_failures_to_time_limit and self.failure(physics) is not None:
            reward *= 1 + max(cfg.episode_steps - self.step_count, 0)
        return reward

    def is_success(self, physics) -> bool:
        return float(np.linalg.norm(self.nut_pos(physics) - self.goal_pos(physics))) < self.config.success_distance

    def failure(self, physics) -> str | None:
        """Factory's failures, by name, or None: the nut slipped in the grasp, fell off the bolt or moved far.
        Memoised per physics state: the episode's end, its discount and its outcome all ask."""
        return self._per_state("failure", physics, lambda: self._failure(physics))

    def _failure(self, physics) -> str | None:
        d, ids = physics.data, self._ids
        nut, goal = self.nut_pos(physics), self.goal_pos(physics)
        nut_up = d.xmat[ids["held_body"]].reshape(3, 3)[:, 2]
        hand_up = -d.xmat[ids["hand_body"]].reshape(3, 3)[:, 2]
        pads_mid = d.site_xpos[ids["tcp"]] + 0.5 * PAD_LENGTH * hand_up
        if np.linalg.norm(pads_mid - (nut + 0.5 * props.NUT_HEIGHT * nut_up)) > 0.5 * (PAD_LENGTH + props.NUT_HEIGHT):
            return "slipped in the grasp"
        bolt_top = self.fixed_pos(physics)[2] + props.BOLT_HEAD_HEIGHT + props.SHANK_LENGTH
        if math.hypot(*(nut[:2] - goal[:2])) > props.BOLT_THREAD_RADIUS + props.THREAD_TUBE and nut[2] < bolt_top:
            return "fell off the bolt"
        if np.linalg.norm(nut - goal) > self.config.far_distance:
            return "moved far away"
        return None

    def should_terminate_episode(self, physics):
        return super().should_terminate_episode(physics) or self.is_success(physics) or self.failure(physics) is not None

    def get_discount(self, physics):
        # Success and failure end the episode (Factory resets on both): terminations. The time limit truncates.
        return 0.0 if self.is_success(physics) or self.failure(physics) is not None else 1.0

    def outcome(self, physics) -> dict:
        """How far the nut is from its goal (thread turns to go, offset from the bolt's axis, tilt) and why it
        stopped there: screwed down (engaged start) or threaded on and seated (off the thread); a failure (slipped in the grasp, fell off the bolt, moved far away); or, at
        the time limit, above the bolt's tip off its axis (missed the bolt) or on it (jammed on the crest: its thread
        not a pitch past the bolt's), tilted with the threads overlapping (cross-threaded), or on the thread, not down yet."""
        nut, goal = self.nut_pos(physics), self.goal_pos(physics)
        tilt = float(np.arccos(min(abs(physics.data.xmat[self._ids["held_body"]][8]), 1.0)))
        offset = math.hypot(*(nut[:2] - goal[:2]))
        thread_gap = self.thread_gap(physics)
        if self.is_success(physics):
            label = "screwed down" if self.config.start == "engaged" else "threaded on and seated"
        elif self.failure(physics):
            label = self.failure(physics)
        elif thread_gap > 0 and offset > props.NUT_THREAD_RADIUS - props.BOLT_THREAD_RADIUS + props.THREAD_TUBE:
            label = "missed the bolt"
        elif thread_gap > -props.PITCH:  # the helices meet within a pitch of their ends, whatever the phase
            label = "jammed on the crest"
        elif tilt > CROSS_THREAD_TILT:
            label = "cross-threaded"
        else:
            label = "on the thread, not down yet"
        return dict(outcome=label, turns_to_go=float((nut[2] - goal[2]) / props.PITCH), nut_offset_xy=offset,
                    nut_tilt=tilt)

    def get_state(self, physics) -> dict:
        return dict(super().get_state(physics), hold_target=self._hold_target.copy(), bolt_noise=self._bolt_noise.copy())

    def set_state(self, physics, state: dict) -> None:
        super().set_state(physics, state)
        self._hold_target = state["hold_target"].copy()
        self._bolt_noise = state.get("bolt_noise", np.zeros(3)).copy()  # absent from older checkpoints

    # ---------------------------------------------------------------------------------- observations
    # The insertion task's layout with the goal (the bolt's head top) in the socket's place.
    def proprio(self, physics) -> np.ndarray:
        ids, d = self._ids, physics.data
        tcp, goal = d.site_xpos[ids["tcp"]], self.observed_goal_pos(physics)
        return np.concatenate([tcp, d.xquat[ids["hand_body"]], goal, [1.0, 0, 0, 0], d.qpos[ids["finger_qpos"]],
                               goal - tcp]).astype(np.float32)

    def peg_state(self, physics) -> np.ndarray:
        ids, d = self._ids, physics.data
        nut = self.nut_pos(physics)
        return np.concatenate([nut, d.xquat[ids["held_body"]], self.observed_goal_pos(physics) - nut]).astype(np.float32)

    def critic_state(self, physics) -> np.ndarray:
        ids, d = self._ids, physics.data
        lin, ang = self._velocity(physics, mujoco.mjtObj.mjOBJ_SITE, ids["tcp"])
        nut, goal = self.nut_pos(physics), self.goal_pos(physics)
        return np.concatenate([
            d.site_xpos[ids["tcp"]], d.xquat[ids["hand_body"]], nut, d.xquat[ids["held_body"]], goal, [1.0, 0, 0, 0],
            d.qpos[ids["finger_qpos"]], lin, ang, self.contact_forces(physics), goal - nut,
            [self.keypoint_distance(physics)]]).astype(np.float32)

    def _observation_sources(self) -> dict:
        return dict(proprio=self.proprio, peg_state=self.peg_state, critic_state=self.critic_state)
