"""Reading vitac checkpoints: a missing, truncated or foreign file is refused with a message."""

from __future__ import annotations

from pathlib import Path

import torch
from lightning.pytorch.plugins.io import TorchCheckpointIO


def load_checkpoint(path: str | Path, key: str = "ckpt") -> dict:
    """The checkpoint dict at `path` (our own files: they carry numpy RNG and environment states).

    Args:
        path: checkpoint file.
        key: the config key that named it, for error messages.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{key}={str(path)!r}: no such checkpoint file")
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as err:  # a truncated or foreign file must not be half-read
        raise ValueError(f"{key}={str(path)!r} is not a readable vitac checkpoint: {err}") from err
    if not isinstance(checkpoint, dict) or "vitac_config" not in checkpoint or "state_dict" not in checkpoint:
        raise ValueError(f"{key}={str(path)!r} is not a vitac checkpoint (no stored config or weights)")
    return checkpoint


class PortableCheckpointIO(TorchCheckpointIO):
    """Lightning's checkpoint reader with every tensor read onto the CPU, so that a run trained on a GPU
    resumes on a machine without one; Lightning then moves weights and optimizer state to the run's device."""

    def load_checkpoint(self, path, map_location=None, weights_only=None) -> dict:
        return super().load_checkpoint(path, map_location="cpu", weights_only=weights_only)
