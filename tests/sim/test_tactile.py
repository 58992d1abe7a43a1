"""Tactile force field: the penalty model on a taxel grid, alone and inside the simulated grasp."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from vitac.sim.tactile import TactileFieldSensor, box, cylinder, regular_prism

PEG = cylinder(0.008, 0.05)
PAD_ROT = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])  # pad x = world x, y = world z, z (out) = world -y


def _sensor():
    return TactileFieldSensor(32, 32, 0.024, 0.032, 0.0005, kn=1000.0, kt=100.0, mu=2.0)


def _field(gap=-0.0005, peg_vel=(0, 0, 0), pad_vel=(0, 0, 0), peg_shift=(0, 0, 0)):
    """Pad face at y = 0.008 + gap... facing -y, peg axis along world z centred at the origin."""
    sensor = _sensor()
    pad_pos = np.array([0.0, PEG.radius + gap, 0.025])
    peg_pos = np.array(peg_shift, float)
    zero = np.zeros(3)
    return sensor.field(PEG, pad_pos, PAD_ROT, np.array(pad_vel, float), zero, peg_pos, np.eye(3),
                        np.array(peg_vel, float), zero)


def test_no_contact_gives_zeros():
    assert np.all(_field(gap=+0.001) == 0.0)


def test_more_squeeze_gives_more_normal_force():
    light, firm = _field(gap=-0.0002), _field(gap=-0.0008)
    assert firm[2].sum() > light[2].sum() > 0
    assert np.all(firm[2] >= 0)


def test_sliding_peg_gives_shear_in_the_sliding_direction():
    # The peg slides down (world -z) past the pad: the pad's y axis is world +z, so friction adds negative
    # shear_y. (Channel 0 also carries the in-plane part of the curved surface's normal force, which is
    # antisymmetric across the contact line and cancels in the sum.)
    still, sliding = _field(), _field(peg_vel=(0, 0, -0.05))
    touching = sliding[2] > 0
    assert touching.any()
    assert np.all((sliding[1] - still[1])[touching] < 0)
    assert np.allclose(sliding[0], still[0])
    assert abs(still[0].sum()) < 1e-9
    # Sliding along world x (the pad's x) adds shear_x in that direction.
    sliding_x = _field(peg_vel=(0.05, 0, 0))
    assert np.all((sliding_x[0] - still[0])[touching] > 0)


def test_shear_is_capped_by_coulomb_friction():
    still, fast = _field(), _field(peg_vel=(0, 0, -100.0))
    touching = still[2] > 0
    normal_force = np.linalg.norm(still, axis=0)[touching]  # at rest the whole force is kn * depth
    friction = np.linalg.norm(fast - still, axis=0)[touching]
    np.testing.assert_allclose(friction, 2.0 * normal_force, rtol=1e-6)  # saturated at mu * fn


def test_contact_line_lies_where_the_peg_touches():
    field = _field()
    rows, cols = np.nonzero(field[2] > 0)
    # A 0.5 mm deep contact with an 8 mm cylinder is a band +-2.8 mm wide (+-3.8 rows of 0.74 mm) about the middle.
    assert rows.min() + rows.max() == 31 and np.all(np.abs(rows - 15.5) <= 4)
    assert cols.min() == 0 and cols.max() == 31  # along the whole pad length


@pytest.mark.parametrize("shape", ["round", "rectangular"])
def test_normal_force_is_kn_times_depth_along_the_face_normal(shape):
    # A pad facing -y pressed 0.4 mm into the +y face of the peg: at the contact line the force is
    # purely normal, kn * depth, and no taxel beyond the peg's length (z > 0.05) feels anything.
    peg = cylinder(0.008, 0.05) if shape == "round" else box(0.008, 0.005, 0.05)
    face = 0.008 if shape == "round" else 0.005
    sensor = _sensor()
    zero = np.zeros(3)
    field = sensor.field(peg, np.array([0.0, face - 0.0004, 0.04]), PAD_ROT, zero, zero, zero, np.eye(3), zero, zero)
    # Exact on a flat face; on the cylinder the nearest taxel rows sit 0.37 mm off the contact line.
    assert field[2].max() == pytest.approx(1000.0 * 0.0004, rel=1e-6 if shape == "rectangular" else 0.03)
    y_world = 0.04 + sensor.points[:, 1].reshape(32, 32)  # the pad's y axis is world +z
    assert np.all(field[2][y_world >= 0.05] == 0.0) and np.any(field[2][y_world < 0.05] > 0)


def test_a_new_part_is_a_shape_not_a_change_to_the_model_a_hexagonal_prism_pressed_on_a_flat():
    # A hexagonal nut (24 mm across flats) with a flat facing +y: pressed 0.4 mm into that flat, the pad feels
    # kn * depth along the flat's normal, exactly as on a box of the same half width, and nothing past its height.
    sensor, zero = _sensor(), np.zeros(3)
    nut = regular_prism(6, 0.012, 0.013, yaw=np.pi / 2)
    slab = box(0.02, 0.012, 0.013)
    pad = np.array([0.0, 0.012 - 0.0004, 0.0065])
    on_nut = sensor.field(nut, pad, PAD_ROT, zero, zero, zero, np.eye(3), zero, zero)
    on_box = sensor.field(slab, pad, PAD_ROT, zero, zero, zero, np.eye(3), zero, zero)
    assert on_nut[2].max() == pytest.approx(1000.0 * 0.0004, rel=1e-9)
    # Within the flat (|x| under half its 13.9 mm length) the two fields agree; beyond it the hexagon turns away.
    x_world = sensor.points[:, 0].reshape(32, 32)
    within = np.abs(x_world) < 0.0069 - 0.0005
    np.testing.assert_allclose(on_nut[2][within], on_box[2][within], atol=1e-9)
    assert on_nut[2][np.abs(x_world) > 0.0075].max() == 0.0


# sha256 of the float64 fields of tests/data/tactile_states.npz's states, as 6428cf5's kernel computed them.
FIELD_DIGESTS = {"insertion": "5be58bde8aeb282ce02a4c8d15eed3ccad92fee7c7b172a116da502e1af6b4e3",
                 "screw": "025acde1af5cf1edc3c03c4acecbf3d9917991d09bdb45beecb2498d0cfd92f2"}


@pytest.mark.parametrize("task", sorted(FIELD_DIGESTS))
def test_fields_along_episodes_of_each_task_are_bit_identical_to_6428cf5s(task):
    from vitac.sim.gripper import PAD_LENGTH, PAD_WIDTH
    from vitac.sim.tactile import ContactShape
    from vitac.tasks.insertion.config import InsertionConfig
    from vitac.tasks.screw.config import ScrewConfig

    states = np.load(Path(__file__).parents[1] / "data" / "tactile_states.npz")
    c = {"insertion": InsertionConfig, "screw": ScrewConfig}[task]()
    sensor = TactileFieldSensor(c.taxel_rows, c.taxel_cols, PAD_WIDTH, PAD_LENGTH, c.taxel_margin, c.tactile_kn,
                                c.tactile_kt, c.tactile_mu)
    length, radius = states[f"{task}_shape"]
    shape = ContactShape(float(length), float(radius), tuple(map(tuple, states[f"{task}_normals"].tolist())),
                         tuple(states[f"{task}_offsets"].tolist()))
    inputs = [states[f"{task}_{k}"] for k in ("pad_pos", "pad_rot", "pad_lin", "pad_ang", "part_pos", "part_rot",
                                               "part_lin", "part_ang")]
    fields = np.stack([sensor.fields(shape, *step) for step in zip(*inputs, strict=True)])
    assert np.count_nonzero(fields[:, :, 2]) > 0.05 * fields[:, :, 2].size  # the pads do touch the part
    assert hashlib.sha256(fields.tobytes()).hexdigest() == FIELD_DIGESTS[task]
