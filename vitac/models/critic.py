"""The asymmetric critic (TacSL's asymmetric actor-critic): the value from the privileged critic state."""

from __future__ import annotations

import torch
from torch import nn

from vitac.models.head import mlp
from vitac.utils.checks import check_flag, check_widths


class StateCritic(nn.Module):
    """Asymmetric critic: an ELU MLP on the privileged critic state, and with `reads_actor_memory` on the actor's
    recurrent features beside it (the LSTM's output, detached: the critic's loss never moves the actor).

    The state is fully observed, so a critic needs no memory of its own; but the return an actor with memory
    earns depends on what it remembers, and a critic blind to that gives biased advantages (Baisero and Amato's
    asymmetric actor-critic for partially observed tasks): a student fine-tuned by PPO acts on its memory.

    Args:
        in_dim: size of the critic state.
        units: MLP widths.
        memory_dim: size of the actor's recurrent features (the policy passes its head's).
        reads_actor_memory: whether the critic reads them.
    """

    def __init__(self, in_dim: int, units=(256, 128, 64), memory_dim: int = 0, reads_actor_memory: bool = False):
        super().__init__()
        check_widths("critic.units", units)
        check_flag("critic.reads_actor_memory", reads_actor_memory)
        self.reads_actor_memory = reads_actor_memory
        self.state_dim = in_dim
        self.mlp, d = mlp(in_dim + (memory_dim if reads_actor_memory else 0), units)
        self.value = nn.Linear(d, 1)

    def forward(self, critic_state: torch.Tensor, memory: torch.Tensor | None = None) -> torch.Tensor:
        if self.reads_actor_memory:
            critic_state = torch.cat([critic_state, memory.detach()], dim=-1)
        return self.value(self.mlp(critic_state)).squeeze(-1)
