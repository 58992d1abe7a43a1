"""Recurrent PPO on the shared rollout loop: GAE and the clipped update (the loop is `rollout.RolloutAlgorithm`)."""

from __future__ import annotations

import torch
from lightning.pytorch.utilities import move_data_to_device

from vitac.algos import losses
from vitac.algos.buffer import check_batch_layout
from vitac.algos.curriculum import RandomizationCurriculum
from vitac.algos.lr_schedule import make_lr_schedule
from vitac.algos.rollout import RolloutAlgorithm
from vitac.models.normalizer import RunningNormalizer
from vitac.models.policy import VisuoTactilePolicy


def make_optimizer(params, lr: float) -> torch.optim.Adam:
    """PPO's optimizer: Adam with rl_games' eps, fused into one kernel over every parameter (about 4x faster
    per step than torch's default on CPU, benchmarks/bench_optimizer.py; the same arithmetic)."""
    return torch.optim.Adam(params, lr=lr, eps=1e-5, fused=True)


class PPO(RolloutAlgorithm):
    """Rollouts from a vector env, GAE, clipped surrogate + clipped value + bounds + entropy + symmetry terms.

    The rollout loop, resume and curriculum are the shared `RolloutAlgorithm`'s; PPO samples the action from the
    policy's Gaussian, bootstraps truncated episodes from their final observation, computes GAE and updates. The
    update runs on the module's device; GAE and the action noise stay on the CPU.

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
        rollout_threads, update_threads: torch threads while collecting and while updating.
        run_config: the resolved run config, stored in checkpoints so evaluation can rebuild the policy.
        curriculum: optional schedule of the training envs' randomization scale.
        lr_schedule: "fixed" keeps `lr` (TacSL's actor); "adaptive" is rl_games' KL-adaptive rate (`kl_threshold`),
            moved after every minibatch step, mini-epoch or iteration (`lr_schedule_every`) within [lr_min, lr_max].
            The current rate is saved in checkpoints with the optimizer.
        critic_warmup_iterations: iterations at the start during which only the critic learns (the actor's
            weights, noise and input normalizers stay as loaded, the rate stays at `lr`): a critic fitted to a
            warm-started actor before that actor's first gradient (PIRLNav). Needs an asymmetric critic.
    """

    # The per-step fields an update's minibatches carry (an algorithm built on PPO may add its own).
    minibatch_fields = ("actions", "log_probs", "values", "advantages", "returns")

    def __init__(self, policy: VisuoTactilePolicy, envs, horizon: int = 512, seq_len: int = 128,
                 minibatch_size: int = 512, mini_epochs: int = 4, lr: float = 1e-4, gamma: float = 0.99,
                 gae_lambda: float = 0.95, clip: float = 0.2, critic_coef: float = 2.0, clip_value: bool = True,
                 grad_norm: float = 1.0, entropy_coef: float = 0.0, bounds_loss_coef: float = 1e-4,
                 normalize_input: bool = True, normalize_value: bool = True, normalize_advantage: bool = True,
                 seed: int = 0, rollout_threads: int = 1, update_threads: int = 2,
                 run_config: dict | None = None, curriculum: RandomizationCurriculum | None = None,
                 lr_schedule: str = "fixed", kl_threshold: float = 0.008, lr_schedule_every: str = "minibatch",
                 lr_min: float = 1e-6, lr_max: float = 1e-2, critic_warmup_iterations: int = 0):
        super().__init__(policy, envs, horizon, seq_len, seed, rollout_threads, update_threads, run_config, curriculum)
        if critic_warmup_iterations and policy.critic is None:  # the head's value shares the actor's layers
            raise ValueError(f"algo.critic_warmup_iterations={critic_warmup_iterations} is not allowed with critic=none: "
                             "a warm-up trains the critic alone, which needs an asymmetric critic (critic=state)")
        check_batch_layout(horizon, envs.num_envs, seq_len, minibatch_size)
        self.value_normalizer = RunningNormalizer((), clip=float("inf"))
        self.hp = dict(minibatch_size=minibatch_size, mini_epochs=mini_epochs, lr=lr, gamma=gamma, gae_lambda=gae_lambda,
                       clip=clip, critic_coef=critic_coef, clip_value=clip_value, grad_norm=grad_norm,
                       entropy_coef=entropy_coef, bounds_loss_coef=bounds_loss_coef, normalize_input=normalize_input,
                       normalize_value=normalize_value, normalize_advantage=normalize_advantage,
                       critic_warmup_iterations=critic_warmup_iterations)
        self.lr_schedule = make_lr_schedule(lr_schedule, kl_threshold, lr_schedule_every, lr_min, lr_max, lr)

    @property
    def actor_frozen(self) -> bool:
        """Whether this iteration is one of the critic's warm-up (a function of the iteration: resume continues it)."""
        return self.current_epoch < self.hp["critic_warmup_iterations"]

    def configure_optimizers(self):
        params = [p for p in self.policy.parameters() if p.requires_grad]
        return make_optimizer(params, self.hp["lr"])

    # ----------------------------------------------------------------------------------- rollout
    @torch.no_grad()
    def _value(self, obs: dict, state, starts) -> torch.Tensor:
        """Raw-scale value (on the CPU) of one step of observations (B, ...)."""
        inputs, starts = self.policy.step_inputs(obs, starts)
        _, _, value, _ = self.policy(inputs, state, starts)
        return self._raw(value[0]).cpu()

    def _raw(self, value: torch.Tensor) -> torch.Tensor:
        """Network value -> return scale (the network predicts normalized returns when normalize_value)."""
        return self.value_normalizer.denormalize(value) if self.hp["normalize_value"] else value

    def act(self, t, obs, mean, log_std, value):
        buf = self.buffer
        action = mean + log_std.exp() * torch.randn(mean.shape, generator=self.generator)
        buf.log_probs[t] = losses.gaussian_log_prob(action, mean, log_std)
        buf.values[t] = self._raw(value).cpu()
        return action

    def after_env_step(self, t, info, terminated, next_state):
        # Truncations bootstrap from the final observation, valued with the pre-reset recurrent state.
        bootstrap = torch.zeros(self.envs.num_envs)
        for i, final in info["final_obs"].items():
            if not terminated[i]:
                sub_state = (next_state[0][:, i:i + 1], next_state[1][:, i:i + 1])
                final_t = {k: torch.as_tensor(v)[None] for k, v in final.items()}
                bootstrap[i] = self._value(final_t, sub_state, torch.zeros(1))[0]
        self.buffer.next_values[t] = bootstrap  # mid-episode entries are filled from values[t + 1] below

    def finish_rollout(self, obs):
        buf, hp = self.buffer, self.hp
        last_value = self._value(obs, self._state, self._starts)
        following = torch.cat([buf.values[1:], last_value[None]], dim=0)
        buf.next_values = torch.where(buf.ends.bool(), buf.next_values, following)
        buf.advantages, buf.returns = losses.gae(buf.rewards, buf.values, buf.next_values, buf.ends,
                                                 hp["gamma"], hp["gae_lambda"])

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
        total = 0.5 * hp["critic_coef"] * v_loss
        if not self.actor_frozen:  # in the warm-up no actor term reaches a gradient
            actor = pg_loss - hp["entropy_coef"] * entropy + hp["bounds_loss_coef"] * b_loss
            total = total + (actor + policy.regularizer.term(sym_loss, total + actor))
        return dict(loss=total, policy_loss=pg_loss, value_loss=v_loss, entropy=entropy, bounds_loss=b_loss,
                    sym_loss=sym_loss, approx_kl=approx_kl, clipfrac=clipfrac, advantages=advantages, mean=mean)

    logged_losses = ("loss", "policy_loss", "value_loss", "entropy", "bounds_loss", "sym_loss", "approx_kl", "clipfrac")

    @staticmethod
    def _lr(optimizer) -> float:
        return optimizer.param_groups[0]["lr"]

    @staticmethod
    def _set_lr(optimizer, lr: float) -> None:
        for group in optimizer.param_groups:
            group["lr"] = lr

    def update(self) -> dict:
        hp, metrics = self.hp, {}
        if hp["normalize_value"]:
            self.value_normalizer.update(self.buffer.returns)
        optimizer = self.optimizers()
        # In the critic's warm-up the actor's KL is 0: an adaptive rate would climb to its maximum before the actor
        # learns at all, so the schedule waits.
        schedule = None if self.actor_frozen else self.lr_schedule
        sums: dict[str, float] = {}
        count = 0
        for _ in range(hp["mini_epochs"]):
            for mb in self.buffer.minibatches(hp["minibatch_size"], self.generator, self.minibatch_fields):
                terms = self.minibatch_losses(move_data_to_device(mb, self.device))
                optimizer.zero_grad()
                self.manual_backward(terms["loss"])
                grad_norm = torch.nn.utils.clip_grad_norm_(self.policy.parameters(), hp["grad_norm"])
                if not torch.isfinite(grad_norm):  # one bad minibatch must not poison every weight
                    sums["skipped_updates"] = sums.get("skipped_updates", 0.0) + 1.0
                    continue
                optimizer.step()
                if schedule is not None:
                    self._set_lr(optimizer, schedule.after_minibatch(self._lr(optimizer), float(terms["approx_kl"])))
                count += 1
                for k in self.logged_losses:
                    sums[k] = sums.get(k, 0.0) + float(terms[k].detach())
                sums["grad_norm"] = sums.get("grad_norm", 0.0) + float(grad_norm)
            if schedule is not None:
                self._set_lr(optimizer, schedule.after_mini_epoch(self._lr(optimizer)))
        if schedule is not None:
            self._set_lr(optimizer, schedule.after_iteration(self._lr(optimizer)))
        if hp["normalize_input"]:  # after the update, so rollout and update saw the same statistics
            self.policy.update_normalizers({k: v.reshape(-1, *v.shape[2:]) for k, v in self.buffer.obs.items()},
                                           actor=not self.actor_frozen)
        skipped = sums.pop("skipped_updates", 0.0)
        metrics.update({f"losses/{k}": v / max(count, 1) for k, v in sums.items()})
        metrics["losses/skipped_updates"] = skipped
        metrics["charts/lr"] = self._lr(optimizer)
        metrics["charts/actor_frozen"] = float(self.actor_frozen)
        values, returns = self.buffer.values.flatten(), self.buffer.returns.flatten()
        metrics["losses/explained_variance"] = losses.explained_variance(values, returns)
        return metrics
