"""Starting a run from checkpoints: the exact-resume check, a warm start from another run's weights, and the
critic of a privileged run (TacSL's AACD)."""

from __future__ import annotations

import logging
from pathlib import Path

import torch

from vitac.utils.checkpoint import load_checkpoint, state_mismatch

log = logging.getLogger(__name__)

class WarmStart(torch.nn.Module):
    """What `init_ckpt` and `critic_ckpt` load into before any environment exists, so that a checkpoint that does
    not fit is refused before workers start: the run's policy itself (loaded in place, later handed to the
    algorithm) and, for an algorithm with one (PPO's), a return normalizer handed over by `into`."""

    def __init__(self, policy, value_normalizer: bool):
        super().__init__()
        from vitac.models.normalizer import RunningNormalizer

        self.policy = policy
        if value_normalizer:
            self.value_normalizer = RunningNormalizer((), clip=float("inf"))

    def into(self, module) -> None:
        """Give the algorithm module the return statistics the checkpoints held (its policy is already ours)."""
        if hasattr(self, "value_normalizer"):
            module.value_normalizer.load_state_dict(self.value_normalizer.state_dict())


POLICY_GROUPS = ("obs", "encoder", "fusion", "head", "reg", "critic", "residual")


def check_resume(run_dir: str, policy, num_envs: int, config: dict) -> Path:
    """The checkpoint an exact resume of `run_dir` continues from. Its weights must fit this policy and its
    environment states `num_envs`: refused before any environment is built otherwise, pointing to init_ckpt
    (a warm start). `config` is this run's resolved config, compared group by group in the message."""
    path = Path(run_dir) / "checkpoints" / "last.ckpt"
    if not path.is_file():
        raise FileNotFoundError(f"resume={run_dir!r}: no checkpoint at {path}")
    checkpoint = load_checkpoint(path, key="resume")
    saved_envs = len(checkpoint["vitac"]["env_states"])
    if saved_envs != num_envs:
        raise ValueError(f"envs.num_envs={num_envs} is not allowed with resume={run_dir!r}: its checkpoint "
                         f"holds the states of {saved_envs} environments; resume with envs.num_envs={saved_envs}, "
                         f"or start a new run from its weights with init_ckpt={path}")
    own = {f"policy.{k}": tuple(v.shape) for k, v in policy.state_dict().items()}
    saved = {k: tuple(v.shape) for k, v in checkpoint["state_dict"].items() if k.startswith("policy.")}
    if own != saved:
        differ = sorted(k for k in own.keys() | saved.keys() if own.get(k) != saved.get(k))
        groups = [g for g in POLICY_GROUPS if config.get(g) != checkpoint["vitac_config"].get(g)]
        raise ValueError(f"resume={run_dir!r} does not fit this policy: {len(differ)} tensors differ in name or "
                         f"shape ({differ[:3]}); config groups set differently from the checkpoint's: {groups}. "
                         f"Resume with the checkpoint's settings, or start a new run from its weights with "
                         f"init_ckpt={path}")
    return path


FEATURE_INPUT = "policy.head.lstm.weight_ih_l0"  # the only layer that reads the fused features


def load_weights(module, path: str, exclude: list) -> None:
    """Warm start: every tensor of another run's checkpoint except those under an `exclude` prefix.

    When this policy reads vector observations that the checkpoint's did not (e.g. obs=privileged_contact
    from an obs=privileged run), their columns of the feature input layer start at zero and their
    encoders and normalizers fresh: the policy acts exactly as the checkpoint's until PPO learns to use them.
    """
    checkpoint = load_checkpoint(path, key="init_ckpt")
    state = checkpoint["state_dict"]
    own = module.state_dict()
    picked = {k: v for k, v in state.items() if k.startswith(("policy.", "value_normalizer."))  # not a teacher's
              and not any(k.startswith(prefix) for prefix in exclude)}
    if FEATURE_INPUT in picked and picked[FEATURE_INPUT].shape[1] < own[FEATURE_INPUT].shape[1]:
        picked[FEATURE_INPUT] = _widen_feature_input(module.policy, picked[FEATURE_INPUT],
                                                     checkpoint["vitac_config"]["obs"]["modalities"], path)
    _, unexpected, shapes = state_mismatch(own, picked)  # the tensors left out start fresh
    mismatched = unexpected + shapes
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


CRITIC_INPUT = "policy.critic.mlp.0.weight"  # the critic's first layer: critic state, then the actor's memory
MEMORY_WIDTH = "policy.head.lstm.weight_hh_l0"  # (4 x hidden, hidden): the actor's memory is `hidden` wide


def load_critic(module, path: str, same_actor: bool = False) -> None:
    """TacSL's AACD: start the asymmetric critic (and its input normalizer) from another run's checkpoint.

    A critic reads the privileged state and, with `reads_actor_memory`, its actor's recurrent features. Columns
    for features the checkpoint's critic did not read start at zero; those it read of its own actor are kept only
    when this run's actor is that one (`same_actor`, e.g. init_ckpt is the same file), since another actor's
    features mean something else: the critic starts as the checkpoint's reading of the state alone.
    """
    critic = module.policy.critic
    if critic is None:
        raise ValueError(f"critic_ckpt={path!r} needs an asymmetric critic: set critic=state")
    checkpoint = load_checkpoint(path, key="critic_ckpt")
    state = checkpoint["state_dict"]
    prefixes = ("policy.critic.", "policy.critic_normalizer.", "value_normalizer.")
    picked = {k: v for k, v in state.items() if k.startswith(prefixes)}
    if not picked:
        raise ValueError(f"critic_ckpt={path!r} holds no critic weights")
    width = critic.mlp[0].in_features
    saved = picked.get(CRITIC_INPUT)
    if saved is not None and checkpoint["vitac_config"].get("critic", {}).get("reads_actor_memory"):
        own_state = saved.shape[1] - state[MEMORY_WIDTH].shape[1]
        if not (same_actor and saved.shape[1] == width) and own_state == critic.state_dim:
            saved = picked[CRITIC_INPUT] = saved[:, :own_state]
            log.info("critic_ckpt: its critic read another actor's memory; those weights are left out")
    if saved is not None and saved.shape[1] < width and critic.reads_actor_memory:
        # A critic that reads the actor's memory, from one that did not: the memory enters with zero weights, so
        # the critic starts as the checkpoint's and learns to use it.
        picked[CRITIC_INPUT] = torch.cat([saved, saved.new_zeros(saved.shape[0], width - saved.shape[1])], dim=1)
    _, unexpected, shapes = state_mismatch(module.state_dict(), picked)
    if unexpected or shapes:
        raise ValueError(f"critic_ckpt={path!r} does not fit this critic: {(unexpected + shapes)[:5]} differ in name "
                         f"or shape")
    missing = module.load_state_dict(picked, strict=False)
    log.info("critic loaded from %s (%d tensors, %d other keys untouched)", path, len(picked),
             len(missing.missing_keys))
