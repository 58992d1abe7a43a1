"""Scripted screwing controller: the physics sanity check of the screw task."""

from __future__ import annotations

import numpy as np

from vitac.tasks.screw.task import ROTATION_AXIS, ScrewTask


class OracleController:
    """Turn the nut the tightening way at a fixed rate while pressing it lightly onto the thread.

    Args:
        task: the screw task whose physics the controller reads.
        turn: how much of the full tightening step (`task.rot_action_scale` rad a control step) to turn.
        press: the z action (negative: down; -0.1 sets the hand's target 1 mm below it at the default scale).
    """

    def __init__(self, task: ScrewTask, turn: float = 1.0, press: float = -0.1):
        self.task, self.turn, self.press = task, turn, press

    def reset(self):
        pass

    def __call__(self, physics) -> np.ndarray:
        action = np.zeros(6)
        action[2] = self.press
        # Tightening is a negative world z rotation, which the unidirectional mapping -(a + 1) / 2 reaches at a = 2 t - 1.
        action[ROTATION_AXIS] = 2 * self.turn - 1 if self.task.config.unidirectional_rotation else -self.turn
        return action
