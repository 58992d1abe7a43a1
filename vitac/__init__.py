"""vitac: visuo-tactile insertion policies on MuJoCo + dm_control composer."""

__version__ = "0.1.0"
