"""Pose helpers of the hand's impedance control: Euler angles, axis-angle deltas, the hand's joint targets."""

from __future__ import annotations

import math

import mujoco
import numba
import numpy as np

DOWN = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])  # hand frame pointing down: Rx(pi)


# Compiled (numba): these run at every control step, where numpy's per-call overhead on 3-vectors would dominate.
@numba.njit(cache=True)
def euler_zyx_from_matrix(m: np.ndarray) -> tuple[float, float, float]:
    """(yaw, pitch, roll) with m = Rz(yaw) Ry(pitch) Rx(roll)."""
    return (math.atan2(m[1, 0], m[0, 0]), -math.asin(min(max(m[2, 0], -1.0), 1.0)), math.atan2(m[2, 1], m[2, 2]))


@numba.njit(cache=True)
def matrix_from_euler_zyx(yaw: float, pitch: float, roll: float) -> np.ndarray:
    cy, sy, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
    cr, sr = math.cos(roll), math.sin(roll)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


@numba.njit(cache=True)
def axis_angle_matrix(rotvec: np.ndarray) -> np.ndarray:
    """Rotation matrix of an axis-angle vector (Rodrigues)."""
    angle = math.sqrt(rotvec[0] ** 2 + rotvec[1] ** 2 + rotvec[2] ** 2)
    if angle <= 1e-6:  # TacSL's clamp_rot_thresh: below it the delta is the identity
        return np.eye(3)
    x, y, z = rotvec[0] / angle, rotvec[1] / angle, rotvec[2] / angle
    s, c = math.sin(angle), math.cos(angle)
    t = 1.0 - c
    return np.array([[c + t * x * x, t * x * y - s * z, t * x * z + s * y],
                     [t * x * y + s * z, c + t * y * y, t * y * z - s * x],
                     [t * x * z - s * y, t * y * z + s * x, c + t * z * z]])


@numba.njit(cache=True)
def hand_target(hand_qpos: np.ndarray, action: np.ndarray, pos_scale: float, rot_scale: float) -> np.ndarray:
    """The six hand joints' targets for an action in [-1, 1]^6: the current pose plus a position delta and an
    axis-angle delta in the world frame applied to the current orientation (TacSL)."""
    target = np.empty(6)
    target[:3] = hand_qpos[:3] + action[:3] * pos_scale
    # The hinges' angles give the orientation relative to DOWN = diag(1, -1, -1), in which the world-frame
    # delta w reads DOWN.T w (DOWN.T R(w) DOWN = R(DOWN.T w)).
    rotvec = np.array([action[3], -action[4], -action[5]]) * rot_scale
    current = matrix_from_euler_zyx(hand_qpos[3], hand_qpos[4], hand_qpos[5])
    yaw, pitch, roll = euler_zyx_from_matrix(axis_angle_matrix(rotvec) @ current)
    target[3] = hand_qpos[3] + (yaw - hand_qpos[3] + math.pi) % (2 * math.pi) - math.pi  # no wrap-around jumps
    target[4], target[5] = pitch, roll
    return target


def rotation_vector(m: np.ndarray) -> np.ndarray:
    """Axis-angle vector of a rotation matrix."""
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, m.ravel())
    vec = np.empty(3)
    mujoco.mju_quat2Vel(vec, quat, 1.0)
    return vec
