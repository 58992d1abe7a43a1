"""Bilateral symmetry prior (paper eq. 6): MSE between h_L and the embedding of the vertically flipped right map.

"Vertical" is the image's row axis (dim -2). The pads' frames are set up so that for a centred,
symmetric grasp the right map with its rows reversed equals the left map (see docs/environment.md).
"""

from __future__ import annotations

import torch
from torch import nn


def flip_vertical(image: torch.Tensor) -> torch.Tensor:
    """Reverse the rows of (..., H, W) images."""
    return torch.flip(image, dims=(-2,))


class SymmetryRegularizer(nn.Module):
    """L_sym = E ||h_L - enc(flip(right))||^2, weighted by lambda_sym in the total loss.

    Args:
        lambda_sym: weight of the term (0 turns it off).
    """

    def __init__(self, lambda_sym: float = 1.0):
        super().__init__()
        if isinstance(lambda_sym, bool) or not isinstance(lambda_sym, (int, float)):
            raise ValueError(f"reg.lambda_sym={lambda_sym!r} is not allowed: expected a number >= 0")
        if lambda_sym < 0:
            raise ValueError(f"reg.lambda_sym={lambda_sym!r} is not allowed: expected a number >= 0")
        self.lambda_sym = float(lambda_sym)

    @property
    def active(self) -> bool:
        return self.lambda_sym > 0

    @staticmethod
    def per_sample(left_embedding: torch.Tensor, right_encoder: nn.Module, right_image: torch.Tensor) -> torch.Tensor:
        """||h_L - enc_R(flip(right))||^2 averaged over embedding dimensions, one value per sample."""
        mirrored = right_encoder(flip_vertical(right_image))
        return ((left_embedding - mirrored) ** 2).mean(dim=-1)
