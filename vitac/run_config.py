"""What a run's resolved config builds for the entry points: the task settings and the policy."""

from __future__ import annotations

from omegaconf import DictConfig, OmegaConf

from vitac.models.build import build_policy
from vitac.tasks.config import GraspTaskConfig


def uses_critic(cfg: DictConfig) -> bool:
    return cfg.critic is not None and cfg.critic.get("_target_") is not None


def task_settings(cfg: DictConfig) -> dict:
    """The task's keys with the observations the actor and critic read (runs before the task group: `env`)."""
    settings = OmegaConf.to_container(cfg.task if "task" in cfg else cfg.env, resolve=True)
    keys = list(cfg.obs.modalities)
    if uses_critic(cfg):
        keys.append("critic_state")
    settings["observations"] = keys
    return settings


def build_policy_from_config(cfg: DictConfig, task_config: GraspTaskConfig):
    """The run's policy over the observations its task declares for `obs.modalities`."""
    specs = task_config.observation_specs()
    missing = [k for k in cfg.obs.modalities if k not in specs]
    if missing:
        raise ValueError(f"obs.modalities={list(cfg.obs.modalities)} is not allowed: the task declares no {missing}; "
                         f"expected a subset of {list(specs)}")
    actor = {k: specs[k] for k in specs if k in cfg.obs.modalities}
    return build_policy(cfg.encoder, cfg.fusion, cfg.head, cfg.reg, cfg.critic, actor,
                        critic_state_dim=specs["critic_state"].shape[0], obs_name=cfg.obs.get("name"))
