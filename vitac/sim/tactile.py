"""Penalty-based tactile force field (TacSL's model) on a taxel grid; numpy + a numba kernel, no simulator.

Each pad carries a rows x cols grid of taxels on its contact face. The pad frame has x along the
image rows, y along the image columns and z along the face normal, pointing out of the pad towards
the object. At each taxel the peg's signed distance gives a penetration depth d >= 0; the taxel then
feels a normal force kn * d along the peg's surface normal and a viscous-Coulomb shear
-min(kt * |vt|, mu * fn) * vt / |vt| where vt is the tangential velocity of the taxel relative to the
peg surface. The output per pad is a (3, rows, cols) map of (shear_x, shear_y, normal) in the pad frame.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numba
import numpy as np


@dataclass(frozen=True)
class ContactShape:
    """A held part as the pads feel it, in its own frame (bottom face at z = 0, axis along +z): a cylinder of
    `radius`, or a convex prism whose side faces have outward unit normals `normals` ((nx, ny) each) at
    distances `offsets` from the axis. A new part needs only its shape (`cylinder`, `box`, `regular_prism`,
    or its own faces), not a change to the force model.
    """

    length: float
    radius: float = 0.0
    normals: tuple = ()
    offsets: tuple = ()

    @property
    def is_cylinder(self) -> bool:
        return not self.normals

    @functools.cached_property
    def face_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """The side faces' normals (F, 2) and offsets (F,) as the force kernel reads them, built once."""
        return (np.array(self.normals, dtype=np.float64).reshape(-1, 2), np.array(self.offsets, dtype=np.float64))

    @functools.cached_property
    def reach(self) -> float:
        """Radius of the smallest cylinder about the axis that holds the part: the cylinder's radius, or the
        prism's farthest corner (a hair more, so that rounding never drops a point inside it)."""
        if self.is_cylinder:
            return self.radius
        n, d = self.face_arrays
        corners = [np.linalg.solve(n[[i, j]], d[[i, j]]) for i in range(len(n)) for j in range(i)
                   if abs(np.linalg.det(n[[i, j]])) > 1e-9]
        inside = [c for c in corners if np.all(n @ c <= d + 1e-12)]
        return float(max(np.linalg.norm(c) for c in inside)) * (1.0 + 1e-9)


def cylinder(radius: float, length: float) -> ContactShape:
    return ContactShape(float(length), radius=float(radius))


def box(half_x: float, half_y: float, length: float) -> ContactShape:
    return ContactShape(float(length), normals=((1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)),
                        offsets=(float(half_x), float(half_x), float(half_y), float(half_y)))


def regular_prism(sides: int, apothem: float, length: float, yaw: float = 0.0) -> ContactShape:
    """A regular polygon's prism (a hexagonal nut: sides=6, apothem = half the width across flats), its first
    face normal at `yaw` from the x axis."""
    angles = yaw + 2 * math.pi * np.arange(sides) / sides
    return ContactShape(float(length), normals=tuple((math.cos(a), math.sin(a)) for a in angles),
                        offsets=(float(apothem),) * sides)


def taxel_grid(rows: int, cols: int, size_x: float, size_y: float, margin: float) -> np.ndarray:
    """Taxel positions (rows*cols, 3) on the pad face (z = 0), row-major, x along rows, y along columns."""
    xs = np.linspace(-0.5 * size_x + margin, 0.5 * size_x - margin, rows)
    ys = np.linspace(-0.5 * size_y + margin, 0.5 * size_y - margin, cols)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    return np.stack([gx.ravel(), gy.ravel(), np.zeros(rows * cols)], axis=1)


@numba.njit(cache=True)
def _penetration(x, y, z, cylinder, radius, normals, offsets, length):
    """Depth below the nearest face and that face's outward normal, for a point inside the part (else depth 0).
    Side faces are tried in order and the first of equal depths is kept."""
    if z <= 0.0 or z >= length:
        return 0.0, 0.0, 0.0, 0.0
    cap = min(z, length - z)
    cap_nz = 1.0 if z > 0.5 * length else -1.0
    if cylinder:
        r2 = x * x + y * y
        if r2 >= radius * radius:
            return 0.0, 0.0, 0.0, 0.0
        radial = math.sqrt(r2)
        side = radius - radial
        if side <= cap:
            if radial < 1e-12:
                return side, 1.0, 0.0, 0.0
            return side, x / radial, y / radial, 0.0
        return cap, 0.0, 0.0, cap_nz
    best, best_face = math.inf, -1
    for f in range(normals.shape[0]):
        slack = offsets[f] - (normals[f, 0] * x + normals[f, 1] * y)
        if slack <= 0.0:
            return 0.0, 0.0, 0.0, 0.0
        if slack < best:
            best, best_face = slack, f
    if best <= cap:
        return best, normals[best_face, 0], normals[best_face, 1], 0.0
    return cap, 0.0, 0.0, cap_nz


@numba.njit(cache=True)
def _fields(points, pad_pos, pad_rot, pad_lin, pad_ang, peg_pos, peg_rot, peg_lin, peg_ang,
            cylinder, radius, normals, offsets, length, reach2, kn, kt, mu, out):
    """Fill out (P, 3, N) with (shear_x, shear_y, normal) per taxel; see TactileFieldSensor.fields."""
    for p in range(pad_pos.shape[0]):
        rot = pad_rot[p]
        for n in range(points.shape[0]):
            px, py, pz = points[n, 0], points[n, 1], points[n, 2]
            # Taxel relative to its pad origin (r) and to the peg origin (w), world axes.
            rx = rot[0, 0] * px + rot[0, 1] * py + rot[0, 2] * pz
            ry = rot[1, 0] * px + rot[1, 1] * py + rot[1, 2] * pz
            rz = rot[2, 0] * px + rot[2, 1] * py + rot[2, 2] * pz
            wx = pad_pos[p, 0] + rx - peg_pos[0]
            wy = pad_pos[p, 1] + ry - peg_pos[1]
            wz = pad_pos[p, 2] + rz - peg_pos[2]
            # ... and in the peg frame.
            lx = peg_rot[0, 0] * wx + peg_rot[1, 0] * wy + peg_rot[2, 0] * wz
            ly = peg_rot[0, 1] * wx + peg_rot[1, 1] * wy + peg_rot[2, 1] * wz
            lz = peg_rot[0, 2] * wx + peg_rot[1, 2] * wy + peg_rot[2, 2] * wz
            # Most taxels lie outside the part's bounding cylinder: no call for them. Calling for every taxel, with
            # the face arrays as arguments, made the kernel several times slower (docs/benchmarks.md).
            if lz <= 0.0 or lz >= length or lx * lx + ly * ly >= reach2:
                depth, nx_, ny_, nz_ = 0.0, 0.0, 0.0, 0.0
            else:
                depth, nx_, ny_, nz_ = _penetration(lx, ly, lz, cylinder, radius, normals, offsets, length)
            if depth <= 0.0:
                out[p, 0, n] = 0.0
                out[p, 1, n] = 0.0
                out[p, 2, n] = 0.0
                continue
            # Outward peg normal in the world: the direction the pad is pushed.
            nx = peg_rot[0, 0] * nx_ + peg_rot[0, 1] * ny_ + peg_rot[0, 2] * nz_
            ny = peg_rot[1, 0] * nx_ + peg_rot[1, 1] * ny_ + peg_rot[1, 2] * nz_
            nz = peg_rot[2, 0] * nx_ + peg_rot[2, 1] * ny_ + peg_rot[2, 2] * nz_
            fn = kn * depth
            # Taxel velocity minus the peg material's velocity at the same point.
            a = pad_ang[p]
            vx = pad_lin[p, 0] + a[1] * rz - a[2] * ry - (peg_lin[0] + peg_ang[1] * wz - peg_ang[2] * wy)
            vy = pad_lin[p, 1] + a[2] * rx - a[0] * rz - (peg_lin[1] + peg_ang[2] * wx - peg_ang[0] * wz)
            vz = pad_lin[p, 2] + a[0] * ry - a[1] * rx - (peg_lin[2] + peg_ang[0] * wy - peg_ang[1] * wx)
            vn = vx * nx + vy * ny + vz * nz
            tx, ty, tz = vx - vn * nx, vy - vn * ny, vz - vn * nz
            speed = math.sqrt(tx * tx + ty * ty + tz * tz)
            scale = min(kt * speed, mu * fn) / max(speed, 1e-12)
            fx, fy, fz = fn * nx - scale * tx, fn * ny - scale * ty, fn * nz - scale * tz
            # World -> pad frame; compression (force into the pad, -z) reads positive.
            out[p, 0, n] = fx * rot[0, 0] + fy * rot[1, 0] + fz * rot[2, 0]
            out[p, 1, n] = fx * rot[0, 1] + fy * rot[1, 1] + fz * rot[2, 1]
            out[p, 2, n] = -(fx * rot[0, 2] + fy * rot[1, 2] + fz * rot[2, 2])


class TactileFieldSensor:
    """Force field on one pad's taxel grid.

    Args:
        rows, cols: taxel grid size (image height and width).
        size_x, size_y: pad face extent along the pad's x (rows) and y (columns) axes (m).
        margin: inset of the outermost taxels from the pad edge (m).
        kn: normal stiffness (force per metre of penetration).
        kt: tangential viscous coefficient (force per m/s of slip).
        mu: Coulomb cap on shear as a multiple of the normal force.
    """

    def __init__(self, rows: int, cols: int, size_x: float, size_y: float, margin: float,
                 kn: float, kt: float, mu: float):
        self.rows, self.cols = rows, cols
        self.kn, self.kt, self.mu = kn, kt, mu
        self.points = taxel_grid(rows, cols, size_x, size_y, margin)  # (N, 3) pad frame

    def field(self, peg: ContactShape, pad_pos, pad_rot, pad_lin_vel, pad_ang_vel,
              peg_pos, peg_rot, peg_lin_vel, peg_ang_vel) -> np.ndarray:
        """(3, rows, cols) map (shear_x, shear_y, normal) of one pad; see `fields`."""
        return self.fields(peg, np.asarray(pad_pos)[None], np.asarray(pad_rot)[None], np.asarray(pad_lin_vel)[None],
                           np.asarray(pad_ang_vel)[None], peg_pos, peg_rot, peg_lin_vel, peg_ang_vel)[0]

    def fields(self, peg: ContactShape, pad_pos, pad_rot, pad_lin_vel, pad_ang_vel,
               peg_pos, peg_rot, peg_lin_vel, peg_ang_vel) -> np.ndarray:
        """(P, 3, rows, cols) maps (shear_x, shear_y, normal), each in its pad's frame, for P pads at once.

        Pad arguments are stacked over pads: positions (P, 3), rotations (P, 3, 3) whose columns are the
        pad axes, world linear velocities of the pad origins (P, 3) and angular velocities (P, 3). The peg
        pose and velocities are (3,) and (3, 3); velocities are world-frame, at the frame origins.
        """
        f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
        out = np.empty((len(pad_pos), 3, len(self.points)))
        normals, offsets = peg.face_arrays
        _fields(self.points, f64(pad_pos), f64(pad_rot), f64(pad_lin_vel), f64(pad_ang_vel), f64(peg_pos),
                f64(peg_rot), f64(peg_lin_vel), f64(peg_ang_vel), peg.is_cylinder, float(peg.radius), normals, offsets,
                float(peg.length), peg.reach * peg.reach, float(self.kn), float(self.kt), float(self.mu), out)
        return out.reshape(len(pad_pos), 3, self.rows, self.cols)
