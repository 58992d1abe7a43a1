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



class SequenceStore:
    """The seq_len chunks of the last `capacity` rollouts, for DAgger's aggregated dataset (Ross et al.'s DAgger
    trains on every state visited so far; a few rollouts keep memory bounded): observations, episode starts,
    the recurrent state at each chunk's start and per-step fields, as (R, T, N, ...) tensors filled as a ring."""

    def __init__(self, capacity: int, fields=("labels",)):
        self.capacity, self.fields = capacity, tuple(fields)
        self.obs: dict[str, torch.Tensor] = {}
        self.steps: dict[str, torch.Tensor] = {}  # starts, the named fields, and h / c at each chunk's start
        self.filled, self.next_slot = 0, 0

    def add(self, buffer: RolloutBuffer) -> None:
        """Copy the rollout in `buffer` over the oldest one kept."""
        steps = dict(starts=buffer.starts, h=torch.stack([s[0] for s in buffer.chunk_states]),  # (chunks, layers,
                     c=torch.stack([s[1] for s in buffer.chunk_states]),                        # N, H)
                     **{name: getattr(buffer, name) for name in self.fields})
        if not self.obs:
            empty = lambda v: torch.zeros((self.capacity, *v.shape), dtype=v.dtype)  # noqa: E731
            self.obs = {k: empty(v) for k, v in buffer.obs.items()}
            self.steps = {k: empty(v) for k, v in steps.items()}
        for kept, new in ((self.obs, buffer.obs), (self.steps, steps)):
            for k, v in new.items():
                kept[k][self.next_slot] = v
        self.next_slot = (self.next_slot + 1) % self.capacity
        self.filled = min(self.filled + 1, self.capacity)

    def minibatches(self, minibatch_size: int, generator: torch.Generator, count: int):
        """Yield dicts of (L, B, ...) tensors as RolloutBuffer.minibatches does, from `count` steps' worth of
        chunks drawn without replacement from every rollout kept. With one rollout kept and `count` its size,
        the chunks and their order are RolloutBuffer.minibatches' own."""
        _, horizon, n = self.steps["starts"].shape
        L = horizon // self.steps["h"].shape[1]
        per_rollout = horizon // L * n
        order = torch.randperm(self.filled * per_rollout, generator=generator)[:count // L]
        for ids in order.split(minibatch_size // L):
            rollout, chunk, env = ids // per_rollout, ids % per_rollout // n, ids % n
            index = (rollout[None, :].expand(L, -1), chunk[None, :] * L + torch.arange(L)[:, None],
                     env[None, :].expand(L, -1))  # (L, B) rollout, time, env
            state = tuple(self.steps[k][rollout, chunk, :, env].transpose(0, 1) for k in ("h", "c"))  # (layers, B, H)
            yield dict(obs={k: v[index] for k, v in self.obs.items()}, starts=self.steps["starts"][index],
                       state=state, **{name: self.steps[name][index] for name in self.fields})

    def state_dict(self) -> dict:
        return dict(capacity=self.capacity, obs=self.obs, steps=self.steps, filled=self.filled, next_slot=self.next_slot)

    def load_state_dict(self, state: dict) -> None:
        self.obs, self.steps = state["obs"], state["steps"]
        self.filled, self.next_slot = state["filled"], state["next_slot"]
