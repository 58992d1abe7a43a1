"""A training run from its whole config: check every value, seed, build the task, policy, environments and
algorithm, fit (the library behind `python -m vitac.train`, vitac/train.py; docs/training.md)."""

from __future__ import annotations

import logging
from pathlib import Path

import lightning as L
from hydra.core.hydra_config import HydraConfig
from lightning.pytorch.loggers import CSVLogger
from omegaconf import DictConfig, OmegaConf

from vitac.algos.callbacks import run_callbacks
from vitac.algos.ppo import PPO
from vitac.algos.run_checks import check_accelerator, check_run, resolve_trainer_threads
from vitac.algos.weights import WarmStart, check_resume, load_critic, load_weights
from vitac.envs.gym_env import TaskEnv
from vitac.models.encoders import ConvSoftArgmaxEncoder
from vitac.run_config import build_policy_from_config, check_modalities, load_teacher, task_settings
from vitac.run_dirs import (
    auto_resume,
    check_output_dir,
    check_same_teacher,
    keep_metrics,
    recover_metrics_row,
    report_run,
    write_teacher_record,
)
from vitac.tasks import import_object, make_task_config
from vitac.utils.checkpoint import PortableCheckpointIO, resolve_checkpoint
from vitac.utils.instantiate import instantiate
from vitac.utils.quiet import OfflineWandbLogger
from vitac.viz import OUTSIDE, VIDEO_OBSERVATIONS

log = logging.getLogger(__name__)


def check_job(cfg: DictConfig, with_policy: bool = True) -> tuple[dict, dict, dict, object]:
    """Every value of a run that can be checked without simulating: the run's groups, the task, the modalities and,
    `with_policy`, the policy's model values (by building one). A multirun checks each of its jobs so before the
    first starts (hydra_plugins/vitac_sweeper). Returns the resolved config, the checked `envs` group, the task's
    settings and its config."""
    resolved = OmegaConf.to_container(cfg, resolve=True)
    envs_cfg = check_run(resolved)
    settings = task_settings(cfg)
    check_modalities(cfg, settings)
    task_config = make_task_config(settings)
    if with_policy:
        build_policy_from_config(cfg, task_config)
    return resolved, envs_cfg, settings, task_config


def train(cfg: DictConfig) -> dict:
    """Check, seed, build task, policy, environments and algorithm, fit; returns the last metrics and paths."""
    # Everything that can be checked without simulating is checked first; the policy, built after seeding,
    # refuses its own values.
    resolved, envs_cfg, settings, task_config = check_job(cfg, with_policy=False)
    accelerator = check_accelerator(cfg.trainer.accelerator)
    rollout_threads, update_threads = resolve_trainer_threads(cfg.trainer.rollout_threads, cfg.trainer.update_threads,
                                                              cfg.trainer.deterministic)
    out = Path(cfg.output_dir) if cfg.get("output_dir") else Path(HydraConfig.get().runtime.output_dir)
    resume = cfg.resume
    if resume == "auto":  # a sweep re-run: skip a finished cell, continue an interrupted one in its directory
        resume, finished = auto_resume(out, cfg.trainer.iterations)
        if finished:
            print(f"vitac: {out} has finished its {cfg.trainer.iterations} iterations (resume=auto): nothing to train")
            return dict(metrics={}, checkpoint=str(out / "checkpoints" / "last.ckpt"), skipped=True,
                        metrics_csv=str(out / "csv" / "metrics.csv"), wandb=None, preset=cfg.preset.name)
    check_output_dir(out)
    if cfg.seed is not None:  # before any weights are initialised
        L.seed_everything(cfg.seed, workers=True, verbose=False)
    policy = build_policy_from_config(cfg, task_config)
    log.info("policy: %s fusion, %d parameters", type(policy.fusion).__name__ if policy.fusion else "no",
             sum(p.numel() for p in policy.parameters()))
    ckpt_path = check_resume(resume, policy, envs_cfg["num_envs"], resolved) if resume else None
    teacher = load_teacher(cfg, settings)  # {} unless the algorithm distills
    if teacher and ckpt_path is not None:
        check_same_teacher(resume, cfg.teacher_ckpt)
    # Warm-start weights load now, before any environment worker starts, so a checkpoint that does not fit is
    # refused at once; the algorithm receives the loaded policy (and return statistics) once it is built.
    warm = WarmStart(policy, value_normalizer=issubclass(import_object(cfg.algo._target_), PPO))
    if cfg.init_ckpt:
        load_weights(warm, cfg.init_ckpt, list(cfg.init_exclude))
    if cfg.critic_ckpt:
        files = [resolve_checkpoint(p).resolve() for p in (cfg.init_ckpt, cfg.critic_ckpt) if p]
        load_critic(warm, cfg.critic_ckpt, same_actor=len(files) == 2 and files[0] == files[1])
    OmegaConf.save(cfg, out / "config.yaml", resolve=True)
    if teacher:
        write_teacher_record(out, cfg.teacher_ckpt)
    if ckpt_path is not None and Path(resume).resolve() == out.resolve():
        keep_metrics(out)  # resumed in place: Lightning's CSV logger would delete the earlier attempt's metrics
    if ckpt_path is not None:
        recover_metrics_row(out, Path(resume), ckpt_path)
    video_settings = dict(settings, observations=sorted(set(settings["observations"]) | set(VIDEO_OBSERVATIONS)))
    make_envs, num_envs = instantiate(OmegaConf.create(envs_cfg)), envs_cfg["num_envs"]
    evaluation = instantiate(cfg.eval, make_envs=lambda: make_envs(settings, num_envs=min(num_envs, cfg.eval.episodes),
                                                                   num_workers=0, step_in_main=False, seed=1_000_000),
                             make_video_env=lambda: TaskEnv(video_settings, seed=1_000_000, offscreen_size=OUTSIDE),
                             video_dir=out / "videos")
    callbacks = run_callbacks(instantiate(cfg.checkpoint, dirpath=out / "checkpoints"), evaluation, out / "checkpoints",
                              cfg.trainer.max_nonfinite_iterations)
    loggers = [CSVLogger(out, name="csv", version="")]
    if cfg.logger.wandb:
        loggers.append(OfflineWandbLogger(save_dir=str(out), project=cfg.logger.project, name=cfg.logger.get("name"),
                                          config=resolved))
    trainer = L.Trainer(max_epochs=cfg.trainer.iterations, accelerator=accelerator, devices=1, logger=loggers,
                        callbacks=callbacks, enable_progress_bar=False, enable_model_summary=False,
                        log_every_n_steps=1, num_sanity_val_steps=0, deterministic=cfg.trainer.deterministic,
                        plugins=[PortableCheckpointIO()])
    log.info("policy and update on %s; environments on CPU", trainer.strategy.root_device)
    images = [e for e in policy.encoders.values() if isinstance(e, ConvSoftArgmaxEncoder)]
    if images:  # all built from encoder.image
        log.info("image convolutions in %s (encoder.image.bf16=%s)",
                 "bfloat16" if images[0].uses_bf16(trainer.strategy.root_device.type) else "float32", images[0].bf16)
    envs = make_envs(settings, seed=cfg.seed or 0)
    log.info("env: %d envs in %d groups (the main process steps one: %s), observations %s", num_envs,
             max(envs_cfg["num_workers"], 1), envs_cfg["step_in_main"] or not envs_cfg["num_workers"],
             settings["observations"])
    try:
        module = instantiate(cfg.algo)(policy, envs, **teacher, seed=cfg.seed or 0,
                                       rollout_threads=rollout_threads, update_threads=update_threads,
                                       run_config=resolved,
                                       curriculum=instantiate(cfg.curriculum) if cfg.curriculum._target_ else None)
        warm.into(module)
        if cfg.freeze_critic and policy.critic is not None:  # AACD with a fixed pre-trained critic
            policy.critic.requires_grad_(False)
        # PortableCheckpointIO reads weights-only whatever this flag says (numpy states admitted, code never);
        # True keeps Lightning from warning about unpickling.
        trainer.fit(module, ckpt_path=str(ckpt_path) if ckpt_path else None, weights_only=True)
    finally:
        envs.close()
    metrics = {k: float(v) for k, v in trainer.callback_metrics.items()}
    return report_run(out, metrics, module.env_steps, cfg.preset.name, wandb=bool(cfg.logger.wandb))
