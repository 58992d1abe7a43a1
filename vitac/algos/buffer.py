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

    def chunk_tensors(self, fields) -> tuple[dict, dict]:
        """The observations and the per-step tensors minibatches draw from: episode starts, the named `fields`,
        and h / c, the recurrent state at each chunk's start as (chunks, layers, N, H)."""
        h, c = (torch.stack([s[k] for s in self.chunk_states]) for k in (0, 1))
        return self.obs, dict(starts=self.starts, h=h, c=c, **{name: getattr(self, name) for name in fields})

    def minibatches(self, minibatch_size: int, generator: torch.Generator,
                    fields=("actions", "log_probs", "values", "advantages", "returns")):
        """Yield dicts of (L, B, ...) tensors, B = minibatch_size / L chunks of L consecutive steps of one env:
        the observations, episode starts, recurrent state at each chunk's start and the named per-step `fields`
        (PPO's by default; an algorithm may store its own, e.g. DAgger's `labels`).

        Every (t, env) appears exactly once per call; chunk order is shuffled by `generator`.
        """
        obs, steps = self.chunk_tensors(fields)
        order = torch.randperm(self.horizon // self.seq_len * self.num_envs, generator=generator)
        yield from chunk_minibatches({k: v[None] for k, v in obs.items()}, {k: v[None] for k, v in steps.items()},
                                     fields, order, minibatch_size // self.seq_len)


def chunk_minibatches(obs: dict, steps: dict, fields, order: torch.Tensor, per_batch: int):
    """Minibatches of `per_batch` whole chunks each, in `order`, from (R, T, N, ...) tensors of R rollouts
    (`steps` as RolloutBuffer.chunk_tensors gives them, with the leading R): chunk id r * T / L * N + chunk * N +
    env, for chunks of L = T / (chunks per rollout) steps."""
    _, horizon, n = steps["starts"].shape
    L = horizon // steps["h"].shape[1]
    per_rollout = horizon // L * n
    for ids in order.split(per_batch):
        rollout, chunk, env = ids // per_rollout, ids % per_rollout // n, ids % n
        index = (rollout[None, :].expand(L, -1), chunk[None, :] * L + torch.arange(L)[:, None],
                 env[None, :].expand(L, -1))  # (L, B) rollout, time, env
        # (layers, B, H), contiguous: cuDNN's LSTM refuses a strided initial state ("rnn: hx is not contiguous")
        state = tuple(steps[k][rollout, chunk, :, env].transpose(0, 1).contiguous() for k in ("h", "c"))
        yield dict(obs={k: v[index] for k, v in obs.items()}, starts=steps["starts"][index], state=state,
                   **{name: steps[name][index] for name in fields})


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
        obs, steps = buffer.chunk_tensors(self.fields)
        if not self.obs:
            empty = lambda v: torch.zeros((self.capacity, *v.shape), dtype=v.dtype)  # noqa: E731
            self.obs = {k: empty(v) for k, v in obs.items()}
            self.steps = {k: empty(v) for k, v in steps.items()}
        for kept, new in ((self.obs, obs), (self.steps, steps)):
            for k, v in new.items():
                kept[k][self.next_slot] = v
        self.next_slot = (self.next_slot + 1) % self.capacity
        self.filled = min(self.filled + 1, self.capacity)

    def minibatches(self, minibatch_size: int, generator: torch.Generator, count: int):
        """Yield dicts of (L, B, ...) tensors as RolloutBuffer.minibatches does, from `count` steps' worth of
        chunks drawn without replacement from every rollout kept. With one rollout kept and `count` its size,
        the chunks and their order are RolloutBuffer.minibatches' own."""
        L = self.steps["starts"].shape[1] // self.steps["h"].shape[1]
        order = torch.randperm(self.filled * self.steps["h"].shape[1] * self.steps["starts"].shape[2],
                               generator=generator)[:count // L]
        yield from chunk_minibatches(self.obs, self.steps, self.fields, order, minibatch_size // L)

    def state_dict(self) -> dict:
        return dict(capacity=self.capacity, obs=self.obs, steps=self.steps, filled=self.filled, next_slot=self.next_slot)

    def load_state_dict(self, state: dict) -> None:
        self.obs, self.steps = state["obs"], state["steps"]
        self.filled, self.next_slot = state["filled"], state["next_slot"]
