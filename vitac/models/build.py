"""Build a policy from the model config groups (encoder, fusion, head, reg, critic) and observation shapes."""

from __future__ import annotations

from vitac.models.policy import VisuoTactilePolicy
from vitac.utils.instantiate import instantiate


def build_policy(encoder, fusion, head, reg, critic, obs_shapes: dict, critic_state_dim: int | None = None):
    """Each argument is that group's config node; `obs_shapes` maps actor observation keys to shapes."""
    has_critic = critic is not None and critic.get("_target_") is not None
    return VisuoTactilePolicy(
        obs_shapes={k: tuple(v) for k, v in obs_shapes.items()},
        image_encoder=instantiate(encoder.image),
        vector_encoder=instantiate(encoder.vector),
        fusion=instantiate(fusion),
        head=instantiate(head),
        regularizer=instantiate(reg),
        critic=instantiate(critic) if has_critic else None,
        critic_state_dim=critic_state_dim if has_critic else None,
    )
