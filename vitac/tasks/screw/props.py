"""Threaded M16 nut and bolt (Factory's nut_bolt_m16: 2 mm pitch, 24 mm across flats) whose threads collide as
threads.

Each thread is a helix of capsules, `segments_per_turn` a turn, swept along the thread's crest. The bolt's
helix runs at radius BOLT_THREAD_RADIUS, the nut's at NUT_THREAD_RADIUS, half a pitch apart along the axis. In
a cross-section through the axis the two threads are interleaved rows of circles: their radial overlap
(2 THREAD_TUBE - the radial gap) stops a nut pulled straight up, and the distance between neighbouring
circles leaves THREAD_CLEARANCE of play, so the nut advances only by turning (docs/environment.md). Capsule
pairs are MuJoCo's analytic narrowphase: cheaper and steadier than the SDF nut and bolt plugins, whose size
is fixed at about a metre (a 1/12 pitch) and cannot be scaled to an M16.
"""

from __future__ import annotations

import math

import numpy as np
from dm_control import composer, mjcf

from vitac.sim import collision
from vitac.sim.tactile import ContactShape, regular_prism

PITCH = 0.002
THREAD_TUBE = 0.00046  # capsule radius of both threads
BOLT_THREAD_RADIUS = 0.00754  # helix of the bolt's thread: crest at 8.0 mm, the M16 major radius
NUT_THREAD_RADIUS = 0.00774
BOLT_CORE_RADIUS = 0.00708  # leaves 0.2 mm between the nut's thread and the bolt's core: the nut's lateral play
NUT_APOTHEM = 0.012  # half the width across flats
NUT_HEIGHT = 0.013
NUT_BORE_APOTHEM = 0.0084  # the nut's bore, a hexagon around its thread
BOLT_HEAD_HEIGHT = 0.016
BOLT_HEAD_APOTHEM = 0.012
SHANK_LENGTH = 0.025
THREAD_CONDIM = 3  # sliding friction only: no torsional friction at a thread's point contacts (a third cheaper)
NUT_MASS_DENSITY = 7850.0  # steel (Factory)
# Gap, along the line between their centres, between a bolt capsule and the nearest nut capsule when engaged.
THREAD_CLEARANCE = math.hypot(NUT_THREAD_RADIUS - BOLT_THREAD_RADIUS, 0.5 * PITCH) - 2 * THREAD_TUBE


def helix_points(radius: float, z_start: float, z_end: float, segments_per_turn: int, phase_z: float) -> np.ndarray:
    """Points on the right-handed helix z = phase_z + PITCH * theta / 2 pi, at angles k 2 pi / segments_per_turn,
    from the first at or above z_start to the last at or below z_end."""
    first = math.ceil((z_start - phase_z) / PITCH * segments_per_turn)
    last = math.floor((z_end - phase_z) / PITCH * segments_per_turn)
    theta = 2 * math.pi * np.arange(first, last + 1) / segments_per_turn
    return np.stack([radius * np.cos(theta), radius * np.sin(theta), phase_z + PITCH * theta / (2 * math.pi)], 1)


def _add_thread(body, name: str, points: np.ndarray, **geom) -> list:
    # Group 3, which cameras do not draw: hundreds of capsules would cost the 64x64 wrist frame ~25x its time.
    return [body.add("geom", name=f"{name}_{k}", type="capsule", size=(THREAD_TUBE,), group=3,
                     fromto=np.concatenate([points[k], points[k + 1]]), **geom) for k in range(len(points) - 1)]


def _add_hex_ring(body, name: str, inner: float, outer: float, z_low: float, z_high: float, **geom) -> list:
    """A hexagonal tube between apothems `inner` and `outer`, one box per side, flats facing +-y (and +-30 deg)."""
    half_depth = 0.5 * (outer - inner)
    half_side = outer * math.tan(math.pi / 6)  # the outer side's half length: boxes overlap at the corners
    geoms = []
    for k in range(6):
        angle = math.pi / 6 + k * math.pi / 3
        centre = (inner + half_depth) * np.array([math.cos(angle), math.sin(angle)])
        geoms.append(body.add("geom", name=f"{name}_{k}", type="box", size=(half_depth, half_side, 0.5 * (z_high - z_low)),
                              pos=(centre[0], centre[1], 0.5 * (z_low + z_high)), euler=(0, 0, angle), **geom))
    return geoms


def nut_mass_properties() -> tuple[float, float, float]:
    """Mass (kg) and principal inertia about the axis and across it (kg m^2) of a solid hex prism less its bore."""
    hex_area = 2 * math.sqrt(3) * NUT_APOTHEM**2
    bore_area = math.pi * NUT_THREAD_RADIUS**2
    mass = NUT_MASS_DENSITY * (hex_area - bore_area) * NUT_HEIGHT
    # Inertia of the tube with the hexagon's area and the bore's radius.
    r_out, r_in = math.sqrt(hex_area / math.pi), NUT_THREAD_RADIUS
    axial = 0.5 * mass * (r_out**2 + r_in**2)
    across = mass * (3 * (r_out**2 + r_in**2) + NUT_HEIGHT**2) / 12
    return mass, axial, across


class Nut(composer.Entity):
    """A hex nut with an internal thread; its frame's origin is the bottom face's centre, z along the axis.

    Args:
        friction: sliding friction of the nut's flats and thread (Factory: 0.3).
        segments_per_turn: capsules a turn of thread.
        thread_turns: turns of the nut's thread (at most NUT_HEIGHT / PITCH = 6.5), centred in its height.
    """

    def _build(self, friction: float, segments_per_turn: int = 24, thread_turns: float = 6.0,
               rgba=(0.83, 0.68, 0.4, 1)):
        self._mjcf_root = mjcf.RootElement(model="nut")
        self.body = self._mjcf_root.worldbody.add("body", name="body")
        mass, axial, across = nut_mass_properties()
        self.body.add("inertial", pos=(0, 0, 0.5 * NUT_HEIGHT), mass=mass, diaginertia=(across, across, axial))
        common = dict(friction=(friction, 0.005, 0.0001), condim=4, rgba=rgba, density=0)
        # The flats: what the pads and the bolt's head touch.
        self.flats = _add_hex_ring(self.body, "flat", NUT_BORE_APOTHEM, NUT_APOTHEM, 0.0, NUT_HEIGHT,
                                   contype=collision.PEG | collision.PEG_GRASP, conaffinity=collision.PEG_AFFINITY,
                                   **common)
        self.geom = self.grasp_geom = self.flats[1]  # the flat facing +y
        margin = 0.5 * (NUT_HEIGHT - thread_turns * PITCH)  # the thread's turns centred in the nut's height
        points = helix_points(NUT_THREAD_RADIUS, margin, NUT_HEIGHT - margin, segments_per_turn, 0.5 * PITCH)
        self.thread = _add_thread(self.body, "thread", points, contype=collision.PEG, conaffinity=collision.WORLD,
                                  **dict(common, condim=THREAD_CONDIM))

    def contact_shape(self) -> ContactShape:
        """The nut as the pads feel it: a hexagonal prism with flats facing +-y."""
        return regular_prism(6, NUT_APOTHEM, NUT_HEIGHT, yaw=math.pi / 6)

    @property
    def mjcf_model(self):
        return self._mjcf_root


class Bolt(composer.Entity):
    """A fixed hex-head bolt standing on the table; its frame's origin is the head's bottom centre.

    Its thread starts at the head's top (BOLT_HEAD_HEIGHT) and runs SHANK_LENGTH up, in phase with
    `helix_points(..., phase_z=0)`: a nut whose bottom is at height h engages it at yaw 2 pi h / PITCH.
    """

    def _build(self, friction: float, contact_timeconst: float, segments_per_turn: int = 24,
               rgba=(0.7, 0.7, 0.72, 1)):
        self._mjcf_root = mjcf.RootElement(model="bolt")
        self.body = self._mjcf_root.worldbody.add("body", name="body")
        common = dict(contype=collision.WORLD, conaffinity=collision.WORLD_AFFINITY, friction=(friction, 0.005, 0.0001),
                      condim=4, rgba=rgba, priority=1, solref=(contact_timeconst, 1.0))
        top = BOLT_HEAD_HEIGHT + SHANK_LENGTH
        self.head = self.body.add("geom", name="head", type="cylinder", size=(BOLT_HEAD_APOTHEM, 0.5 * BOLT_HEAD_HEIGHT),
                                  pos=(0, 0, 0.5 * BOLT_HEAD_HEIGHT), **common)
        self.core = self.body.add("geom", name="core", type="cylinder", size=(BOLT_CORE_RADIUS, 0.5 * SHANK_LENGTH),
                                  pos=(0, 0, BOLT_HEAD_HEIGHT + 0.5 * SHANK_LENGTH), **common)
        points = helix_points(BOLT_THREAD_RADIUS, BOLT_HEAD_HEIGHT, top - THREAD_TUBE, segments_per_turn, 0.0)
        self.thread = _add_thread(self.body, "thread", points, **dict(common, condim=THREAD_CONDIM))
        # What cameras see of the threaded shank: a cylinder at the thread's mean radius, which touches nothing.
        self.body.add("geom", name="shank_visual", type="cylinder", size=(BOLT_THREAD_RADIUS, 0.5 * SHANK_LENGTH),
                      pos=(0, 0, BOLT_HEAD_HEIGHT + 0.5 * SHANK_LENGTH), contype=0, conaffinity=0, density=0, rgba=rgba)
        self.top_site = self.body.add("site", name="top", pos=(0, 0, top), size=(0.001,), rgba=(0, 1, 0, 0.5))

    @property
    def mjcf_model(self):
        return self._mjcf_root
