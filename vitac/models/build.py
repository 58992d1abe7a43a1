"""Build a policy from the model config groups (encoder, fusion, head, reg, critic) and observation shapes."""

from __future__ import annotations

from vitac.models.fusion import check_fusion
from vitac.models.policy import VisuoTactilePolicy
from vitac.tasks import import_object
from vitac.tasks.config import ObservationSpec
from vitac.utils.instantiate import instantiate


def build_policy(encoder, fusion, head, reg, critic, obs_specs: dict[str, ObservationSpec],
                 critic_state_dim: int | None = None, obs_name: str | None = None, residual=None):
    """Each argument is that group's config node (`residual` absent or null in runs without one); `obs_specs` are
    the actor's observations as the task declares them. A fusion whose roles the observations lack is refused
    first, naming both."""
    roles = {k: s.role for k, s in obs_specs.items() if s.kind == "image"}
    check_fusion(fusion["_target_"], roles, obs_name)
    if reg.get("lambda_sym", 0) and not {"left", "right"} <= set(roles.values()):
        raise ValueError(f"reg=sym is not allowed with obs={obs_name}: the symmetry prior compares the two pads "
                         f"(roles ['left', 'right']) and the actor's images are {roles or '(none)'}; use reg=none")
    fusion_cls = import_object(fusion["_target_"])
    if reg.get("lambda_sym", 0) and reg.get("placement") == "self_attention" and not hasattr(fusion_cls, "self_attend"):
        raise ValueError(f"reg.placement='self_attention' is not allowed with fusion="
                         f"{getattr(fusion_cls, 'config_name', fusion['_target_'])}: only fusion=cmt has a tactile "
                         "self-attention; use reg.placement=encoder")
    has_critic = critic is not None and critic.get("_target_") is not None
    return VisuoTactilePolicy(
        obs_specs=dict(obs_specs),
        image_encoder=instantiate(encoder.image),
        vector_encoder=instantiate(encoder.vector),
        fusion=instantiate(fusion),
        head=instantiate(head),
        regularizer=instantiate(reg),
        critic=instantiate(critic) if has_critic else None,
        critic_state_dim=critic_state_dim if has_critic else None,
        residual=instantiate(residual) if residual is not None and residual.get("_target_") else None,
    )
