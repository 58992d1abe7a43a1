"""Insertion task on MuJoCo + dm_control composer, with gymnasium adapters."""

import os

# Headless rendering through EGL (Mesa llvmpipe on CPU machines); must be set before dm_control loads.
os.environ.setdefault("MUJOCO_GL", "egl")
