"""Train a policy: `python -m vitac.train [overrides]` (conf/config.yaml; docs/training.md, docs/running.md). The run itself is
vitac/training.py, which scripts and tests import."""

from __future__ import annotations

import sys

import hydra
from omegaconf import DictConfig

from vitac.training import train
from vitac.utils.cli import refusals_in_one_line, refuse_unusable_output_folders
from vitac.utils.quiet import quiet_third_party


@hydra.main(version_base="1.3", config_path="../conf", config_name="config")
@refusals_in_one_line
def main(cfg: DictConfig) -> float:
    quiet_third_party()
    return train(cfg)["metrics"].get("eval/success_rate", float("nan"))


if __name__ == "__main__":
    refuse_unusable_output_folders(sys.argv[1:])
    main()
