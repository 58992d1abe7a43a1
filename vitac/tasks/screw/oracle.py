"""Scripted screwing controller: the physics sanity check of the screw task."""

from __future__ import annotations

import numpy as np

from vitac.tasks.screw import props
from vitac.tasks.screw.config import thread_yaw
from vitac.tasks.screw.task import ROTATION_AXIS, ScrewTask


class OracleController:
    """Turn the nut the tightening way at a fixed rate while pressing it lightly onto the thread; from off the
    thread, first bring the nut's axis over the bolt's (true poses), and press only while it is there. With both
    rotation ways open it turns the nut to the thread's phase before pressing; tightening only, it need not.

    Args:
        task: the screw task whose physics the controller reads.
        turn: how much of the full tightening step (`task.rot_action_scale` rad a control step) to turn.
        press: the z action (negative: down; -0.1 sets the hand's target 1 mm below it at the default scale).
        align_tolerance: how far (m) the nut's axis may be off the bolt's before it is lowered onto the thread.
    """

    def __init__(self, task: ScrewTask, turn: float = 1.0, press: float = -0.1, align_tolerance: float = 0.0003):
        self.task, self.turn, self.press, self.align_tolerance = task, turn, press, align_tolerance
        self.hover = 0.0005  # how far above the bolt's top thread turn the nut's is turned to the thread's phase

    def reset(self):
        pass

    def __call__(self, physics) -> np.ndarray:
        action = np.zeros(6)
        if self.task.config.action_axes[0] and self.task.config.action_axes[1]:
            approach = self._off_thread(physics)
            if approach is not None:
                return approach
            action[:2] = self._centre(physics, turning=True)
        action[2] = self.press
        action[ROTATION_AXIS] = self._rotation(-self.turn)  # tightening is a negative world z rotation
        return action

    def _rotation(self, turn: float) -> float:
        """The rotation action for a signed turn (in rotation steps, negative tightens). Under
        `unidirectional_rotation` the action a turns -(a + 1) / 2, only ever tightening: a = -2 turn - 1."""
        if not self.task.config.unidirectional_rotation:
            return turn
        return -2.0 * min(turn, 0.0) - 1.0

    def _centre(self, physics, turning: bool) -> np.ndarray:
        """The x, y action that puts the nut's axis on the bolt's; while turning, against the circle the nut, held
        off the hand's axis, makes about it."""
        task = self.task
        off_axis = (task.goal_pos(physics) - task.nut_pos(physics))[:2]
        if turning:
            held = (task.nut_pos(physics) - physics.data.site_xpos[task._ids["tcp"]])[:2]
            angle = -self.turn * task.config.rot_action_scale
            turned = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]]) @ held
            off_axis = off_axis - (turned - held)
        # Three times the error: the compliant hand, its nut pressed on the bolt, stops short of a target at the error.
        return np.clip(3.0 * off_axis / task.config.pos_action_scale, -1.0, 1.0)

    def _off_thread(self, physics) -> np.ndarray | None:
        """Until the threads meet: centre the nut over the bolt, lower it to just above the bolt's top thread turn,
        turn it to the thread's phase there; None once it is on the thread (then screw as from an engaged start)."""
        task = self.task
        gap = task.thread_gap(physics)
        if gap < -0.5 * props.PITCH:
            return None
        action = np.zeros(6)
        action[ROTATION_AXIS] = self._rotation(0.0)
        action[:2] = self._centre(physics, turning=False)
        if np.linalg.norm((task.goal_pos(physics) - task.nut_pos(physics))[:2]) > self.align_tolerance:
            # Lifted back to the hover height first: a nut resting on the crest off the axis does not slide over.
            action[2] = max(0.0, (self.hover - gap) / task.config.pos_action_scale)
            return action
        if gap > self.hover:
            action[2] = -min(1.0, (gap - 0.5 * self.hover) / task.config.pos_action_scale)
            return action
        if task.config.unidirectional_rotation:
            return None  # it can only tighten: pressed lightly while turning, the nut drops into the thread's phase
        height = task.nut_pos(physics)[2] - task.fixed_pos(physics)[2]
        phase = (thread_yaw(height) - task.nut_yaw(physics) + np.pi) % (2 * np.pi) - np.pi
        if abs(phase) > 0.1:
            action[ROTATION_AXIS] = np.clip(phase / task.config.rot_action_scale, -1.0, 1.0)
            return action
        return None
