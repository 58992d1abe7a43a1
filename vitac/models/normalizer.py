"""Running mean/variance normalizer kept as module buffers, so checkpoints carry its statistics."""

from __future__ import annotations

import torch
from torch import nn


class RunningNormalizer(nn.Module):
    """Normalizes by running statistics (Chan et al.'s parallel update), clipped to +-clip.

    Args:
        shape: feature shape.
        clip: bound on normalized values.
        epsilon: variance floor.
    """

    def __init__(self, shape, clip: float = 5.0, epsilon: float = 1e-8):
        super().__init__()
        self.register_buffer("mean", torch.zeros(shape, dtype=torch.float64))
        self.register_buffer("var", torch.ones(shape, dtype=torch.float64))
        self.register_buffer("count", torch.tensor(epsilon, dtype=torch.float64))
        self.clip, self.epsilon = clip, epsilon

    @torch.no_grad()
    def update(self, x: torch.Tensor) -> None:
        x = x.reshape(-1, *self.mean.shape).to(self.mean.device, torch.float64)  # e.g. CPU rollouts, GPU stats
        batch_mean, batch_var, n = x.mean(0), x.var(0, unbiased=False), x.shape[0]
        delta, total = batch_mean - self.mean, self.count + n
        self.mean += delta * n / total
        self.var = (self.var * self.count + batch_var * n + delta**2 * self.count * n / total) / total
        self.count = total

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        std = torch.sqrt(self.var + self.epsilon).to(x.dtype)
        return ((x - self.mean.to(x.dtype)) / std).clamp(-self.clip, self.clip)

    def denormalize(self, x: torch.Tensor) -> torch.Tensor:
        return x * torch.sqrt(self.var + self.epsilon).to(x.dtype) + self.mean.to(x.dtype)


class ForceFieldScale(nn.Module):
    """Divides tactile force fields (C, H, W) by each channel's running root mean square over taxels and samples.

    Raw fields are newtons per taxel, about 1e-3 to 3e-2 in a grasp: at that scale the encoders' biases swamp
    their input and a student learns nothing from touch. No centering, so zero force stays zero and a mirrored
    field (rows flipped, one shear channel negated) scales as the field does; one instance serves both pads, so
    the symmetry prior compares maps on one scale. Before its first update it is the identity.

    Args:
        channels: force components per taxel.
        clip: bound on scaled values (a contact spike many times the typical force).
        epsilon: floor of the mean square.
    """

    def __init__(self, channels: int, clip: float = 20.0, epsilon: float = 1e-10):
        super().__init__()
        self.register_buffer("mean_square", torch.ones(channels, dtype=torch.float64))
        self.register_buffer("count", torch.tensor(epsilon, dtype=torch.float64))
        self.clip, self.epsilon = clip, epsilon

    @torch.no_grad()
    def update(self, x: torch.Tensor) -> None:
        """x: (N, C, H, W) maps; each counts as one sample of each channel's mean square."""
        x = x.to(self.mean_square.device, torch.float64)
        n = x.shape[0]
        total = self.count + n
        self.mean_square = (self.mean_square * self.count + x.square().mean(dim=(0, 2, 3)) * n) / total
        self.count = total

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        scale = torch.sqrt(self.mean_square + self.epsilon).to(x.dtype)[:, None, None]
        return (x / scale).clamp(-self.clip, self.clip)
