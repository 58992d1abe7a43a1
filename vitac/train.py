"""Train a visuo-tactile insertion policy with recurrent PPO: `python -m vitac.train [overrides]`."""

from __future__ import annotations

import logging
from pathlib import Path

import hydra
import lightning as L
import torch
from hydra.core.hydra_config import HydraConfig
from lightning.pytorch.callbacks import ModelCheckpoint
from lightning.pytorch.loggers import CSVLogger, WandbLogger
from omegaconf import DictConfig, OmegaConf

from vitac.envs.gym_env import TaskEnv
from vitac.envs.vector_env import TaskVectorEnv
from vitac.rl.callbacks import (
    BestEvaluation,
    CheckpointOnTermination,
    EvaluationCallback,
    IterationProgressBar,
)
from vitac.rl.curriculum import RandomizationCurriculum
from vitac.rl.hyperparameters import check_algo, check_seed, resolve_trainer_threads
from vitac.rl.lr_schedule import make_lr_schedule
from vitac.rl.ppo import PPO
from vitac.run_config import build_policy_from_config, task_settings
from vitac.tasks import make_task_config
from vitac.utils.checkpoint import PortableCheckpointIO, load_checkpoint
from vitac.utils.checks import resolve_groups
from vitac.utils.quiet import quiet_third_party
from vitac.viz import OUTSIDE, VIDEO_OBSERVATIONS

log = logging.getLogger(__name__)


ACCELERATORS = ("cpu", "gpu", "auto")


def check_accelerator(accelerator: str) -> str:
    """The Lightning accelerator for `trainer.accelerator`, refusing a GPU that torch cannot see."""
    if accelerator not in ACCELERATORS:
        raise ValueError(f"trainer.accelerator={accelerator!r} is not allowed: expected one of {list(ACCELERATORS)}")
    if accelerator == "gpu" and not torch.cuda.is_available():
        raise ValueError("trainer.accelerator='gpu' is not allowed here: torch sees no CUDA device "
                         f"(torch {torch.__version__}); use cpu or auto")
    return accelerator


POLICY_GROUPS = ("obs", "encoder", "fusion", "head", "reg", "critic")


def check_resume(cfg: DictConfig, policy, path: Path) -> None:
    """An exact resume needs the checkpoint's weights to fit this policy and its environment states to fit
    algo.num_envs: refused before any environment is built otherwise, pointing to init_ckpt (a warm start)."""
    checkpoint = load_checkpoint(path, key="resume")
    saved_envs = len(checkpoint["vitac"]["env_states"])
    if saved_envs != cfg.algo.num_envs:
        raise ValueError(f"algo.num_envs={cfg.algo.num_envs} is not allowed with resume={cfg.resume!r}: its checkpoint "
                         f"holds the states of {saved_envs} environments; resume with algo.num_envs={saved_envs}, "
                         f"or start a new run from its weights with init_ckpt={path}")
    own = {f"policy.{k}": tuple(v.shape) for k, v in policy.state_dict().items()}
    saved = {k: tuple(v.shape) for k, v in checkpoint["state_dict"].items() if k.startswith("policy.")}
    if own != saved:
        differ = sorted(k for k in own.keys() | saved.keys() if own.get(k) != saved.get(k))
        current = OmegaConf.to_container(cfg, resolve=True)
        groups = [g for g in POLICY_GROUPS if current.get(g) != checkpoint["vitac_config"].get(g)]
        raise ValueError(f"resume={cfg.resume!r} does not fit this policy: {len(differ)} tensors differ in name or "
                         f"shape ({differ[:3]}); config groups set differently from the checkpoint's: {groups}. "
                         f"Resume with the checkpoint's settings, or start a new run from its weights with "
                         f"init_ckpt={path}")


def output_dir(cfg: DictConfig) -> Path:
    if cfg.get("output_dir"):
        return Path(cfg.output_dir)
    return Path(HydraConfig.get().runtime.output_dir)


def train(cfg: DictConfig) -> dict:
    """Validate, seed, build env and policy, run PPO; returns the last metrics and the output paths."""
    # Everything that can be checked without simulating is checked first.
    check_seed(cfg.seed)
    algo = OmegaConf.to_container(cfg.algo, resolve=True)  # the PPO module's keyword arguments, popped below
    algo["num_workers"] = resolve_groups(algo["num_envs"], algo["num_workers"])
    check_algo(algo)
    lr_schedule = make_lr_schedule(algo.pop("lr_schedule"), algo.pop("kl_threshold"), algo.pop("lr_schedule_every"),
                                   algo.pop("lr_min"), algo.pop("lr_max"), algo["lr"])
    curriculum_settings = algo.pop("curriculum")
    curriculum = None
    if curriculum_settings.pop("enabled"):
        curriculum = RandomizationCurriculum(**curriculum_settings)
    settings = task_settings(cfg)
    task_config = make_task_config(settings)
    accelerator = check_accelerator(cfg.trainer.accelerator)
    rollout_threads, update_threads = resolve_trainer_threads(cfg.trainer.rollout_threads, cfg.trainer.update_threads,
                                                              cfg.trainer.deterministic)
    out = output_dir(cfg)
    out.mkdir(parents=True, exist_ok=True)
    if cfg.seed is not None:  # before any weights are initialised
        L.seed_everything(cfg.seed, workers=True)
    policy = build_policy_from_config(cfg, task_config)
    log.info("policy: %s fusion, %d parameters", type(policy.fusion).__name__ if policy.fusion else "no",
             sum(p.numel() for p in policy.parameters()))
    ckpt_path = None
    if cfg.resume:
        ckpt_path = Path(cfg.resume) / "checkpoints" / "last.ckpt"
        if not ckpt_path.is_file():
            raise FileNotFoundError(f"resume={cfg.resume!r}: no checkpoint at {ckpt_path}")
        check_resume(cfg, policy, ckpt_path)
    OmegaConf.save(cfg, out / "config.yaml", resolve=True)
    resolved = OmegaConf.to_container(cfg, resolve=True)
    num_envs, num_workers, step_in_main = algo.pop("num_envs"), algo.pop("num_workers"), algo.pop("step_in_main")
    iterations, eval_every, eval_episodes = algo.pop("iterations"), algo.pop("eval_every"), algo.pop("eval_episodes")
    save_every, video_every = algo.pop("save_every"), algo.pop("eval_video_every")
    checkpoints = ModelCheckpoint(dirpath=out / "checkpoints", filename="iter_{iteration:05.0f}", save_last=True,
                                  every_n_epochs=save_every, save_top_k=-1, auto_insert_metric_name=False)
    best = BestEvaluation(dirpath=out / "checkpoints", filename="best", monitor="eval/success_rate", mode="max",
                          save_top_k=1, auto_insert_metric_name=False)
    video_settings = dict(settings, observations=sorted(set(settings["observations"]) | set(VIDEO_OBSERVATIONS)))
    evaluation = EvaluationCallback(lambda: TaskVectorEnv(settings, num_envs=min(num_envs, eval_episodes),
                                                               num_workers=0, seed=1_000_000),
                                    every=eval_every, episodes=eval_episodes, video_every=video_every,
                                    make_video_env=lambda: TaskEnv(video_settings, seed=1_000_000,
                                                                        offscreen_size=OUTSIDE),
                                    video_dir=out / "videos")
    loggers = [CSVLogger(out, name="csv", version="")]
    if cfg.logger.wandb:
        loggers.append(WandbLogger(save_dir=str(out), offline=True, project=cfg.logger.project,
                                   name=cfg.logger.get("name"), config=resolved))
    trainer = L.Trainer(max_epochs=iterations, accelerator=accelerator, devices=1, logger=loggers,
                        callbacks=[checkpoints, best, evaluation, CheckpointOnTermination(out / "checkpoints" / "last.ckpt"),
                                   IterationProgressBar()], enable_progress_bar=False,
                        enable_model_summary=False, log_every_n_steps=1, num_sanity_val_steps=0,
                        deterministic=cfg.trainer.deterministic, plugins=[PortableCheckpointIO()])
    log.info("policy and PPO update on %s; environments on CPU", trainer.strategy.root_device)
    envs = TaskVectorEnv(settings, num_envs=num_envs, num_workers=num_workers, seed=cfg.seed or 0,
                              step_in_main=step_in_main)
    log.info("env: %d envs in %d groups (the main process steps one: %s), observations %s", num_envs,
             max(num_workers, 1), step_in_main or not num_workers, settings["observations"])
    try:
        module = PPO(policy, envs, freeze_critic=cfg.freeze_critic, seed=cfg.seed or 0,
                     rollout_threads=rollout_threads, update_threads=update_threads,
                     run_config=resolved, curriculum=curriculum, lr_schedule=lr_schedule, **algo)
        if cfg.init_ckpt:
            load_weights(module, cfg.init_ckpt, list(cfg.init_exclude))
        if cfg.critic_ckpt:
            load_critic(module, cfg.critic_ckpt)
        # Our checkpoints carry environment and RNG states (numpy objects): they are our own files.
        trainer.fit(module, ckpt_path=str(ckpt_path) if ckpt_path else None, weights_only=False)
    finally:
        envs.close()
    metrics = {k: float(v) for k, v in trainer.callback_metrics.items()}
    result = dict(metrics=metrics, checkpoint=str(out / "checkpoints" / "last.ckpt"),
                  metrics_csv=str(out / "csv" / "metrics.csv"),
                  wandb=str(out / "wandb") if cfg.logger.wandb else None, preset=cfg.preset.name)
    print(f"\nvitac: preset={cfg.preset.name}, {module.env_steps} env steps, "
          f"success (train episodes) {metrics.get('charts/success_rate', float('nan')):.3f}, "
          f"eval {metrics.get('eval/success_rate', float('nan')):.3f}")
    print(f"  checkpoint: {result['checkpoint']}\n  metrics:    {result['metrics_csv']}")
    if result["wandb"]:
        print(f"  wandb:      {result['wandb']}  (offline; `wandb sync {out}/wandb/offline-run-*` to upload)")
    return result


FEATURE_INPUT = "policy.head.lstm.weight_ih_l0"  # the only layer that reads the fused features


def load_weights(module: PPO, path: str, exclude: list) -> None:
    """Warm start: every tensor of another run's checkpoint except those under an `exclude` prefix.

    When this policy reads vector observations that the checkpoint's did not (e.g. obs=privileged_contact
    from an obs=privileged run), their columns of the feature input layer start at zero and their
    encoders and normalizers fresh: the policy acts exactly as the checkpoint's until PPO learns to use them.
    """
    checkpoint = load_checkpoint(path, key="init_ckpt")
    state = checkpoint["state_dict"]
    own = module.state_dict()
    picked = {k: v for k, v in state.items() if not any(k.startswith(prefix) for prefix in exclude)}
    if FEATURE_INPUT in picked and picked[FEATURE_INPUT].shape[1] < own[FEATURE_INPUT].shape[1]:
        picked[FEATURE_INPUT] = _widen_feature_input(module.policy, picked[FEATURE_INPUT],
                                                     checkpoint["vitac_config"]["obs"]["modalities"], path)
    mismatched = [k for k, v in picked.items() if k not in own or own[k].shape != v.shape]
    if mismatched:
        raise ValueError(f"init_ckpt={path!r} does not fit this policy: {mismatched[:5]} differ in name or shape")
    module.load_state_dict(picked, strict=False)
    log.info("weights from %s (%d tensors; left out: %s)", path, len(picked), sorted(set(state) - set(picked)))


def _widen_feature_input(policy, weight: torch.Tensor, old_modalities: list, path: str) -> torch.Tensor:
    """The checkpoint's feature-input weights with zero columns for the observations it did not read."""
    old_vectors = [k for k in policy.vector_keys if k in old_modalities]
    old_images = [k for k in policy.image_keys if k in old_modalities]
    dropped = set(old_modalities) - set(old_vectors) - set(old_images)
    added = policy.vector_keys[len(old_vectors):]
    # Vector features come last, in the task's order: only added vector observations append columns.
    if (dropped or old_images != policy.image_keys or policy.vector_keys[:len(old_vectors)] != old_vectors
            or not added):
        raise ValueError(f"init_ckpt={path!r} does not fit this policy: it read {sorted(old_modalities)}; a warm "
                         f"start may only add vector observations after those, not change them "
                         f"(this policy reads {policy.image_keys + policy.vector_keys})")
    widened = torch.zeros(weight.shape[0], policy.feature_dim, dtype=weight.dtype)
    widened[:, :weight.shape[1]] = weight
    log.info("init_ckpt: %s enter the policy with zero weights", added)
    return widened


def load_critic(module: PPO, path: str) -> None:
    """TacSL's AACD: start the asymmetric critic (and its input normalizer) from another run's checkpoint."""
    if module.policy.critic is None:
        raise ValueError(f"critic_ckpt={path!r} needs an asymmetric critic: set critic=state")
    state = load_checkpoint(path, key="critic_ckpt")["state_dict"]
    prefixes = ("policy.critic.", "policy.critic_normalizer.", "value_normalizer.")
    picked = {k: v for k, v in state.items() if k.startswith(prefixes)}
    if not picked:
        raise ValueError(f"critic_ckpt={path!r} holds no critic weights")
    missing = module.load_state_dict(picked, strict=False)
    log.info("critic loaded from %s (%d tensors, %d other keys untouched)", path, len(picked),
             len(missing.missing_keys))


@hydra.main(version_base="1.3", config_path="../conf", config_name="config")
def main(cfg: DictConfig) -> float:
    quiet_third_party()
    result = train(cfg)
    return result["metrics"].get("eval/success_rate", float("nan"))


if __name__ == "__main__":
    main()
