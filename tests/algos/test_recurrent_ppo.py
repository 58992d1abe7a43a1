"""Recurrent-PPO checklist: resets, poison invariance, rollout/replay consistency, layout, bootstrap."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

from tests.conftest import compose_config
from vitac.algos.buffer import RolloutBuffer, check_batch_layout
from vitac.algos.losses import gaussian_log_prob
from vitac.algos.ppo import PPO
from vitac.models.head import RecurrentActorHead
from vitac.run_config import build_policy_from_config, task_settings
from vitac.tasks.insertion.config import InsertionConfig


class FakeVectorEnv:
    """Random observations; env i ends its episode every (5 + i) steps, odd envs by termination."""

    def __init__(self, num_envs=4, seed=0):
        self.num_envs = num_envs
        self.single_action_space = gym.spaces.Box(-1, 1, (6,), np.float32)
        self.rng = np.random.default_rng(seed)
        self.t = np.zeros(num_envs, int)
        self.log = []

    def _obs(self):
        shapes = InsertionConfig().observation_shapes()
        return {k: self.rng.normal(size=(self.num_envs, *shapes[k])).astype(np.float32)
                for k in ("proprio", "peg_state", "critic_state")}

    def reset(self, seed=None):
        return self._obs(), {}

    def step(self, actions):
        self.t += 1
        ended = self.t % (5 + np.arange(self.num_envs)) == 0
        terminated = ended & (np.arange(self.num_envs) % 2 == 1)
        truncated = ended & ~terminated
        final = self._obs()
        final_obs = {i: {k: v[i] for k, v in final.items()} for i in np.flatnonzero(ended)}
        self.log.append(dict(final_obs=final_obs, truncated=truncated.copy()))
        infos = [dict(success=False, steps_to_success=-1, keypoint_distance=0.1)] * self.num_envs
        return (self._obs(), self.rng.normal(size=self.num_envs).astype(np.float32), terminated, truncated,
                {"final_obs": final_obs, "env_infos": infos})


def _policy(critic="state"):
    cfg = compose_config(["experiment=table1/privileged", f"critic={critic}"])
    return build_policy_from_config(cfg, InsertionConfig.from_dict(task_settings(cfg)))


def _module(critic="state", num_envs=4, horizon=16, seq_len=8, minibatch_size=16):
    torch.manual_seed(0)
    module = PPO(_policy(critic), FakeVectorEnv(num_envs), horizon=horizon, seq_len=seq_len,
                 minibatch_size=minibatch_size, mini_epochs=1)
    module.policy.update_normalizers({k: torch.randn(64, *v.shape[1:]) for k, v in module.envs._obs().items()})
    module.on_train_start()
    module.policy.eval()
    return module


def test_state_is_isolated_across_a_mid_sequence_reset_and_garbage_obs():
    torch.manual_seed(0)
    head = RecurrentActorHead(5, hidden=16, layers=2, units=(8,))
    x = torch.randn(6, 3, 5)
    starts = torch.zeros(6, 3)
    starts[3, 1] = 1.0  # sequence 1 starts a new episode at t = 3
    mean, _, value, _ = head(x, head.initial_state(3), starts)
    fresh_mean, _, fresh_value, _ = head(x[3:, 1:2], head.initial_state(1), torch.zeros(3, 1))
    assert torch.allclose(mean[3:, 1:2], fresh_mean, atol=1e-6) and torch.allclose(value[3:, 1:2], fresh_value, atol=1e-6)
    poisoned = x.clone()
    poisoned[:3, 1] = 1e6
    p_mean, _, _, _ = head(poisoned, head.initial_state(3), starts)
    assert torch.allclose(p_mean[3:, 1], mean[3:, 1], atol=1e-6)
    assert torch.allclose(p_mean[:, 0], mean[:, 0]) and torch.allclose(p_mean[:, 2], mean[:, 2])


def test_single_sequence_batch_with_mid_sequence_reset():
    torch.manual_seed(0)
    head = RecurrentActorHead(5, hidden=16, layers=1, units=(8,))
    x = torch.randn(5, 1, 5)
    starts = torch.tensor([[0.0], [0.0], [1.0], [0.0], [0.0]])
    mean, _, _, _ = head(x, head.initial_state(1), starts)
    fresh, _, _, _ = head(x[2:], head.initial_state(1), torch.zeros(3, 1))
    assert torch.allclose(mean[2:], fresh, atol=1e-6)


@pytest.mark.parametrize("critic", ["state", "none"])
def test_replayed_minibatches_reproduce_rollout_log_probs_and_values(critic):
    module = _module(critic)
    module.collect_rollout()
    with torch.no_grad():
        for mb in module.buffer.minibatches(16, torch.Generator().manual_seed(1)):
            mean, log_std, value, _ = module.policy(mb["obs"], mb["state"], mb["starts"])
            assert torch.allclose(gaussian_log_prob(mb["actions"], mean, log_std), mb["log_probs"], atol=1e-5)
            assert torch.allclose(module.value_normalizer.denormalize(value), mb["values"], atol=1e-5)
        # As in training: the value normalizer takes this rollout's returns, then the first update's ratio is 1.
        module.value_normalizer.update(module.buffer.returns)
        for mb in module.buffer.minibatches(16, torch.Generator().manual_seed(1)):
            terms = module.minibatch_losses(mb)
            assert float(terms["approx_kl"]) == pytest.approx(0.0, abs=1e-6)
            assert float(terms["clipfrac"]) == 0.0


def test_stored_chunk_state_equals_the_rollout_state():
    module = _module()
    module.collect_rollout()
    buf = module.buffer
    state = buf.chunk_states[0]
    with torch.no_grad():
        _, _, _, state_after = module.policy({k: v[:8] for k, v in buf.obs.items()}, state, buf.starts[:8])
    assert torch.allclose(state_after[0], buf.chunk_states[1][0], atol=1e-6)


def test_episode_start_flags_mark_first_steps():
    module = _module(num_envs=2)
    module.collect_rollout()
    starts = module.buffer.starts
    assert torch.equal(starts[0], torch.ones(2))  # the first rollout starts fresh episodes
    # env 0 ends every 5 steps: obs at t = 5, 10, 15 are first steps
    assert torch.nonzero(starts[1:, 0]).flatten().add(1).tolist() == [5, 10, 15]
    assert torch.nonzero(module.buffer.ends[:, 0]).flatten().tolist() == [4, 9, 14]


def test_truncation_bootstraps_from_final_obs_with_pre_reset_state_and_termination_does_not():
    module = _module(critic="none", num_envs=2)
    buf = module.buffer
    module.collect_rollout()
    log = module.envs.log
    t = 4  # env 0 truncates at t = 4 (every 5 steps), env 1 terminates at t = 5
    final = {k: torch.as_tensor(v)[None, None] for k, v in log[t]["final_obs"][0].items()}
    with torch.no_grad():
        state = buf.chunk_states[0]
        obs = {k: v[: t + 1, 0:1] for k, v in buf.obs.items()}
        _, _, _, pre_reset = module.policy(obs, (state[0][:, 0:1], state[1][:, 0:1]), buf.starts[: t + 1, 0:1])
        _, _, value, _ = module.policy(final, pre_reset, torch.zeros(1, 1))
    expected = module.value_normalizer.denormalize(value)[0, 0]
    assert float(buf.next_values[t, 0]) == pytest.approx(float(expected), abs=1e-5)
    assert float(buf.next_values[5, 1]) == 0.0  # termination: no bootstrap
    assert float(buf.next_values[0, 0]) == pytest.approx(float(buf.values[1, 0]))  # mid-episode


def test_sequence_minibatch_layout_and_coverage():
    buf = RolloutBuffer(horizon=8, num_envs=4, seq_len=4)
    buf.allocate({"x": torch.zeros(4, 1)}, action_dim=1)
    t_idx, e_idx = torch.meshgrid(torch.arange(8), torch.arange(4), indexing="ij")
    buf.obs["x"] = (1000 * e_idx + t_idx).float()[..., None]
    buf.advantages, buf.returns = torch.zeros(8, 4), torch.zeros(8, 4)
    buf.chunk_states = [(torch.zeros(2, 4, 3), torch.zeros(2, 4, 3)) for _ in range(2)]  # a 2-layer LSTM's
    seen = []
    for mb in buf.minibatches(8, torch.Generator().manual_seed(0)):
        # cuDNN's LSTM (the update on a GPU) refuses a strided initial state: "rnn: hx is not contiguous"
        assert all(s.shape == (2, 2, 3) and s.is_contiguous() for s in mb["state"])
        x = mb["obs"]["x"][..., 0]  # (L, B)
        env = torch.div(x, 1000, rounding_mode="floor")
        assert torch.all(env == env[0])  # one env per column
        assert torch.all(x[1:] - x[:-1] == 1)  # time increases down the rows
        seen += x.flatten().tolist()
    assert sorted(seen) == sorted((1000 * e_idx + t_idx).flatten().float().tolist())


@pytest.mark.parametrize("horizon,num_envs,seq_len,minibatch", [(10, 4, 4, 8), (8, 4, 4, 6), (8, 3, 4, 16)])
def test_indivisible_layouts_are_refused(horizon, num_envs, seq_len, minibatch):
    with pytest.raises(ValueError, match="algo"):
        check_batch_layout(horizon, num_envs, seq_len, minibatch)


def test_advantages_reaching_the_loss_are_normalized_and_the_flag_matters():
    module = _module()
    module.collect_rollout()
    module.value_normalizer.update(module.buffer.returns)
    mb = next(module.buffer.minibatches(16, torch.Generator().manual_seed(0)))
    with torch.no_grad():
        terms = module.minibatch_losses(mb)
        assert float(terms["advantages"].mean()) == pytest.approx(0.0, abs=1e-5)
        assert float(terms["advantages"].std()) == pytest.approx(1.0, rel=1e-3)
        module.hp["normalize_advantage"] = False
        raw = module.minibatch_losses(mb)
    assert torch.equal(raw["advantages"], mb["advantages"])
    assert not torch.allclose(raw["policy_loss"], terms["policy_loss"])
