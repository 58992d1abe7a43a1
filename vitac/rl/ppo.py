"""Recurrent PPO as a LightningModule (manual optimization): one training step = rollout + update."""

from __future__ import annotations

import time

import lightning as L
import numpy as np
import torch
from lightning.pytorch.utilities import move_data_to_device
from torch.utils.data import DataLoader, Dataset

from vitac.models.normalizer import RunningNormalizer
from vitac.models.policy import VisuoTactilePolicy
from vitac.rl import losses
from vitac.rl.buffer import RolloutBuffer, check_batch_layout
from vitac.rl.curriculum import RandomizationCurriculum
from vitac.rl.lr_schedule import AdaptiveKLSchedule


def make_optimizer(params, lr: float) -> torch.optim.Adam:
    """PPO's optimizer: Adam with rl_games' eps, fused into one kernel over every parameter (about 4x faster
    per step than torch's default on CPU, tools/bench_optimizer.py; the same arithmetic)."""
    return torch.optim.Adam(params, lr=lr, eps=1e-5, fused=True)


class _OneItem(Dataset):
    """Lightning needs a dataloader; each epoch is one PPO iteration."""

    def __len__(self):
        return 1

    def __getitem__(self, i):
        return torch.zeros(())


class PPO(L.LightningModule):
    """Rollouts from a vector env, GAE, clipped surrogate + clipped value + bounds + entropy + symmetry terms.

    The policy, its normalizers and the update run on the module's device (Lightning's accelerator); the
    environments, the rollout buffer, GAE and the action noise stay on the CPU, so a run draws the same
    noise on either device and its checkpoints load anywhere.

    Args:
        policy: the actor-critic.
        envs: a vector env with `reset`, `step`, `get_state`, `set_state` (TaskVectorEnv).
        horizon: steps per env per rollout.
        seq_len: BPTT length; the recurrent state is stored at the start of every seq_len chunk.
        minibatch_size: transitions per minibatch (a multiple of seq_len).
        mini_epochs: passes over the rollout.
        lr, gamma, gae_lambda, clip, critic_coef, clip_value, grad_norm, entropy_coef, bounds_loss_coef:
            the paper's A2C table.
        normalize_input, normalize_value, normalize_advantage: running normalizations (advantages per minibatch).
        freeze_critic: keep the asymmetric critic fixed (AACD with a pre-trained critic).
        rollout_threads, update_threads: torch threads while collecting and while updating.
        run_config: the resolved run config, stored in checkpoints so evaluation can rebuild the policy.
        curriculum: optional schedule of the training envs' randomization scale.
        lr_schedule: optional adaptive learning rate (rl_games' `adaptive`), moved after every minibatch step,
            mini-epoch or iteration (its `every`); None keeps `lr` fixed (TacSL's actor). The current rate is
            saved in checkpoints with the optimizer.
    """

    def __init__(self, policy: VisuoTactilePolicy, envs, horizon: int = 512, seq_len: int = 128,
                 minibatch_size: int = 512, mini_epochs: int = 4, lr: float = 1e-4, gamma: float = 0.99,
                 gae_lambda: float = 0.95, clip: float = 0.2, critic_coef: float = 2.0, clip_value: bool = True,
                 grad_norm: float = 1.0, entropy_coef: float = 0.0, bounds_loss_coef: float = 1e-4,
                 normalize_input: bool = True, normalize_value: bool = True, normalize_advantage: bool = True,
                 freeze_critic: bool = False, seed: int = 0, rollout_threads: int = 1, update_threads: int = 2,
                 run_config: dict | None = None, curriculum: RandomizationCurriculum | None = None,
                 lr_schedule: AdaptiveKLSchedule | None = None):
        super().__init__()
        check_batch_layout(horizon, envs.num_envs, seq_len, minibatch_size)
        self.automatic_optimization = False
        self.policy, self.envs = policy, envs
        self.value_normalizer = RunningNormalizer((), clip=float("inf"))
        self.hp = dict(horizon=horizon, seq_len=seq_len, minibatch_size=minibatch_size, mini_epochs=mini_epochs,
                       lr=lr, gamma=gamma, gae_lambda=gae_lambda, clip=clip, critic_coef=critic_coef,
                       clip_value=clip_value, grad_norm=grad_norm, entropy_coef=entropy_coef,
                       bounds_loss_coef=bounds_loss_coef, normalize_input=normalize_input,
                       normalize_value=normalize_value, normalize_advantage=normalize_advantage)
        self.run_config = run_config
        self.curriculum = curriculum
        self.lr_schedule = lr_schedule
        self.rollout_threads, self.update_threads = rollout_threads, update_threads
        if freeze_critic and policy.critic is not None:
            policy.critic.requires_grad_(False)
        self.buffer = RolloutBuffer(horizon, envs.num_envs, seq_len)
        # All of PPO's randomness (action noise, minibatch order) comes from this generator, saved in
        # checkpoints: Lightning's dataloader draws from the global RNG, which would break exact resume.
        self.generator = torch.Generator().manual_seed(seed)
        self.env_steps = 0
        self._obs = None  # current observation (numpy dict), LSTM state and episode-start flags
        self._restored = None

    # --------------------------------------------------------------------------- lightning plumbing
    def train_dataloader(self):
        return DataLoader(_OneItem(), batch_size=None)

    def configure_optimizers(self):
        params = [p for p in self.policy.parameters() if p.requires_grad]
        return make_optimizer(params, self.hp["lr"])

    def on_train_start(self):
        n = self.envs.num_envs
        if self._restored is not None:  # exact resume: environments, recurrent state and flags
            r = self._restored
            self._obs = self.envs.set_state(r["env_states"])
            self._state = tuple(s.to(self.device) for s in r["lstm_state"])
            self._starts = r["starts"]
            self.env_steps = r["env_steps"]
            self.generator.set_state(r["generator"])
            if self.curriculum is not None:
                self.curriculum.load_state_dict(r["curriculum"])
            elif r["curriculum"] is not None:  # curriculum switched off on resume: the configured ranges from
                self.envs.set_randomization_scale(self.envs.configured_scale)  # each env's next episode on
            self._restored = None
        elif self._obs is None:
            if self.curriculum is not None:
                self.envs.set_randomization_scale(self.curriculum.scale)
            self._obs, _ = self.envs.reset(seed=None)
            self._state = self.policy.initial_state(n, self.device)
            self._starts = torch.ones(n)

    def on_save_checkpoint(self, checkpoint):
        checkpoint["vitac_config"] = self.run_config
        checkpoint["vitac"] = dict(env_states=self.envs.get_state(), lstm_state=tuple(s.cpu() for s in self._state),
                                   starts=self._starts,
                                   env_steps=self.env_steps, generator=self.generator.get_state(),
                                   curriculum=self.curriculum.state_dict() if self.curriculum else None)

    def on_load_checkpoint(self, checkpoint):
        self._restored = checkpoint.get("vitac")

    # ----------------------------------------------------------------------------------- rollout
    @staticmethod
    def _to_torch(obs: dict) -> dict:
        return {k: torch.as_tensor(v) for k, v in obs.items()}

    @torch.no_grad()
    def _value(self, obs: dict, state, starts) -> torch.Tensor:
        """Raw-scale value (on the CPU) of one step of observations (B, ...)."""
        inputs, starts = self.policy.step_inputs(obs, starts)
        _, _, value, _ = self.policy(inputs, state, starts)
        return self._raw(value[0]).cpu()

    def _raw(self, value: torch.Tensor) -> torch.Tensor:
        """Network value -> return scale (the network predicts normalized returns when normalize_value)."""
        return self.value_normalizer.denormalize(value) if self.hp["normalize_value"] else value

    @torch.no_grad()
    def collect_rollout(self) -> dict:
        buf, hp = self.buffer, self.hp
        obs = self._to_torch(self._obs)
        if not buf.obs:
            buf.allocate(obs, self.envs.single_action_space.shape[0])
        successes, steps_to_success = [], []
        start_time = time.perf_counter()
        for t in range(hp["horizon"]):
            if t % hp["seq_len"] == 0:
                buf.chunk_states[t // hp["seq_len"]] = (self._state[0].cpu().clone(), self._state[1].cpu().clone())
            inputs, starts = self.policy.step_inputs(obs, self._starts)
            mean, log_std, value, next_state = self.policy(inputs, self._state, starts)
            mean, log_std, value = mean[0].cpu(), log_std[0].cpu(), self._raw(value[0]).cpu()
            action = mean + log_std.exp() * torch.randn(mean.shape, generator=self.generator)
            for k, v in obs.items():
                buf.obs[k][t] = v
            buf.actions[t], buf.starts[t] = action, self._starts
            buf.log_probs[t] = losses.gaussian_log_prob(action, mean, log_std)
            buf.values[t] = value
            next_obs, reward, terminated, truncated, info = self.envs.step(action.clamp(-1.0, 1.0).numpy())
            ended = torch.as_tensor(terminated | truncated, dtype=torch.float32)
            buf.rewards[t], buf.ends[t] = torch.as_tensor(reward), ended
            # Truncations bootstrap from the final observation, valued with the pre-reset recurrent state.
            bootstrap = torch.zeros(self.envs.num_envs)
            for i, final in info["final_obs"].items():
                if not terminated[i]:
                    sub_state = (next_state[0][:, i:i + 1], next_state[1][:, i:i + 1])
                    final_t = {k: torch.as_tensor(v)[None] for k, v in final.items()}
                    bootstrap[i] = self._value(final_t, sub_state, torch.zeros(1))[0]
                env_info = info["env_infos"][i]
                successes.append(float(env_info["success"]))
                if env_info["steps_to_success"] >= 0:
                    steps_to_success.append(env_info["steps_to_success"])
            buf.next_values[t] = bootstrap  # mid-episode entries are filled from values[t + 1] below
            self._obs, obs = next_obs, self._to_torch(next_obs)
            self._state, self._starts = next_state, ended
        last_value = self._value(obs, self._state, self._starts)
        following = torch.cat([buf.values[1:], last_value[None]], dim=0)
        buf.next_values = torch.where(buf.ends.bool(), buf.next_values, following)
        buf.advantages, buf.returns = losses.gae(buf.rewards, buf.values, buf.next_values, buf.ends,
                                                 hp["gamma"], hp["gae_lambda"])
        steps = hp["horizon"] * self.envs.num_envs
        self.env_steps += steps
        rollout_time = time.perf_counter() - start_time
        curriculum = {}
        if self.curriculum is not None:
            if self.curriculum.observe(successes):  # applies from each env's next episode
                self.envs.set_randomization_scale(self.curriculum.scale)
            curriculum["charts/randomization_scale"] = self.curriculum.scale
        return curriculum | {"charts/rollout_SPS": steps / rollout_time, "charts/episodes": len(successes),
                "charts/success_rate": float(np.mean(successes)) if successes else float("nan"),
                "charts/steps_to_success": float(np.mean(steps_to_success)) if steps_to_success else float("nan"),
                "charts/reward_per_step": float(buf.rewards.mean())}

    # ------------------------------------------------------------------------------------ update
    def minibatch_losses(self, mb: dict) -> dict:
        """Every loss term of one minibatch, in the space the networks use."""
        hp, policy = self.hp, self.policy
        mean, log_std, value, _, sym = policy(mb["obs"], mb["state"], mb["starts"], with_aux=True)
        new_log_prob = losses.gaussian_log_prob(mb["actions"], mean, log_std)
        advantages = mb["advantages"]
        if hp["normalize_advantage"]:
            advantages = losses.normalize_advantages(advantages)
        pg_loss, approx_kl, clipfrac = losses.policy_loss(new_log_prob, mb["log_probs"], advantages, hp["clip"])
        old_values, returns = mb["values"], mb["returns"]
        if hp["normalize_value"]:
            old_values, returns = self.value_normalizer(old_values), self.value_normalizer(returns)
        v_loss = losses.value_loss(value, old_values, returns, hp["clip"] if hp["clip_value"] else None)
        entropy = losses.gaussian_entropy(log_std).mean()
        b_loss = losses.bounds_loss(mean)
        sym_loss = sym.mean() if sym is not None else torch.zeros((), device=mean.device)
        total = (pg_loss + 0.5 * hp["critic_coef"] * v_loss - hp["entropy_coef"] * entropy
                 + hp["bounds_loss_coef"] * b_loss + policy.regularizer.lambda_sym * sym_loss)
        return dict(loss=total, policy_loss=pg_loss, value_loss=v_loss, entropy=entropy, bounds_loss=b_loss,
                    sym_loss=sym_loss, approx_kl=approx_kl, clipfrac=clipfrac, advantages=advantages)

    @staticmethod
    def _lr(optimizer) -> float:
        return optimizer.param_groups[0]["lr"]

    @staticmethod
    def _set_lr(optimizer, lr: float) -> None:
        for group in optimizer.param_groups:
            group["lr"] = lr

    def training_step(self, batch, batch_idx):
        hp = self.hp
        iteration_start = time.perf_counter()
        self.policy.eval()
        torch.set_num_threads(self.rollout_threads)  # the env workers need the other cores while collecting
        metrics = self.collect_rollout()
        torch.set_num_threads(self.update_threads)
        self.policy.train()
        if hp["normalize_value"]:
            self.value_normalizer.update(self.buffer.returns)
        optimizer = self.optimizers()
        sums: dict[str, float] = {}
        count = 0
        for _ in range(hp["mini_epochs"]):
            for mb in self.buffer.minibatches(hp["minibatch_size"], self.generator):
                terms = self.minibatch_losses(move_data_to_device(mb, self.device))
                optimizer.zero_grad()
                self.manual_backward(terms["loss"])
                grad_norm = torch.nn.utils.clip_grad_norm_(self.policy.parameters(), hp["grad_norm"])
                if not torch.isfinite(grad_norm):  # one bad minibatch must not poison every weight
                    sums["skipped_updates"] = sums.get("skipped_updates", 0.0) + 1.0
                    continue
                optimizer.step()
                if self.lr_schedule is not None:
                    self._set_lr(optimizer, self.lr_schedule.after_minibatch(self._lr(optimizer), float(terms["approx_kl"])))
                count += 1
                for k in ("loss", "policy_loss", "value_loss", "entropy", "bounds_loss", "sym_loss", "approx_kl",
                          "clipfrac"):
                    sums[k] = sums.get(k, 0.0) + float(terms[k].detach())
                sums["grad_norm"] = sums.get("grad_norm", 0.0) + float(grad_norm)
            if self.lr_schedule is not None:
                self._set_lr(optimizer, self.lr_schedule.after_mini_epoch(self._lr(optimizer)))
        if self.lr_schedule is not None:
            self._set_lr(optimizer, self.lr_schedule.after_iteration(self._lr(optimizer)))
        if hp["normalize_input"]:  # after the update, so rollout and update saw the same statistics
            self.policy.update_normalizers({k: v.reshape(-1, *v.shape[2:]) for k, v in self.buffer.obs.items()})
        skipped = sums.pop("skipped_updates", 0.0)
        metrics.update({f"losses/{k}": v / max(count, 1) for k, v in sums.items()})
        metrics["losses/skipped_updates"] = skipped
        metrics["charts/lr"] = self._lr(optimizer)
        values, returns = self.buffer.values.flatten(), self.buffer.returns.flatten()
        metrics["losses/explained_variance"] = losses.explained_variance(values, returns)
        steps = hp["horizon"] * self.envs.num_envs
        metrics["charts/SPS"] = steps / (time.perf_counter() - iteration_start)
        metrics["charts/env_steps"] = float(self.env_steps)
        metrics["iteration"] = float(self.current_epoch + 1)  # 1-based; names the periodic checkpoints
        self.log_dict(metrics, on_step=False, on_epoch=True)
