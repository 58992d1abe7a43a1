"""What a run's resolved config builds for the entry points: the task settings and the policy."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from vitac.models.build import build_policy
from vitac.tasks import DEFAULT_TASK_CONFIG, make_task_config
from vitac.tasks.config import GraspTaskConfig
from vitac.utils.checkpoint import load_checkpoint, state_mismatch


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


def check_modalities(cfg: DictConfig, settings: dict) -> None:
    """Refuse `obs.modalities` naming an observation the task does not declare, by that key (before the task's
    config would refuse the observation list built from it)."""
    declared = make_task_config(dict(settings, observations=[])).observation_specs()
    missing = [k for k in cfg.obs.modalities if k not in declared]
    if missing:
        raise ValueError(f"obs.modalities={list(cfg.obs.modalities)} is not allowed: the task declares no {missing}; "
                         f"expected a subset of {[k for k, s in declared.items() if not s.critic_only]}")


def build_policy_from_config(cfg: DictConfig, task_config: GraspTaskConfig):
    """The run's policy over the observations its task declares for `obs.modalities`."""
    specs = task_config.observation_specs()
    missing = [k for k in cfg.obs.modalities if k not in specs]
    if missing:
        raise ValueError(f"obs.modalities={list(cfg.obs.modalities)} is not allowed: the task declares no {missing}; "
                         f"expected a subset of {list(specs)}")
    actor = {k: specs[k] for k in specs if k in cfg.obs.modalities}
    return build_policy(cfg.encoder, cfg.fusion, cfg.head, cfg.reg, cfg.critic, actor,
                        critic_state_dim=specs["critic_state"].shape[0], obs_name=cfg.obs.get("name"),
                        residual=cfg.get("residual"))


def load_policy(ckpt: str | Path, key: str = "ckpt"):
    """Rebuild the policy from the resolved config stored in the checkpoint, then load its weights."""
    checkpoint = load_checkpoint(ckpt, key=key)
    cfg = OmegaConf.create(checkpoint["vitac_config"])
    if cfg.critic.get("_target_") == "vitac.models.head.StateCritic":  # runs from before models/critic.py
        cfg.critic._target_ = "vitac.models.critic.StateCritic"
    if "bf16" in cfg.encoder.image:
        # Precision is the machine's to pick, not the policy's: runs before `auto` stored true, which emulates
        # bfloat16 on CPUs without it, 6-7x slower at inference (features differ by about 1e-5).
        cfg.encoder.image.bf16 = "auto"
    settings = task_settings(cfg)
    task_config = make_task_config(settings)
    if all(task_config.observation_specs()[k].kind != "image" for k in cfg.obs.modalities):
        # Runs from before fusion and reg were checked against obs recorded the defaults (cmt, sym) beside
        # image-free observations, where neither was ever built: the same policy as naive and none.
        cfg.fusion, cfg.reg.lambda_sym = {"_target_": "vitac.models.fusion.NaiveFusion", "_partial_": True}, 0.0
    policy = build_policy_from_config(cfg, task_config)
    weights = {k[len("policy."):]: v for k, v in checkpoint["state_dict"].items() if k.startswith("policy.")}
    missing, unexpected, shapes = state_mismatch(policy.state_dict(), weights)
    if missing or unexpected or shapes:  # e.g. a hand-edited config, or weights from another architecture
        raise ValueError(f"{key}={str(ckpt)!r}: its weights do not fit the policy its stored config builds "
                         f"(missing {missing[:5]}, unexpected {unexpected[:5]}, other shape {shapes[:5]})")
    policy.load_state_dict(weights)
    return policy, cfg, settings


def load_teacher(cfg: DictConfig, settings: dict) -> dict:
    """For an algorithm that distills (`needs_teacher`): the teacher of `teacher_ckpt`, loaded before anything is
    simulated, with its observations added to `settings`; the keyword arguments it adds to the algorithm."""
    from vitac.tasks import import_object

    if not getattr(import_object(cfg.algo._target_), "needs_teacher", False):
        return {}
    if not cfg.get("teacher_ckpt"):
        raise ValueError("teacher_ckpt=None is not allowed with this algo: pass a trained policy, e.g. "
                         "teacher_ckpt=pretrained/privileged")
    teacher, _, teacher_settings = load_policy(cfg.teacher_ckpt, key="teacher_ckpt")
    theirs, ours = (x.get("_target_") or DEFAULT_TASK_CONFIG for x in (teacher_settings, settings))
    if theirs != ours:  # the observation names are shared between tasks: only the task tells them apart
        raise ValueError(f"teacher_ckpt={cfg.teacher_ckpt!r} is not allowed: its policy was trained on {theirs}, this "
                         f"run's task is {ours}; expected a teacher trained on the same task")
    settings["observations"] += [k for k in teacher.input_keys if k not in settings["observations"]]
    return dict(teacher=teacher)
