"""Fusion of the wrist-image and tactile embeddings: naive concat, gated sum, cross-modal transformer."""

from __future__ import annotations

import torch
from torch import nn


class NaiveFusion(nn.Module):
    """Concatenate whatever image embeddings are present, e.g. [vision, left, right] -> 384-d (TacSL)."""

    requires = ()

    def __init__(self, embed_dim: int, num_inputs: int):
        super().__init__()
        self.out_dim = embed_dim * num_inputs

    def forward(self, vision=None, left=None, right=None) -> torch.Tensor:
        return torch.cat([x for x in (vision, left, right) if x is not None], dim=-1)


class GatedFusion(nn.Module):
    """Per-sample softmax weights over [vision, left, right] and their weighted sum (128-d)."""

    requires = ("wrist", "tactile_left", "tactile_right")

    def __init__(self, embed_dim: int, num_inputs: int = 3):
        super().__init__()
        self.gate = nn.Linear(3 * embed_dim, 3)
        self.out_dim = embed_dim
        self.last_weights = None

    def forward(self, vision, left, right) -> torch.Tensor:
        tokens = torch.stack([vision, left, right], dim=-2)  # (B, 3, D)
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

    requires = ("wrist", "tactile_left", "tactile_right")

    def __init__(self, embed_dim: int, num_inputs: int = 3, num_heads: int = 4, dropout: float = 0.0):
        super().__init__()
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

    def forward(self, vision, left, right) -> torch.Tensor:
        tactile = torch.stack([left, right], dim=1) + self.side  # (B, 2, D)
        z_t, _ = self.self_attn(tactile, tactile, tactile, need_weights=False)
        z_t = self.self_norm(tactile + z_t)
        query = vision.unsqueeze(1)  # (B, 1, D)
        z_vt, _ = self.cross_attn(query, z_t, z_t, need_weights=False)
        z_vt = self.cross_norm(query + z_vt).squeeze(1)
        return torch.cat([vision, z_vt], dim=-1)
