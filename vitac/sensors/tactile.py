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

    def signed_distance(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance (negative inside) and outward unit normal for points p (N, 3) in the peg frame."""
        half_z = 0.5 * self.length
        z = p[:, 2] - half_z  # centred on the peg's mid-height
        if self.shape == "round":
            radial = np.hypot(p[:, 0], p[:, 1])
            q = np.stack([radial - self.half_x, np.abs(z) - half_z], axis=1)
            # Inside: nearest of the side (q0) and the caps (q1); outside: Euclidean to the rim.
            inside = np.minimum(np.maximum(q[:, 0], q[:, 1]), 0.0)
            outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
            sdf = inside + outside
            side = q[:, 0] >= q[:, 1]
            safe_r = np.where(radial > 1e-12, radial, 1.0)
            radial_dir = np.stack([p[:, 0] / safe_r, p[:, 1] / safe_r, np.zeros_like(radial)], axis=1)
            radial_dir[radial <= 1e-12] = (1.0, 0.0, 0.0)
            cap_dir = np.zeros_like(p)
            cap_dir[:, 2] = np.sign(z) + (z == 0)
            normal = np.where(side[:, None], radial_dir, cap_dir)
            return sdf, normal
        half = np.array([self.half_x, self.half_y, half_z])
        c = np.stack([p[:, 0], p[:, 1], z], axis=1)
        q = np.abs(c) - half
        outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
        inside = np.minimum(q.max(axis=1), 0.0)
        axis = q.argmax(axis=1)
        normal = np.zeros_like(p)
        normal[np.arange(len(p)), axis] = np.sign(c[np.arange(len(p)), axis]) + (c[np.arange(len(p)), axis] == 0)
        return inside + outside, normal


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

    def field(self, peg: PegGeometry, pad_pos, pad_rot, pad_lin_vel, pad_ang_vel,
              peg_pos, peg_rot, peg_lin_vel, peg_ang_vel) -> np.ndarray:
        """(3, rows, cols) map (shear_x, shear_y, normal) in the pad frame.

        Poses are world positions (3,) and rotation matrices (3, 3) whose columns are the body axes;
        velocities are world-frame linear velocities of the frame origins and angular velocities.
        """
        taxels_world = pad_pos + self.points @ pad_rot.T
        # Taxels in the peg frame; only those near the peg need the full model.
        taxels_peg = (taxels_world - peg_pos) @ peg_rot
        sdf, normal_peg = peg.signed_distance(taxels_peg)
        out = np.zeros((3, self.rows * self.cols))
        touching = sdf < 0.0
        if not touching.any():
            return out.reshape(3, self.rows, self.cols)
        depth = -sdf[touching]
        n_world = normal_peg[touching] @ peg_rot.T  # outward peg normal, pushes the pad
        x = taxels_world[touching]
        fn = self.kn * depth
        # Relative velocity of the taxel with respect to the peg material at the same point.
        v_taxel = pad_lin_vel + np.cross(pad_ang_vel, x - pad_pos)
        v_peg = peg_lin_vel + np.cross(peg_ang_vel, x - peg_pos)
        v_rel = v_taxel - v_peg
        vt = v_rel - n_world * np.sum(n_world * v_rel, axis=1, keepdims=True)
        speed = np.linalg.norm(vt, axis=1, keepdims=True)
        shear_mag = np.minimum(self.kt * speed, self.mu * fn[:, None])
        shear = -shear_mag * vt / np.maximum(speed, 1e-12)
        force_world = fn[:, None] * n_world + shear
        force_pad = force_world @ pad_rot  # world -> pad frame
        out[0, touching] = force_pad[:, 0]
        out[1, touching] = force_pad[:, 1]
        out[2, touching] = -force_pad[:, 2]  # compression (force into the pad) reads positive
        return out.reshape(3, self.rows, self.cols)
