"""The one place that turns configs into objects (so a target whitelist is a one-line change)."""

from __future__ import annotations

from hydra.utils import instantiate as _hydra_instantiate


def instantiate(config, **kwargs):
    """hydra.utils.instantiate with `_convert_="all"` so constructors receive plain lists and dicts."""
    return _hydra_instantiate(config, _convert_="all", **kwargs)
