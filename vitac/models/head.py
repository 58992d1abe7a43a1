"""Recurrent actor-critic head: 2-layer LSTM -> ELU MLP -> Gaussian mean, bounded log-std, value."""

from __future__ import annotations

import torch
from torch import nn

from vitac.utils.checks import check_int, check_widths


def mlp(in_dim: int, units, activation=nn.ELU) -> tuple[nn.Sequential, int]:
    layers, d = [], in_dim
    for u in units:
        layers += [nn.Linear(d, u), activation()]
        d = u
    return nn.Sequential(*layers), d


class RecurrentActorHead(nn.Module):
    """LSTM (hidden, layers) -> MLP -> mean, log-std (bounded to [log_std_min, log_std_max]) and value.

    The recurrent state (h, c), each (layers, B, hidden), is passed in and out; it is zeroed at every
    step whose `episode_start` flag is set, before that step's input is consumed.

    Args:
        in_dim: size of the fused feature vector.
        action_dim: action size (6).
        hidden, layers: LSTM size.
        units: MLP widths.
        log_std_min, log_std_max: bounds of the log standard deviation.
        log_std_init: the log standard deviation at initialisation (TacSL's 0).
        log_std_mode: where the log-std comes from: "state" (a linear layer on the features, TacSL's
            rl_games `fixed_sigma: False`), "param" (one trained value per action dimension, whatever the
            state: rl_games' `fixed_sigma: True`, cleanrl) or "fixed" (log_std_init, never trained: the mean
            action alone has to earn the reward).
        log_std_bound: "clamp" (hard: no gradient once the layer's output passes a bound, so a log-std that
            PPO pushed past the maximum stays there) or "sigmoid" (min + (max - min) * sigmoid(x): a gradient
            everywhere).
    """

    def __init__(self, in_dim: int, action_dim: int = 6, hidden: int = 256, layers: int = 2,
                 units=(256, 128, 64), log_std_min: float = -5.0, log_std_max: float = 1.0,
                 log_std_init: float = 0.0, log_std_bound: str = "clamp", log_std_mode: str = "state"):
        super().__init__()
        for name, value in (("action_dim", action_dim), ("hidden", hidden), ("layers", layers)):
            check_int(f"head.{name}", value, 1)
        check_widths("head.units", units)
        if log_std_min >= log_std_max:
            raise ValueError(f"head.log_std_min={log_std_min!r} is not allowed: expected less than "
                             f"head.log_std_max={log_std_max!r}")
        if log_std_bound not in ("clamp", "sigmoid"):
            raise ValueError(f"head.log_std_bound={log_std_bound!r} is not allowed: expected 'clamp' or 'sigmoid'")
        if log_std_mode not in ("state", "param", "fixed"):
            raise ValueError(f"head.log_std_mode={log_std_mode!r} is not allowed: expected 'state', 'param' or 'fixed'")
        if log_std_bound == "clamp" and not log_std_min <= log_std_init <= log_std_max:
            raise ValueError(f"head.log_std_init={log_std_init!r} is not allowed: expected a number in [head.log_std_min, "
                             f"head.log_std_max] = [{log_std_min}, {log_std_max}]")
        if log_std_bound == "sigmoid" and not log_std_min < log_std_init < log_std_max:
            raise ValueError(f"head.log_std_init={log_std_init!r} is not allowed with log_std_bound='sigmoid': "
                             f"expected a number strictly between {log_std_min} and {log_std_max}")
        self.lstm = nn.LSTM(in_dim, hidden, num_layers=layers)
        self.mlp, d = mlp(hidden, units)
        self.mean = nn.Linear(d, action_dim)
        self.value = nn.Linear(d, 1)
        self.hidden, self.layers = hidden, layers
        self.log_std_min, self.log_std_max, self.log_std_bound = log_std_min, log_std_max, log_std_bound
        self.log_std_mode = log_std_mode
        for name, p in self.lstm.named_parameters():  # cleanrl's LSTM init
            if "bias" in name:
                nn.init.constant_(p, 0.0)
            else:
                nn.init.orthogonal_(p, 1.0)
        nn.init.orthogonal_(self.mean.weight, 0.01)
        nn.init.zeros_(self.mean.bias)
        if log_std_bound == "sigmoid":  # the raw value whose bounded value is log_std_init
            fraction = (log_std_init - log_std_min) / (log_std_max - log_std_min)
            log_std_init = float(torch.logit(torch.tensor(fraction)))
        if log_std_mode == "state":
            self.log_std = nn.Linear(d, action_dim)
            nn.init.zeros_(self.log_std.weight)
            nn.init.constant_(self.log_std.bias, log_std_init)
        elif log_std_mode == "param":
            self.log_std = nn.Parameter(torch.full((action_dim,), log_std_init))
        else:  # a buffer: saved with the weights, never handed to the optimizer
            self.register_buffer("log_std", torch.full((action_dim,), log_std_init))

    def initial_state(self, batch: int, device=None) -> tuple[torch.Tensor, torch.Tensor]:
        zeros = torch.zeros(self.layers, batch, self.hidden, device=device)
        return zeros, zeros.clone()

    def forward(self, features: torch.Tensor, state, episode_starts: torch.Tensor, with_memory: bool = False):
        """features (T, B, F), episode_starts (T, B) -> mean, log_std (T, B, A), value (T, B), state and, with
        `with_memory`, the LSTM's output (T, B, hidden): the recurrent features an asymmetric critic may read."""
        h, c = state
        if features.shape[0] == 1:  # one step (rollout, evaluation): fused cells beat the sequence kernel
            out, (h, c) = self._lstm_step(features[0], h, c, 1.0 - episode_starts[0].float())
            memory = out.unsqueeze(0)
        else:
            memory, (h, c) = self._lstm_sequence(features, h, c, episode_starts)
        x = self.mlp(memory)
        outputs = self.mean(x), self._bounded_log_std(x), self.value(x).squeeze(-1), (h, c)
        return (*outputs, memory) if with_memory else outputs

    def _lstm_sequence(self, features: torch.Tensor, h: torch.Tensor, c: torch.Tensor, episode_starts: torch.Tensor):
        """The LSTM over (T, B, F), run over whole segments between the times at which any sequence starts an
        episode, masking the state only there (rl_games' RnnWithDones): one call instead of one per step."""
        starts = episode_starts.float()
        cuts = [0] + [t for t in range(1, starts.shape[0]) if bool(starts[t].any())] + [starts.shape[0]]
        outputs = []
        for begin, end in zip(cuts[:-1], cuts[1:], strict=True):
            keep = (1.0 - starts[begin]).view(1, -1, 1)
            out, (h, c) = self.lstm(features[begin:end], (h * keep, c * keep))
            outputs.append(out)
        return torch.cat(outputs, dim=0), (h, c)

    def _bounded_log_std(self, x: torch.Tensor) -> torch.Tensor:
        raw = self.log_std(x) if self.log_std_mode == "state" else self.log_std.expand(*x.shape[:-1], -1)
        if self.log_std_bound == "sigmoid":
            return self.log_std_min + (self.log_std_max - self.log_std_min) * torch.sigmoid(raw)
        return raw.clamp(self.log_std_min, self.log_std_max)

    def _lstm_step(self, x: torch.Tensor, h: torch.Tensor, c: torch.Tensor, keep: torch.Tensor):
        """One time step through every layer with torch.lstm_cell and nn.LSTM's own weights.

        x (B, F) -> output (B, H) and the new state (h, c), each (layers, B, H)."""
        keep = keep.view(-1, 1)
        hs, cs = [], []
        for layer in range(self.layers):
            weights = [getattr(self.lstm, f"{name}_l{layer}") for name in ("weight_ih", "weight_hh", "bias_ih", "bias_hh")]
            h_l, c_l = torch.lstm_cell(x, (h[layer] * keep, c[layer] * keep), *weights)
            hs.append(h_l)
            cs.append(c_l)
            x = h_l
        return x, (torch.stack(hs), torch.stack(cs))
