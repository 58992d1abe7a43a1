"""Scripted insertion controller that reads the true peg and socket poses: the physics sanity check."""

from __future__ import annotations

import numpy as np

from vitac.sim.poses import rotation_vector
from vitac.tasks.insertion import props
from vitac.tasks.insertion.task import InsertionTask


class OracleController:
    """Align the peg upright over the hole, then descend while correcting xy.

    Args:
        task: the insertion task whose physics the controller reads.
        hover: height of the peg bottom above the socket top before descending (m).
        align_tolerance: xy error (m) under which the peg may descend into the hole.
        tilt_tolerance: peg tilt (rad) under which the peg may descend.
        observed_socket: aim at the socket position the actor observes (with the episode's noise) instead of
            the true one: what a policy without contact feedback could do at best.
    """

    def __init__(self, task: InsertionTask, hover: float = 0.01, align_tolerance: float = 0.0006,
                 tilt_tolerance: float = 0.02, observed_socket: bool = False):
        self.task = task
        self.observed_socket = observed_socket
        self.hover, self.align_tolerance, self.tilt_tolerance = hover, align_tolerance, tilt_tolerance
        self.descending = False

    def reset(self):
        self.descending = False

    def __call__(self, physics) -> np.ndarray:
        task, cfg = self.task, self.task.config
        peg_body = task._ids["held_body"]
        peg_pos = physics.data.xpos[peg_body]
        peg_rot = physics.data.xmat[peg_body].reshape(3, 3)
        goal = task.observed_socket_pos(physics) if self.observed_socket else task.socket_pos(physics)
        # Rotation taking the peg's axes onto the socket's (upright, and square to a rectangular hole).
        desired = np.eye(3)
        if cfg.peg_shape == "round":  # the peg's yaw does not matter: keep it
            yaw = np.arctan2(peg_rot[1, 0], peg_rot[0, 0])
            desired = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
        else:  # either of the two symmetric yaws fits the hole: take the nearer one
            yaw = np.arctan2(peg_rot[1, 0], peg_rot[0, 0])
            target_yaw = np.round(yaw / np.pi) * np.pi
            desired = np.array([[np.cos(target_yaw), -np.sin(target_yaw), 0], [np.sin(target_yaw), np.cos(target_yaw), 0],
                                [0, 0, 1]])
        rot_error = rotation_vector(desired @ peg_rot.T)
        xy_error = goal[:2] - peg_pos[:2]
        aligned = np.linalg.norm(xy_error) < self.align_tolerance and np.linalg.norm(rot_error) < self.tilt_tolerance
        above_top = peg_pos[2] > goal[2] + props.HOLE_DEPTH + 0.002
        if aligned:
            self.descending = True
        elif above_top and np.linalg.norm(xy_error) > 3 * self.align_tolerance:
            self.descending = False  # lost alignment before entering the hole: hover again
        target_z = goal[2] - 0.005 if self.descending else goal[2] + props.HOLE_DEPTH + self.hover
        pos_error = np.array([xy_error[0], xy_error[1], target_z - peg_pos[2]])
        # The hand rotates about the fingertip midpoint, which moves the peg bottom: the loop corrects it.
        action = np.concatenate([pos_error / cfg.pos_action_scale, rot_error / cfg.rot_action_scale])
        return np.clip(action, -1.0, 1.0)
