"""A residual policy on a frozen student (ResiP, Ankile et al. 2024): a small network adds a correction to the
distilled student's mean action and learns by PPO, while the student stays exactly as distilled."""

from __future__ import annotations

import torch
from torch import nn

from vitac.models.head import mlp
from vitac.utils.checks import check_widths, is_number, refuse


class ResidualHead(nn.Module):
    """mean = student mean + `action_scale` * MLP(student's recurrent features, student mean), and a trained
    state-independent log-std of its own.

    The MLP's last layer starts at zero, so at initialisation the policy's mean is the student's, bit for bit;
    `action_scale` keeps the correction small while PPO finds it, and a low `log_std_init` keeps exploration
    near the student's behaviour. Both inputs are detached: no gradient reaches the student.

    Args:
        in_dim: size of the student's recurrent features (the policy passes its head's LSTM width).
        action_dim: action size.
        units: MLP widths.
        action_scale: the correction's scale in action units (actions are in [-1, 1]).
        log_std_init, log_std_min, log_std_max: the log standard deviation at start and its clamp.
    """

    def __init__(self, in_dim: int, action_dim: int = 6, units=(256, 128), action_scale: float = 0.1,
                 log_std_init: float = -2.0, log_std_min: float = -5.0, log_std_max: float = 0.0):
        super().__init__()
        check_widths("residual.units", units)
        if not is_number(action_scale) or not action_scale > 0:
            refuse("residual.action_scale", action_scale, "a number > 0")
        if not (is_number(log_std_min) and is_number(log_std_max) and is_number(log_std_init)
                and log_std_min <= log_std_init <= log_std_max):
            refuse("residual.log_std_init", log_std_init,
                   f"a number in [residual.log_std_min, residual.log_std_max] = [{log_std_min}, {log_std_max}]")
        self.mlp, d = mlp(in_dim + action_dim, units)
        self.delta = nn.Linear(d, action_dim)
        nn.init.zeros_(self.delta.weight)
        nn.init.zeros_(self.delta.bias)
        self.log_std = nn.Parameter(torch.full((action_dim,), float(log_std_init)))
        self.action_scale, self.log_std_min, self.log_std_max = action_scale, log_std_min, log_std_max

    def forward(self, memory: torch.Tensor, student_mean: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """memory (..., in_dim), student_mean (..., A) -> mean and log_std (..., A)."""
        memory, student_mean = memory.detach(), student_mean.detach()
        delta = self.delta(self.mlp(torch.cat([memory, student_mean], dim=-1)))
        log_std = self.log_std.clamp(self.log_std_min, self.log_std_max).expand_as(student_mean)
        return student_mean + self.action_scale * delta, log_std
