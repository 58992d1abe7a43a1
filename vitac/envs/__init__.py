"""gymnasium adapters over any task: one environment, and many in worker processes."""

import vitac.sim  # noqa: F401  (selects headless EGL before dm_control loads)
