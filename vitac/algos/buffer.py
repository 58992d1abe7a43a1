"""Rollout storage in (T, N) layout and sequence minibatches for the recurrent policy."""

from __future__ import annotations

import torch


def check_batch_layout(horizon: int, num_envs: int, seq_len: int, minibatch_size: int) -> None:
    """Refuse layouts that would silently drop or misalign steps (rl_games checks only some of these)."""
    if horizon % seq_len:
        raise ValueError(f"algo.horizon={horizon} is not allowed: expected a multiple of algo.seq_len={seq_len}")
    if minibatch_size % seq_len:
        raise ValueError(f"algo.minibatch_size={minibatch_size} is not allowed: expected a multiple of "
                         f"algo.seq_len={seq_len}")
    if (horizon * num_envs) % minibatch_size:
        raise ValueError(f"algo.minibatch_size={minibatch_size} is not allowed: expected a divisor of "
                         f"horizon * num_envs = {horizon * num_envs}")


class RolloutBuffer:
    """Holds one rollout: obs (T, N, ...), actions, log-probs, values, rewards, episode starts and ends,
    bootstrap values, and the recurrent state at the start of every seq_len chunk."""

    def __init__(self, horizon: int, num_envs: int, seq_len: int):
        self.horizon, self.num_envs, self.seq_len = horizon, num_envs, seq_len
        self.obs: dict[str, torch.Tensor] = {}
        self.chunk_states: list = []

    def allocate(self, obs_example: dict, action_dim: int) -> None:
        t, n = self.horizon, self.num_envs
        self.obs = {k: torch.zeros((t, n, *v.shape[1:]), dtype=v.dtype) for k, v in obs_example.items()}
        self.actions = torch.zeros(t, n, action_dim)
        self.log_probs, self.values, self.rewards = torch.zeros(t, n), torch.zeros(t, n), torch.zeros(t, n)
        self.starts, self.ends, self.next_values = torch.zeros(t, n), torch.zeros(t, n), torch.zeros(t, n)
        self.chunk_states = [None] * (t // self.seq_len)

    def minibatches(self, minibatch_size: int, generator: torch.Generator,
                    fields=("actions", "log_probs", "values", "advantages", "returns")):
        """Yield dicts of (L, B, ...) tensors, B = minibatch_size / L chunks of L consecutive steps of one env:
        the observations, episode starts, recurrent state at each chunk's start and the named per-step `fields`
        (PPO's by default; an algorithm may store its own, e.g. DAgger's `labels`).

        Every (t, env) appears exactly once per call; chunk order is shuffled by `generator`.
        """
        L, n = self.seq_len, self.num_envs
        chunks_per_env = self.horizon // L
        total = chunks_per_env * n
        per_batch = minibatch_size // L
        order = torch.randperm(total, generator=generator)
        for start in range(0, total, per_batch):
            ids = order[start:start + per_batch]
            chunk, env = ids // n, ids % n
            index = (chunk[None, :] * L + torch.arange(L)[:, None], env[None, :].expand(L, -1))  # (L, B) time, env
            pairs = list(zip(chunk.tolist(), env.tolist(), strict=True))
            h = torch.stack([self.chunk_states[c][0][:, e] for c, e in pairs], 1)
            c = torch.stack([self.chunk_states[c][1][:, e] for c, e in pairs], 1)
            yield dict(obs={k: v[index] for k, v in self.obs.items()}, starts=self.starts[index], state=(h, c),
                       **{name: getattr(self, name)[index] for name in fields})
