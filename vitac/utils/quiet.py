"""A first run prints what vitac says and nothing else: third-party notices that ask nothing of the user go."""

from __future__ import annotations

import logging
import warnings

from lightning.pytorch.loggers import WandbLogger


class _DropTips(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith("💡 Tip")


def quiet_third_party() -> None:
    """Drop Lightning's promotional tip and the deprecation warnings libraries raise about each other's APIs
    (Lightning on torch's pytree, wandb on its own settings); vitac's own warnings stay."""
    logging.getLogger("lightning.pytorch.utilities.rank_zero").addFilter(_DropTips())
    warnings.filterwarnings("ignore", message=r".*isinstance\(treespec, LeafSpec\).*")
    warnings.filterwarnings("ignore", category=DeprecationWarning, module=r"(wandb|lightning|torch)\b")
    # A resume writes into a new run directory by design (resume=<old> hydra.run.dir=<new>): best.ckpt starts anew.
    warnings.filterwarnings("ignore", message=r"The dirpath has changed from")
    # `resume=auto` continues in the run's own directory, whose metrics it first keeps (vitac/run_dirs.py).
    warnings.filterwarnings("ignore", message=r"(Experiment logs|Checkpoint) directory .* exists and is not empty")


class OfflineWandbLogger(WandbLogger):
    """Lightning's WandbLogger in offline mode, without the `anonymous` argument Lightning always passes and
    wandb (0.19 on) warns about whatever its value."""

    def __init__(self, **kwargs):
        super().__init__(offline=True, **kwargs)
        self._wandb_init.pop("anonymous", None)
