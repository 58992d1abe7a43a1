"""Contact forces on a grasped part, summed by what it touches (a compiled loop over MuJoCo's contacts)."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def part_contact_forces(pairs, efc_address, dim, frames, efc_force, held_geom_mask, contact_slot):
    """World-frame force on the held part from each slot's geoms (slot 0 the fixed part, 1 left pad, 2 right pad),
    summed (3, 3).

    With elliptic cones (the arena's) a contact's force in its own frame is its first `dim` rows of efc_force
    (what mj_contactForce copies): normal, then the two tangential components. One compiled loop instead of
    ~3 us of Python per contact.
    """
    out = np.zeros((3, 3))
    for i in range(pairs.shape[0]):
        held_first, held_second = held_geom_mask[pairs[i, 0]], held_geom_mask[pairs[i, 1]]
        if held_first == held_second or efc_address[i] < 0:
            continue
        slot = contact_slot[pairs[i, 0]] if held_second else contact_slot[pairs[i, 1]]
        if slot < 0:
            continue
        sign = 1.0 if held_second else -1.0  # the frame's force is geom1's on geom2
        for j in range(min(dim[i], 3)):
            f = sign * efc_force[efc_address[i] + j]
            for k in range(3):
                out[slot, k] += frames[i, 3 * j + k] * f
    return out
