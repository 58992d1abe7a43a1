"""How balanced the two pads' force fields are: the bilateral asymmetry the symmetry prior (paper Sec. III-C) is
meant to reduce, measured on the fields the policy sees.

The right pad's field mirrored into the left pad's frame (rows reversed, shear along them negated: the physical
mirror of `vitac.models.symmetry.mirror_pad`) equals the left pad's field when the grasp is symmetric. A step's
asymmetry is |left - mirror(right)| / (|left| + |mirror(right)|): 0 balanced, 1 one pad alone or the two opposed;
for the fields the norm is over every taxel and channel, for the net forces over the three summed channels.
Steps where neither pad feels anything are left out.
"""

from __future__ import annotations

import numpy as np

MEASURES = ("field", "net")
PHASES = ("episode", "contact")


def mirror_field(field: np.ndarray) -> np.ndarray:
    """A (3, H, W) field (shear_x, shear_y, normal) in the other pad's frame."""
    mirrored = field[:, ::-1, :].copy()
    mirrored[0] *= -1.0
    return mirrored


def asymmetry(left: np.ndarray, right_mirrored: np.ndarray) -> float | None:
    size = float(np.linalg.norm(left) + np.linalg.norm(right_mirrored))
    return None if size <= 0.0 else float(np.linalg.norm(left - right_mirrored)) / size


def step_asymmetries(left: np.ndarray, right: np.ndarray) -> dict:
    """This step's field and net-force asymmetries (None where neither pad feels anything)."""
    mirrored = mirror_field(np.asarray(right, np.float64))
    left = np.asarray(left, np.float64)
    return dict(field=asymmetry(left, mirrored), net=asymmetry(left.sum(axis=(1, 2)), mirrored.sum(axis=(1, 2))))


class ForceBalance:
    """Per-episode means of the asymmetries, over the whole episode and over its contact phase (the held part
    touching the fixed one)."""

    def __init__(self):
        self.reset()

    def reset(self) -> None:
        self.sums = {f"{m}_{p}": 0.0 for m in MEASURES for p in PHASES}
        self.counts = dict.fromkeys(self.sums, 0)

    def add(self, asymmetries: dict, in_contact: bool) -> None:
        """Count one step's `step_asymmetries`."""
        for measure, value in asymmetries.items():
            if value is None:
                continue
            for phase in PHASES if in_contact else ("episode",):
                self.sums[f"{measure}_{phase}"] += value
                self.counts[f"{measure}_{phase}"] += 1

    def summary(self) -> dict:
        """Each mean (None where no step counted), and how many contact-phase steps had a field to measure."""
        means = {k: (self.sums[k] / n if n else None) for k, n in self.counts.items()}
        return dict(means, contact_steps=self.counts["field_contact"])

    def state(self) -> dict:
        return dict(sums=dict(self.sums), counts=dict(self.counts))

    def load_state(self, state: dict) -> None:
        self.sums, self.counts = dict(state["sums"]), dict(state["counts"])
