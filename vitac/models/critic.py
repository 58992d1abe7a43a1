"""The asymmetric critic (TacSL's asymmetric actor-critic): the value from the privileged critic state."""

from __future__ import annotations

import torch
from torch import nn

from vitac.models.head import mlp
from vitac.utils.checks import check_widths


class StateCritic(nn.Module):
    """Asymmetric critic: an ELU MLP on the privileged critic state (fully observed, so no memory needed)."""

    def __init__(self, in_dim: int, units=(256, 128, 64)):
        super().__init__()
        check_widths("critic.units", units)
        self.mlp, d = mlp(in_dim, units)
        self.value = nn.Linear(d, 1)

    def forward(self, critic_state: torch.Tensor) -> torch.Tensor:
        return self.value(self.mlp(critic_state)).squeeze(-1)
