"""Reading and writing vitac checkpoints: read weights-only, written whole; a missing, truncated or foreign file
is refused with a message, as is one whose records fail their checksums."""

from __future__ import annotations

import io
import os
import pickle
import zipfile
from pathlib import Path

import torch
from lightning.pytorch.plugins.io import TorchCheckpointIO

from vitac.utils.records import temporary_beside

CHECKOUT = Path(__file__).resolve().parents[2]  # where pretrained/ lives in a source checkout (pip install -e .)


def resolve_checkpoint(path: str | Path) -> Path:
    """`path` itself, or a shipped policy named without its suffix (`pretrained/privileged` for its `.pt`); a
    relative `pretrained/...` that is not under the working directory is read from the checkout's, so the
    defaults work from any directory."""
    path = Path(path)
    candidates = [path, path.with_suffix(".pt")]
    if not path.is_absolute() and path.parts[:1] == ("pretrained",):
        candidates += [CHECKOUT / c for c in candidates]
    return next((c for c in candidates if c.is_file()), path)


def _numpy_globals() -> list:
    """What numpy arrays and scalars unpickle through: constructors of arrays, dtypes and scalars, no code."""
    import importlib

    import numpy as np
    import numpy.dtypes

    multiarray = importlib.import_module("numpy._core.multiarray" if hasattr(np, "_core") else "numpy.core.multiarray")
    dtypes = [getattr(numpy.dtypes, n) for n in dir(numpy.dtypes) if n.endswith("DType")]
    return [np.ndarray, np.dtype, multiarray._reconstruct, multiarray.scalar, *dtypes]


def check_records(archive_file) -> None:
    """Raise `zipfile.BadZipFile` unless every record of the checkpoint archive (a path or a binary file) matches
    its stored CRC-32. torch does not check them when it loads: a flipped bit in a tensor would load silently as
    other weights."""
    with zipfile.ZipFile(archive_file) as archive:
        for record in archive.infolist():
            if record.CRC:  # 0: written with torch's CRC option off, nothing to check against
                archive.read(record)  # zipfile raises on a mismatch


def safe_load(path: str | Path) -> dict:
    """torch's weights-only unpickler, which also admits numpy arrays and scalars (a training checkpoint's
    environment and RNG states): tensors, containers and numbers only, never code; a checkpoint whose records
    fail their checksums is refused first (`check_records`)."""
    data = io.BytesIO(Path(path).read_bytes())  # read once: the bytes checked are the bytes loaded
    check_records(data)
    data.seek(0)
    with torch.serialization.safe_globals(_numpy_globals()):
        return torch.load(data, map_location="cpu", weights_only=True)


def load_checkpoint(path: str | Path, key: str = "ckpt") -> dict:
    """The checkpoint dict at `path` (a training checkpoint or a shipped policy), read weights-only (`safe_load`).

    Args:
        path: checkpoint file, or a shipped policy's name (`pretrained/privileged`).
        key: the config key that named it, for error messages.
    """
    path = resolve_checkpoint(path)
    if not path.is_file():
        raise FileNotFoundError(f"{key}={str(path)!r}: no such checkpoint file")
    try:
        checkpoint = safe_load(path)
    except pickle.UnpicklingError as err:
        if any(m in str(err).lower() for m in ("unsupported global", "can only build")):  # a file with other objects
            raise ValueError(f"{key}={str(path)!r} holds objects other than tensors, numpy arrays and numbers, which "
                             "vitac does not unpickle (they could run code)") from err
        raise ValueError(f"{key}={str(path)!r} is not a readable vitac checkpoint: {str(err).splitlines()[0][:200]}") from err
    except Exception as err:  # a truncated or foreign file must not be half-read
        raise ValueError(f"{key}={str(path)!r} is not a readable vitac checkpoint: {err}") from err
    if not isinstance(checkpoint, dict) or "vitac_config" not in checkpoint or "state_dict" not in checkpoint:
        raise ValueError(f"{key}={str(path)!r} is not a vitac checkpoint (no stored config or weights)")
    return checkpoint


def state_mismatch(own: dict, weights: dict) -> tuple[list, list, list]:
    """How `weights` fails to fit a module whose state dict is `own`: the names it lacks, the names it has in
    excess, and the names whose tensors have another shape (each sorted)."""
    missing, unexpected = sorted(own.keys() - weights.keys()), sorted(weights.keys() - own.keys())
    return missing, unexpected, sorted(k for k in own.keys() & weights.keys() if own[k].shape != weights[k].shape)


def checkpoint_env_steps(checkpoint: dict) -> int | None:
    """The env steps a policy had trained for: an exported file keeps them at the top, a training checkpoint
    with the rollout loop's state."""
    return checkpoint.get("env_steps") or (checkpoint.get("vitac") or {}).get("env_steps")


def save_whole(obj, path: str | Path) -> None:
    """`torch.save` through a temporary file beside `path`, renamed over it only once complete: a full disk or a
    kill mid-write leaves the previous file whole, and no temporary file behind."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = temporary_beside(path)
    os.close(fd)
    try:
        torch.save(obj, tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def export_policy(path: str | Path, out: str | Path) -> dict:
    """Write the checkpoint's policy as a shipped file: the network and normalizer weights (the value normalizer
    too, for a critic started from it) and the run's config, no optimizer or environment state; readable with
    torch's weights-only unpickler. Returns what was written."""
    checkpoint = load_checkpoint(path)
    config = checkpoint["vitac_config"]
    state = {k: v for k, v in checkpoint["state_dict"].items() if k.startswith(("policy.", "value_normalizer."))}
    shipped = dict(vitac_config=config, state_dict=state, env_steps=checkpoint_env_steps(checkpoint), source=str(path))
    save_whole(shipped, out)
    return shipped


class PortableCheckpointIO(TorchCheckpointIO):
    """Lightning's checkpoint reader, weights-only, with every tensor read onto the CPU, so that a run trained on
    a GPU resumes on a machine without one; Lightning then moves weights and optimizer state to the run's device."""

    def load_checkpoint(self, path, map_location=None, weights_only=None) -> dict:
        return safe_load(path)  # weights-only whatever the caller asked: numpy states admitted, code never

    def save_checkpoint(self, checkpoint, path, storage_options=None) -> None:
        """Write through a temporary file renamed over `path` only once complete: a full disk or a kill mid-write
        leaves the previous checkpoint whole, and the run stops naming the file and the cause."""
        try:
            save_whole(checkpoint, path)
        except OSError as err:
            raise OSError(f"could not write checkpoint {path} ({err.strerror or err}); the previous complete "
                          f"checkpoint there, if any, is intact: free space, then resume=<run dir>") from err
