"""Peg-in-socket insertion as a dm_control composer Task (TacSL's task on MuJoCo)."""

from __future__ import annotations

import functools
import math

import mujoco
import numba
import numpy as np

from vitac.sim.poses import DOWN, matrix_from_euler_zyx
from vitac.tasks.base import GraspedPartTask
from vitac.tasks.insertion import props
from vitac.tasks.insertion.config import InsertionConfig


@numba.njit(cache=True)
def mean_keypoint_distance(peg_pos: np.ndarray, peg_xmat: np.ndarray, goal_pos: np.ndarray, offsets: np.ndarray) -> float:
    """Mean distance between keypoints at `offsets` along the peg's z axis (xmat row-major) and the goal's (world z)."""
    total = 0.0
    for offset in offsets:
        dx = peg_pos[0] - goal_pos[0] + offset * peg_xmat[2]
        dy = peg_pos[1] - goal_pos[1] + offset * peg_xmat[5]
        dz = peg_pos[2] - goal_pos[2] + offset * (peg_xmat[8] - 1.0)
        total += math.sqrt(dx * dx + dy * dy + dz * dz)
    return total / offsets.shape[0]


def keypoint_offsets(num: int, scale: float) -> np.ndarray:
    return (np.linspace(0.0, 1.0, num) - 0.5) * scale


class InsertionTask(GraspedPartTask):
    """Insert a grasped peg into a socket; TacSL's reward, success and randomization.

    Args:
        config: validated task settings.
        offscreen_size: offscreen render buffer (pixels); the camera size unless a tool renders larger views.
    """

    config: InsertionConfig

    def __init__(self, config: InsertionConfig, offscreen_size: int | None = None):
        self._keypoints = keypoint_offsets(config.num_keypoints, config.keypoint_scale)
        self._socket_noise = np.zeros(3)
        super().__init__(config, offscreen_size)

    def _build_parts(self):
        config = self.config
        self.peg_geometry = config.peg_geometry()
        self.held_shape = self.peg_geometry.contact_shape()
        self.peg = props.Peg(self.peg_geometry, density=config.density, friction=config.peg_friction)
        hole_x, hole_y = config.hole_half_extents()
        self.socket = props.Socket(config.peg_shape, hole_x, hole_y, friction=config.socket_friction,
                                   contact_timeconst=config.socket_contact_timeconst)
        self._attach_parts(self.peg, self.socket)

    def initialize_episode(self, physics, random_state):
        cfg, r, ids = self.config, self.config.randomization, self._ids
        self.episode_factors = {}
        sample = functools.partial(self._draw, random_state)  # sample(factor name, low, high)
        # Socket pose (fixed base) and its observation noise, drawn once per episode.
        physics.data.mocap_pos[ids["fixed_mocap"]] = sample("socket_pos", r.socket_pos_low, r.socket_pos_high)
        noise = r.socket_obs_noise
        self._socket_noise = sample("socket_obs_noise", [-noise] * 3, [noise] * 3)
        # Contact and joint parameter noise.
        stiffness, damping = sample("pad_stiffness", *r.pad_stiffness), sample("pad_damping", *r.pad_damping)
        self._set_pad_compliance(physics, stiffness, damping)
        damping_noise = sample("joint_damping_noise", *r.joint_damping_noise)
        physics.model.dof_damping[ids["hand_dof"]] = self._nominal_damping + damping_noise
        # Hand pose: fingertip midpoint position and the three hinge angles.
        pos = sample("ee_pos", r.ee_pos_low, r.ee_pos_high)
        roll, pitch, yaw = sample("ee_rot", r.ee_rot_low, r.ee_rot_high)
        qpos = np.concatenate([pos, [yaw, pitch, roll]])
        physics.data.qpos[:] = physics.model.qpos0
        physics.data.qvel[:] = 0.0
        physics.data.qpos[ids["hand_qpos"]] = qpos
        physics.data.ctrl[ids["hand_act"]] = qpos
        # Peg in the hand: its bottom `depth` below the fingertips, tilted about the closing axis
        # around the middle of the grasped segment.
        depth = sample("peg_in_hand_depth", *r.peg_in_hand_depth)
        tilt = sample("peg_in_hand_tilt", *r.peg_in_hand_tilt)
        pivot = np.array([0.0, 0.0, -0.5 * (self.peg_geometry.length - depth)])
        tilt_rot = matrix_from_euler_zyx(0.0, tilt, 0.0)
        peg_rot_hand = tilt_rot @ DOWN  # peg z axis points up the hand, away from the fingertips
        peg_pos_hand = pivot + tilt_rot @ (np.array([0.0, 0.0, depth]) - pivot)
        hand_rot = DOWN @ matrix_from_euler_zyx(yaw, pitch, roll)
        peg_pos = pos + hand_rot @ peg_pos_hand
        peg_quat = np.empty(4)
        mujoco.mju_mat2Quat(peg_quat, (hand_rot @ peg_rot_hand).ravel())
        physics.data.qpos[ids["held_qpos"]:ids["held_qpos"] + 7] = np.concatenate([peg_pos, peg_quat])
        half_grip = self.peg_geometry.half_y if cfg.peg_shape == "rectangular" else self.peg_geometry.half_x
        self._settle_grasp(physics, half_grip)

    def get_reward(self, physics):
        cfg = self.config
        distance = self.keypoint_distance(physics)
        kp = -distance
        offset, height = self.peg_offset(physics)
        centred = offset < self.peg_geometry.half_x
        if cfg.use_shaped_keypoint_reward and not centred and height < props.HOLE_DEPTH:  # beside the hole, below its top
            kp *= 10.0
        # TacSL's 1 / (exp(-50 d) + 1e-4 + exp(50 d)), multiplied through by exp(-50 d) <= 1 (d >= 0): the same
        # value without overflowing when the peg ends far away (a knocked-off or diverged peg).
        decay = math.exp(-50.0 * distance)
        kp_exp = decay / (decay * decay + 0.0001 * decay + 1.0)
        reward = cfg.keypoint_reward_scale * (kp + kp_exp) - cfg.action_gradient_penalty_scale * self._action_delta
        reward += cfg.success_reward_scale * float(self.is_success(physics))
        return reward - cfg.lateral_reward_scale * offset - self.balance_penalty(physics)

    # ------------------------------------------------------------------------------------ task state
    def socket_pos(self, physics) -> np.ndarray:
        return self.fixed_pos(physics)

    def keypoint_distance(self, physics) -> float:
        """Mean distance between the peg's and the goal's keypoints along their z axes."""
        return self._per_state("keypoint_distance", physics, lambda: self._keypoint_distance(physics))

    def _keypoint_distance(self, physics) -> float:
        d, peg = physics.data, self._ids["held_body"]
        return mean_keypoint_distance(d.xpos[peg], d.xmat[peg], self.socket_pos(physics), self._keypoints)

    def is_success(self, physics) -> bool:
        return self.keypoint_distance(physics) < self.config.success_threshold

    def peg_offset(self, physics) -> tuple[float, float]:
        """The peg's bottom-face centre relative to the goal: horizontal distance from the hole axis and height
        above the hole floor (m)."""
        delta = physics.data.xpos[self._ids["held_body"]] - self.socket_pos(physics)
        return math.hypot(delta[0], delta[1]), float(delta[2])

    def outcome(self, physics) -> dict:
        """Where the peg is relative to the goal (`peg_offset`, and its tilt, rad) and what that means, for
        reading why episodes fail."""
        offset, height = self.peg_offset(physics)
        tilt = float(np.arccos(min(abs(physics.data.xmat[self._ids["held_body"]][8]), 1.0)))
        if self.is_success(physics):
            label = "inserted"
        elif tilt > np.pi / 4:
            label = "dropped or knocked over"
        elif offset > self.socket.outer_half_width:
            label = "not over the socket"
        elif height < 0.002:
            label = "at the bottom, misaligned"
        elif height < props.HOLE_DEPTH - 0.001 and offset < 0.002:  # inside the hole, not pressed into its rim
            label = "stuck part-way in the hole"
        else:
            label = "on or above the socket"
        # Why a peg stops part-way: how far below the fingertips its bottom is held now (it slides up the pads when
        # pushed against the socket) and whether a finger link rests on the socket.
        ids, d = self._ids, physics.data
        grasp_depth = float((d.site_xpos[ids["tcp"]] - d.xpos[ids["held_body"]]) @ d.xmat[ids["held_body"]][2::3])
        return dict(outcome=label, peg_offset_xy=offset, peg_height=height, peg_tilt=tilt, grasp_depth=grasp_depth,
                    fingers_on_socket=self.fingers_on_fixed_part(physics))

    def get_state(self, physics) -> dict:
        return dict(super().get_state(physics), socket_noise=self._socket_noise.copy())

    def set_state(self, physics, state: dict) -> None:
        super().set_state(physics, state)
        self._socket_noise = state["socket_noise"].copy()

    # ---------------------------------------------------------------------------------- observations
    def observed_socket_pos(self, physics) -> np.ndarray:
        """The socket position the actor sees: the true one plus this episode's noise."""
        return self.socket_pos(physics) + self._socket_noise

    # Each vector observation ends with the offset to the (observed) socket that it implies. It adds no
    # information, but normalized absolute positions spread over 20 cm leave a millimetre offset at 0.02
    # standard deviations, which a network needs many updates to learn to cancel (docs/environment.md).
    def proprio(self, physics) -> np.ndarray:
        ids, d = self._ids, physics.data
        socket_quat = np.array([1.0, 0, 0, 0])
        tcp, socket = d.site_xpos[ids["tcp"]], self.observed_socket_pos(physics)
        return np.concatenate([tcp, d.xquat[ids["hand_body"]], socket, socket_quat,
                               d.qpos[ids["finger_qpos"]], socket - tcp]).astype(np.float32)

    def peg_state(self, physics) -> np.ndarray:
        ids, d = self._ids, physics.data
        peg = d.xpos[ids["held_body"]]
        return np.concatenate([peg, d.xquat[ids["held_body"]], self.observed_socket_pos(physics) - peg]).astype(np.float32)

    def critic_state(self, physics) -> np.ndarray:
        ids, d = self._ids, physics.data
        lin, ang = self._velocity(physics, mujoco.mjtObj.mjOBJ_SITE, ids["tcp"])
        peg, socket = d.xpos[ids["held_body"]], self.socket_pos(physics)
        return np.concatenate([
            d.site_xpos[ids["tcp"]], d.xquat[ids["hand_body"]], peg, d.xquat[ids["held_body"]],
            socket, [1.0, 0, 0, 0], d.qpos[ids["finger_qpos"]], lin, ang,
            self.contact_forces(physics), socket - peg, [self.keypoint_distance(physics)]]).astype(np.float32)

    def _observation_sources(self) -> dict:
        return dict(proprio=self.proprio, peg_state=self.peg_state, critic_state=self.critic_state)
