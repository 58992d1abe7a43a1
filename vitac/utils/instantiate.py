"""The one place that turns configs into objects (so a target whitelist is a one-line change)."""

from __future__ import annotations

from hydra.errors import InstantiationException
from hydra.utils import instantiate as _hydra_instantiate


def instantiate(config, **kwargs):
    """hydra.utils.instantiate with `_convert_="all"` (plain lists and dicts for constructors).

    A constructor's own ValueError (which names the key, the value and what is allowed) is re-raised
    as it is, rather than wrapped in Hydra's InstantiationException.
    """
    try:
        return _hydra_instantiate(config, _convert_="all", **kwargs)
    except InstantiationException as err:
        if isinstance(err.__cause__, ValueError):
            raise err.__cause__ from None
        raise
