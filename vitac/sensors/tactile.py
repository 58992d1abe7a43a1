"""Penalty-based tactile force field (TacSL's model) on a taxel grid; pure numpy, no simulator import.

Each pad carries a rows x cols grid of taxels on its contact face. The pad frame has x along the
image rows, y along the image columns and z along the face normal, pointing out of the pad towards
the object. At each taxel the peg's signed distance gives a penetration depth d >= 0; the taxel then
feels a normal force kn * d pushing into the pad and a viscous-Coulomb shear
-min(kt * |vt|, mu * fn) * vt / |vt| where vt is the tangential velocity of the taxel relative to the
peg surface. The output per pad is a (3, rows, cols) map of (shear_x, shear_y, normal) in the pad frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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

    def penetration(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For points p (3, N) in the peg frame (rows x, y, z): indices of those strictly inside the peg,
        their depth below the nearest face and that face's outward unit normal (n, 3)."""
        x, y, z, length = p[0], p[1], p[2], self.length
        if self.shape == "round":
            r2 = x * x + y * y
            index = np.flatnonzero((r2 < self.half_x**2) & (z > 0.0) & (z < length))
            xs, ys, zs = x[index], y[index], z[index]
            radial = np.sqrt(r2[index])
            side_depth, cap_depth = self.half_x - radial, np.minimum(zs, length - zs)
            side = side_depth <= cap_depth
            normal = np.zeros((index.size, 3))
            inv = np.where(side, 1.0 / np.maximum(radial, 1e-12), 0.0)
            normal[:, 0], normal[:, 1] = xs * inv, ys * inv
            normal[:, 2] = np.where(side, 0.0, np.where(zs > 0.5 * length, 1.0, -1.0))
            return index, np.where(side, side_depth, cap_depth), normal
        index = np.flatnonzero((np.abs(x) < self.half_x) & (np.abs(y) < self.half_y) & (z > 0.0) & (z < length))
        c = p[:, index].T - (0.0, 0.0, 0.5 * length)  # centred on the box
        slack = np.array([self.half_x, self.half_y, 0.5 * length]) - np.abs(c)
        axis = slack.argmin(axis=1)
        rows = np.arange(index.size)
        normal = np.zeros((index.size, 3))
        normal[rows, axis] = np.where(c[rows, axis] >= 0.0, 1.0, -1.0)
        return index, slack[rows, axis], normal


def taxel_grid(rows: int, cols: int, size_x: float, size_y: float, margin: float) -> np.ndarray:
    """Taxel positions (rows*cols, 3) on the pad face (z = 0), row-major, x along rows, y along columns."""
    xs = np.linspace(-0.5 * size_x + margin, 0.5 * size_x - margin, rows)
    ys = np.linspace(-0.5 * size_y + margin, 0.5 * size_y - margin, cols)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    return np.stack([gx.ravel(), gy.ravel(), np.zeros(rows * cols)], axis=1)


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
        self._points_t = np.ascontiguousarray(self.points.T)  # (3, N): row-wise maths is faster

    def field(self, peg: PegGeometry, pad_pos, pad_rot, pad_lin_vel, pad_ang_vel,
              peg_pos, peg_rot, peg_lin_vel, peg_ang_vel) -> np.ndarray:
        """(3, rows, cols) map (shear_x, shear_y, normal) of one pad; see `fields`."""
        return self.fields(peg, np.asarray(pad_pos)[None], np.asarray(pad_rot)[None], np.asarray(pad_lin_vel)[None],
                           np.asarray(pad_ang_vel)[None], peg_pos, peg_rot, peg_lin_vel, peg_ang_vel)[0]

    def fields(self, peg: PegGeometry, pad_pos, pad_rot, pad_lin_vel, pad_ang_vel,
               peg_pos, peg_rot, peg_lin_vel, peg_ang_vel) -> np.ndarray:
        """(P, 3, rows, cols) maps (shear_x, shear_y, normal), each in its pad's frame, for P pads at once.

        Pad arguments are stacked over pads: positions (P, 3), rotations (P, 3, 3) whose columns are the
        pad axes, world linear velocities of the pad origins (P, 3) and angular velocities (P, 3). The peg
        pose and velocities are (3,) and (3, 3); velocities are world-frame, at the frame origins.
        """
        num_pads, n = len(pad_pos), len(self.points)
        out = np.zeros((num_pads, 3, n))
        # Taxels in the peg frame, (3, P*N): R_peg^T (pad_pos + R_pad p - peg_pos) for every pad.
        local = np.concatenate([(peg_rot.T @ pad_rot[k]) @ self._points_t
                                + (peg_rot.T @ (pad_pos[k] - peg_pos))[:, None] for k in range(num_pads)], axis=1)
        touching, depth, normal_peg = peg.penetration(local)
        if touching.size == 0:
            return out.reshape(num_pads, 3, self.rows, self.cols)
        pad = touching // n
        x = local[:, touching].T @ peg_rot.T  # touching taxels relative to the peg origin, world axes
        r_pad = x - (pad_pos - peg_pos)[pad]  # ... and relative to their pad's origin
        n_world = normal_peg @ peg_rot.T  # outward peg normal: the direction the pad is pushed
        fn = self.kn * depth
        # Velocity of each taxel relative to the peg material at the same point.
        v_rel = np.empty_like(x)
        force_pad = np.empty_like(x)
        for k in range(num_pads):  # per pad: w x r as a product with the skew matrix of w
            sel = pad == k
            v_rel[sel] = (pad_lin_vel[k] - peg_lin_vel) + r_pad[sel] @ _skew(pad_ang_vel[k]).T
        v_rel -= x @ _skew(peg_ang_vel).T
        vt = v_rel - n_world * np.einsum("ij,ij->i", n_world, v_rel)[:, None]
        speed = np.sqrt(np.einsum("ij,ij->i", vt, vt))
        scale = np.minimum(self.kt * speed, self.mu * fn) / np.maximum(speed, 1e-12)
        force = fn[:, None] * n_world - scale[:, None] * vt
        for k in range(num_pads):  # world -> each pad's frame
            sel = pad == k
            force_pad[sel] = force[sel] @ pad_rot[k]
        flat = out.transpose(1, 0, 2).reshape(3, -1)  # (3, P*N) view
        flat[0, touching] = force_pad[:, 0]
        flat[1, touching] = force_pad[:, 1]
        flat[2, touching] = -force_pad[:, 2]  # compression (force into the pad) reads positive
        return flat.reshape(3, num_pads, n).transpose(1, 0, 2).reshape(num_pads, 3, self.rows, self.cols)


def _skew(w: np.ndarray) -> np.ndarray:
    """Matrix K with K @ r = w x r."""
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
