"""Shared fixtures: Hydra composition of conf/ with overrides."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("WANDB_MODE", "offline")
CONF = str(Path(__file__).resolve().parents[1] / "conf")


def compose_config(overrides=(), output_dir=None):
    GlobalHydra.instance().clear()
    with initialize_config_dir(version_base="1.3", config_dir=CONF):
        cfg = compose(config_name="config", overrides=list(overrides))
    if output_dir is not None:
        from omegaconf import open_dict

        with open_dict(cfg):
            cfg.output_dir = str(output_dir)
    return cfg


@pytest.fixture
def compose_cfg():
    return compose_config
