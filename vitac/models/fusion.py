"""Fusion of the image embeddings by role (vision, left, right): naive concat, gated sum, cross-modal transformer.

Each module takes a dict {role: (B, D) embedding} and names the roles it needs in `requires`; a policy whose
observations lack one is refused by `check_fusion` before anything is built.
"""

from __future__ import annotations

import torch
from torch import nn

from vitac.utils.checks import is_number, refuse

ROLE_ORDER = ("vision", "left", "right")


def check_fusion(fusion_target: str, roles: dict[str, str], obs_name: str | None = None) -> None:
    """Refuse the fusion module at `fusion_target` when the actor's image observations ({key: role}) lack a role
    it fuses; called before anything is built."""
    from vitac.tasks import import_object

    cls = import_object(fusion_target)
    missing = [role for role in getattr(cls, "requires", ()) if role not in roles.values()]
    if missing:
        raise ValueError(f"fusion={getattr(cls, 'config_name', fusion_target)} is not allowed with obs={obs_name}: it "
                         f"fuses the roles {list(cls.requires)} and the actor's images {roles or '(none)'} lack "
                         f"{missing} (wrist: vision, tactile_left: left, tactile_right: right); use fusion=naive, "
                         f"or an obs with every role, e.g. obs=wrist_tactile")


class NaiveFusion(nn.Module):
    """Concatenate whatever image embeddings are present, e.g. [vision, left, right] -> 384-d (TacSL)."""

    requires = ()
    config_name = "naive"

    def __init__(self, embed_dim: int, num_inputs: int):
        super().__init__()
        self.out_dim = embed_dim * num_inputs

    def forward(self, embeddings: dict) -> torch.Tensor:
        return torch.cat([embeddings[role] for role in ROLE_ORDER if role in embeddings], dim=-1)


class GatedFusion(nn.Module):
    """Per-sample softmax weights over [vision, left, right] and their weighted sum (128-d)."""

    requires = ROLE_ORDER
    config_name = "gated"

    def __init__(self, embed_dim: int, num_inputs: int = 3):
        super().__init__()
        self.gate = nn.Linear(3 * embed_dim, 3)
        self.out_dim = embed_dim
        self.last_weights = None

    def forward(self, embeddings: dict) -> torch.Tensor:
        tokens = torch.stack([embeddings[role] for role in ROLE_ORDER], dim=-2)  # (B, 3, D)
        weights = torch.softmax(self.gate(tokens.flatten(-2)), dim=-1)  # (B, 3), sums to one
        self.last_weights = weights.detach()
        return (weights.unsqueeze(-1) * tokens).sum(dim=-2)


class CrossModalTransformer(nn.Module):
    """Self-attention over the tactile tokens [h_L; h_R] (paper eq. 3), then cross-attention with vision
    as query and the tactile tokens as key/value (eq. 4). Output [z_V, z_VT]: 256-d for 128-d embeddings.

    Args:
        embed_dim: token size (the encoders' 128).
        num_heads: attention heads; must divide embed_dim.
        dropout: attention dropout.
    """

    requires = ROLE_ORDER
    config_name = "cmt"

    def __init__(self, embed_dim: int, num_inputs: int = 3, num_heads: int = 4, dropout: float = 0.0):
        super().__init__()
        if not is_number(dropout) or not 0.0 <= dropout < 1.0:
            refuse("fusion.dropout", dropout, "a number in [0, 1)")
        if num_heads < 1 or embed_dim % num_heads:
            raise ValueError(f"fusion.num_heads={num_heads!r} is not allowed: expected a positive divisor of the "
                             f"embedding size {embed_dim}")
        # Learned side embeddings: attention alone is permutation-invariant over [h_L; h_R].
        self.side = nn.Parameter(0.02 * torch.randn(2, embed_dim))
        self.self_attn = nn.MultiheadAttention(embed_dim, num_heads, dropout=dropout, batch_first=True)
        self.self_norm = nn.LayerNorm(embed_dim)
        self.cross_attn = nn.MultiheadAttention(embed_dim, num_heads, dropout=dropout, batch_first=True)
        self.cross_norm = nn.LayerNorm(embed_dim)
        self.out_dim = 2 * embed_dim

    def self_attend(self, left: torch.Tensor, right: torch.Tensor) -> torch.Tensor:
        """The tactile tokens after self-attention (eq. 3), (B, 2, D): [z_L; z_R]."""
        tactile = torch.stack([left, right], dim=1) + self.side  # (B, 2, D)
        z_t, _ = self.self_attn(tactile, tactile, tactile, need_weights=False)
        return self.self_norm(tactile + z_t)

    def forward(self, embeddings: dict) -> torch.Tensor:
        vision, left, right = (embeddings[role] for role in ROLE_ORDER)
        z_t = self.self_attend(left, right)
        query = vision.unsqueeze(1)  # (B, 1, D)
        z_vt, _ = self.cross_attn(query, z_t, z_t, need_weights=False)
        z_vt = self.cross_norm(query + z_vt).squeeze(1)
        return torch.cat([vision, z_vt], dim=-1)
