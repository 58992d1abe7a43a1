"""Hydra's basic sweeper, which first composes and checks every job of a multirun: a bad value in any cell stops the
sweep before its first job trains, naming the job and the key (a sweep of 30 cells would otherwise fail hours in)."""

from __future__ import annotations

import sys

from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
from hydra.core.override_parser.overrides_parser import OverridesParser
from omegaconf import OmegaConf, open_dict


class CheckedSweeper(BasicSweeper):
    """`hydra.sweeper` of conf/config.yaml: BasicSweeper's jobs, in its order, each checked as `vitac.train` would
    check it (`vitac.training.check_job`) before the first is launched."""

    def sweep(self, arguments: list[str]):
        from vitac.training import check_job

        parser = OverridesParser.create(config_loader=self.hydra_context.config_loader)
        overrides = parser.parse_overrides(self._parse_config() + list(arguments))
        jobs = [job for batch in self.split_arguments(overrides, None) for job in batch]
        for number, job in enumerate(jobs):
            cfg = self.hydra_context.config_loader.load_sweep_config(self.config, list(job))
            with open_dict(cfg):
                del cfg["hydra"]
            try:
                check_job(OmegaConf.create(OmegaConf.to_container(cfg, resolve=True)))
            except (ValueError, FileNotFoundError) as err:
                print(f"error: job {number} of {len(jobs)} ({' '.join(job)}): {err}; no job was started",
                      file=sys.stderr, flush=True)
                sys.exit(2)
        return super().sweep(arguments)
