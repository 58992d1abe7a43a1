"""Bilateral symmetry prior (paper eq. 6): MSE between h_L and the embedding of the right map mirrored into the
left pad's frame.

The pads' frames are set up so that the right pad is the left one turned by pi about the hand's axis: its
rows (dim -2, the pad's x axis) run the other way. Mirroring a map into the other pad's frame therefore
reverses its rows and, in the channel of shear along the rows (channel 0, shear_x), the sign: then for any
mirror-symmetric grasp, a peg tilted about the closing axis included, the mirrored right map equals the left
map in all three channels (tested on the simulated grasp). The paper's literal image flip reverses the rows
only (`reg.mirror=image`): a symmetric grasp then still leaves shear_x at twice its size apart.

Read as an invariance, the prior says the left slot's representation is the same for the scene and for its mirror
image, in which the left pad feels the right pad's field mirrored. `reg.placement=self_attention` asks that of the
left token after CMT's tactile self-attention (which mixes both pads): the scene's tokens [h_L; h_R] against the
mirror image's [enc_R(mirror(right)); enc_L(mirror(left))], each pad's field through its own encoder as in eq. 6.
"""

from __future__ import annotations

import torch
from torch import nn


def flip_vertical(image: torch.Tensor) -> torch.Tensor:
    """Reverse the rows of (..., H, W) images (the paper's image flip)."""
    return torch.flip(image, dims=(-2,))


def mirror_pad(field: torch.Tensor) -> torch.Tensor:
    """A (..., 3, H, W) force field (shear_x, shear_y, normal) mirrored into the other pad's frame: rows reversed
    and the shear along them negated."""
    sign = torch.ones(field.shape[-3], dtype=field.dtype, device=field.device)
    sign[0] = -1.0
    return flip_vertical(field) * sign[:, None, None]


MIRRORS = {"physical": mirror_pad, "image": flip_vertical}
WEIGHTINGS = ("absolute", "relative")
PLACEMENTS = ("encoder", "self_attention")


class SymmetryRegularizer(nn.Module):
    """L_sym = E ||h_L - enc(mirror(right))||^2, weighted by lambda_sym in the total loss.

    Args:
        lambda_sym: weight of the term (0 turns it off).
        mirror: "physical" (rows reversed and shear_x negated: the right pad's field in the left pad's frame) or
            "image" (the paper's literal row flip).
        weighting: "absolute" (the term is lambda_sym * L_sym, the paper's) or "relative" (the term's value is
            lambda_sym times the size of the main loss, every minibatch: the same weight is the same share of the
            loss under imitation, where L_sym falls to ~1e-3, and under PPO, where it outweighs PPO's own loss).
        placement: where the loss reads the left pad's representation: "encoder" (its embedding h_L, the paper's)
            or "self_attention" (its token after CMT's tactile self-attention; fusion=cmt only).
    """

    def __init__(self, lambda_sym: float = 1.0, mirror: str = "physical", weighting: str = "absolute",
                 placement: str = "encoder"):
        super().__init__()
        if isinstance(lambda_sym, bool) or not isinstance(lambda_sym, (int, float)):
            raise ValueError(f"reg.lambda_sym={lambda_sym!r} is not allowed: expected a number >= 0")
        if lambda_sym < 0:
            raise ValueError(f"reg.lambda_sym={lambda_sym!r} is not allowed: expected a number >= 0")
        if mirror not in MIRRORS:
            raise ValueError(f"reg.mirror={mirror!r} is not allowed: expected one of {list(MIRRORS)}")
        if weighting not in WEIGHTINGS:
            raise ValueError(f"reg.weighting={weighting!r} is not allowed: expected one of {list(WEIGHTINGS)}")
        if placement not in PLACEMENTS:
            raise ValueError(f"reg.placement={placement!r} is not allowed: expected one of {list(PLACEMENTS)}")
        self.lambda_sym = float(lambda_sym)
        self.mirror = mirror
        self.weighting = weighting
        self.placement = placement

    @property
    def active(self) -> bool:
        return self.lambda_sym > 0

    def per_sample(self, left_embedding: torch.Tensor, right_encoder: nn.Module, right_image: torch.Tensor) -> torch.Tensor:
        """||h_L - enc_R(mirror(right))||^2 averaged over embedding dimensions, one value per sample."""
        mirrored = right_encoder(MIRRORS[self.mirror](right_image))
        return ((left_embedding - mirrored) ** 2).mean(dim=-1)

    def per_sample_attended(self, fusion: nn.Module, encoders: tuple[nn.Module, nn.Module],
                            images: tuple[torch.Tensor, torch.Tensor], embeddings: tuple[torch.Tensor, torch.Tensor],
                            ) -> torch.Tensor:
        """The left token after `fusion.self_attend` for the scene against the same for its mirror image, as
        ||.||^2 averaged over dimensions per sample; each pair is (left, right)."""
        mirror = MIRRORS[self.mirror]
        (left_encoder, right_encoder), (left_image, right_image) = encoders, images
        scene = fusion.self_attend(*embeddings)
        mirrored = fusion.self_attend(right_encoder(mirror(right_image)), left_encoder(mirror(left_image)))
        return ((scene[:, 0] - mirrored[:, 0]) ** 2).mean(dim=-1)

    def term(self, sym_loss: torch.Tensor, main_loss: torch.Tensor) -> torch.Tensor:
        """The prior's share of the total loss, given L_sym and the loss it is added to.

        Relative weighting rescales L_sym by |main| / L_sym, both detached: the gradient is L_sym's, scaled so that
        the term's value is lambda_sym * |main|."""
        if self.weighting == "absolute" or not self.active:
            return self.lambda_sym * sym_loss
        scale = main_loss.detach().abs() / sym_loss.detach().clamp_min(1e-12)
        return self.lambda_sym * scale * sym_loss
