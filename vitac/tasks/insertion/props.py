"""Peg and socket entities with IndustReal/TacSL dimensions (origins at the peg bottom and the hole floor)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from dm_control import composer, mjcf

from vitac.sim import collision
from vitac.sim.tactile import ContactShape, box, cylinder

# TacSL (industreal_asset_info_pegs.yaml): nominal size -> peg and hole cross-sections (m).
ROUND_PEG_DIAMETER = {8: 0.007986, 12: 0.011983, 16: 0.015983}
ROUND_HOLE_DIAMETER = {8: 0.0081, 12: 0.0122, 16: 0.0165}
RECT_PEG_SIZE = {8: (0.007964, 0.006910), 12: (0.011957, 0.007910), 16: (0.015957, 0.009910)}
RECT_HOLE_WIDTH = {8: 0.0081444, 12: 0.0121778, 16: 0.0162182}
PEG_LENGTH = 0.050
SOCKET_HEIGHT = 0.028
HOLE_DEPTH = 0.023
# Socket contact impedance (MuJoCo solimp): with the stiff time constant, a fully inserted peg twisted hard by
# the hand tilts ~1.5 degrees, near the 1.3 the clearance allows (TacSL's contacts are rigid), not 3.7 (defaults).
# Stiffer (0.99-0.999) let a wedged peg blow the simulation up once in 100 evaluation episodes.
SOCKET_SOLIMP = (0.97, 0.995, 0.001)


PEG_SHAPES = ("round", "rectangular")


@dataclass(frozen=True)
class PegGeometry:
    """Solid peg in its own frame: bottom face at z = 0, axis along +z.

    Args:
        shape: "round" (cylinder of radius half_x) or "rectangular" (box with half sizes half_x, half_y).
        half_x: radius for a round peg, half width along x for a rectangular one (m).
        half_y: half depth along y for a rectangular peg (ignored for a round one) (m).
        length: peg length along z (m).
    """

    shape: str
    half_x: float
    half_y: float
    length: float

    def contact_shape(self) -> ContactShape:
        """The peg as the tactile pads feel it."""
        if self.shape == "round":
            return cylinder(self.half_x, self.length)
        return box(self.half_x, self.half_y, self.length)


class Peg(composer.Entity):
    """A solid peg; its frame has the origin at the bottom face centre and z along the axis."""

    def _build(self, geometry: PegGeometry, density: float, friction: float, rgba=(0.75, 0.75, 0.78, 1)):
        self.geometry = geometry
        self._mjcf_root = mjcf.RootElement(model="peg")
        self.body = self._mjcf_root.worldbody.add("body", name="body")
        half_z = 0.5 * geometry.length
        common = dict(pos=(0, 0, half_z), friction=(friction, 0.005, 0.0001), rgba=rgba, condim=4)
        if geometry.shape == "round":
            self.geom = self.body.add("geom", name="geom", type="cylinder", size=(geometry.half_x, half_z),
                                      density=density, contype=collision.PEG, conaffinity=collision.WORLD, **common)
            # MuJoCo's cylinder-box narrowphase misses contacts with the thin pads near the peg's end, so the
            # pads touch an inscribed slab whose faces lie on the cylinder's grasp lines (y = +-r).
            self.grasp_geom = self.body.add("geom", name="grasp", type="box", density=0, group=3,
                                            size=(0.5 * geometry.half_x, geometry.half_x, half_z),
                                            contype=collision.PEG_GRASP, conaffinity=collision.PAD, **common)
        else:
            self.geom = self.body.add("geom", name="geom", type="box", density=density,
                                      size=(geometry.half_x, geometry.half_y, half_z),
                                      contype=collision.PEG | collision.PEG_GRASP, conaffinity=collision.PEG_AFFINITY,
                                      **common)
            self.grasp_geom = self.geom

    @property
    def mjcf_model(self):
        return self._mjcf_root


class Socket(composer.Entity):
    """A fixed socket with a real hole: a floor plus walls around a round or rectangular opening.

    A round hole is a ring of `ring_boxes` boxes whose inner faces are tangent to the hole circle
    (tangential half-width r * tan(pi / n)), so adjacent boxes meet without overlapping into the hole.
    """

    def _build(self, shape: str, hole_x: float, hole_y: float, friction: float, contact_timeconst: float = 0.005,
               ring_boxes: int = 32, wall: float = 0.008, rgba=(0.2, 0.35, 0.8, 1)):
        self._mjcf_root = mjcf.RootElement(model="socket")
        self.body = self._mjcf_root.worldbody.add("body", name="body")
        half_depth = 0.5 * HOLE_DEPTH
        floor_half = SOCKET_HEIGHT - HOLE_DEPTH
        outer = max(hole_x, hole_y) + wall
        self.outer_half_width = outer
        common = dict(contype=collision.WORLD, conaffinity=collision.WORLD_AFFINITY, friction=(friction, 0.005, 0.0001),
                      rgba=rgba, condim=4, priority=1, solref=(contact_timeconst, 1.0), solimp=SOCKET_SOLIMP)
        self.body.add("geom", name="floor", type="box", size=(outer, outer, 0.5 * floor_half),
                      pos=(0, 0, -0.5 * floor_half), **common)
        if shape == "round":
            r = hole_x
            tangential = r * np.tan(np.pi / ring_boxes)
            for k in range(ring_boxes):
                angle = 2 * np.pi * k / ring_boxes
                centre = (r + 0.5 * wall) * np.array([np.cos(angle), np.sin(angle)])
                self.body.add("geom", name=f"wall_{k}", type="box", size=(0.5 * wall, tangential + 0.5 * wall * np.tan(np.pi / ring_boxes), half_depth),
                              pos=(centre[0], centre[1], half_depth), euler=(0, 0, angle), **common)
        else:
            for k, (sx, sy, px, py) in enumerate([
                (0.5 * wall, hole_y + wall, hole_x + 0.5 * wall, 0), (0.5 * wall, hole_y + wall, -hole_x - 0.5 * wall, 0),
                (hole_x, 0.5 * wall, 0, hole_y + 0.5 * wall), (hole_x, 0.5 * wall, 0, -hole_y - 0.5 * wall),
            ]):
                self.body.add("geom", name=f"wall_{k}", type="box", size=(sx, sy, half_depth),
                              pos=(px, py, half_depth), **common)
        self.goal_site = self.body.add("site", name="goal", pos=(0, 0, 0), size=(0.002,), rgba=(0, 1, 0, 0.5))

    @property
    def mjcf_model(self):
        return self._mjcf_root
