"""The rollout loop every training algorithm runs on, as a LightningModule: one training step is one rollout
from the vector env and the algorithm's update.

The loop owns what any on-policy learner needs: stepping the environments with the policy, the recurrent
state and episode-start flags, the state at the start of every `seq_len` chunk (truncated BPTT), episode
success bookkeeping, the randomization curriculum, thread switching between rollout and update, and the
environment/RNG state in checkpoints for exact resume. An algorithm supplies `act` (the action to execute,
recording what its update needs), optionally `after_env_step` and `finish_rollout`, and `update`.
"""

from __future__ import annotations

import time

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from vitac.algos.buffer import RolloutBuffer
from vitac.algos.curriculum import RandomizationCurriculum
from vitac.envs.vector_env import RESTARTED
from vitac.models.policy import VisuoTactilePolicy

# Episodes a breakdown ended: the simulation (gym_env.TaskEnv) or a crashed worker process (vector_env), counted.
BROKEN = ("physics diverged", "non-finite observation or reward", RESTARTED)


class _OneItem(Dataset):
    """Lightning needs a dataloader; each epoch is one iteration (a rollout and an update)."""

    def __len__(self):
        return 1

    def __getitem__(self, i):
        return torch.zeros(())


class RolloutAlgorithm(L.LightningModule):
    """Collect `horizon` steps of every environment with the policy, then let the algorithm update.

    The policy runs on the module's device (Lightning's accelerator); the environments, the rollout buffer
    and the algorithm's randomness (`self.generator`) stay on the CPU, so a run draws the same numbers on
    either device and its checkpoints load anywhere.

    Args:
        policy: the actor (and critic).
        envs: a vector env with `reset`, `step`, `get_state`, `set_state` (TaskVectorEnv).
        horizon: steps per env per rollout.
        seq_len: BPTT length; the recurrent state is stored at the start of every seq_len chunk.
        seed: seeds `self.generator`, the algorithm's only source of randomness (saved in checkpoints).
        rollout_threads, update_threads: torch threads while collecting and while updating.
        run_config: the resolved run config, stored in checkpoints so evaluation can rebuild the policy.
        curriculum: optional schedule of the training envs' randomization scale.
    """

    def __init__(self, policy: VisuoTactilePolicy, envs, horizon: int, seq_len: int, seed: int = 0,
                 rollout_threads: int = 1, update_threads: int = 2, run_config: dict | None = None,
                 curriculum: RandomizationCurriculum | None = None):
        super().__init__()
        self.automatic_optimization = False
        self.policy, self.envs = policy, envs
        self.horizon, self.seq_len = horizon, seq_len
        self.run_config = run_config
        self.curriculum = curriculum
        self.rollout_threads, self.update_threads = rollout_threads, update_threads
        self.buffer = RolloutBuffer(horizon, envs.num_envs, seq_len)
        # All of the algorithm's randomness (action noise, minibatch order) comes from this generator, saved in
        # checkpoints: Lightning's dataloader draws from the global RNG, which would break exact resume.
        self.generator = torch.Generator().manual_seed(seed)
        self.env_steps = 0
        self._obs = None  # current observation (numpy dict), LSTM state and episode-start flags
        self._restored = None
        self.saving_resume_point = False  # set while last.ckpt is written (callbacks.save_resume_point)

    # ------------------------------------------------------------------------------- what an algorithm adds
    def act(self, t: int, obs: dict, mean: torch.Tensor, log_std: torch.Tensor, value: torch.Tensor) -> torch.Tensor:
        """The action (N, A) to execute at step t, from the policy's outputs (CPU tensors, value still on the
        module's device); store in `self.buffer` what the update needs."""
        raise NotImplementedError

    def after_env_step(self, t: int, info: dict, terminated: np.ndarray, next_state) -> None:
        """Called after the environments stepped; `info["final_obs"]` holds the last observation of every
        episode that ended (the returned observation already starts the next)."""

    def finish_rollout(self, obs: dict) -> None:
        """Called after the last step with the observation that follows it (bootstrap values, targets)."""

    def update(self) -> dict:
        """Learn from `self.buffer`; returns metrics."""
        raise NotImplementedError

    def extra_state(self) -> dict:
        """Algorithm state beyond the loop's, for exact resume (saved with the environments)."""
        return {}

    def resume_state(self) -> dict:
        """Bulky algorithm state only an exact resume needs: saved in last.ckpt alone (`saving_resume_point`),
        restored through `load_extra_state` with the rest."""
        return {}

    def load_extra_state(self, state: dict) -> None:
        pass

    # --------------------------------------------------------------------------- lightning plumbing
    def train_dataloader(self):
        return DataLoader(_OneItem(), batch_size=None)

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
            self.load_extra_state(r)
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
                                   curriculum=self.curriculum.state_dict() if self.curriculum else None,
                                   **self.extra_state(), **(self.resume_state() if self.saving_resume_point else {}))
        if self.saving_resume_point:  # this iteration's metrics row: a kill before the logger writes it loses nothing
            metrics = {k: float(v) for k, v in self.trainer.callback_metrics.items()}
            checkpoint["vitac"]["metrics_row"] = dict(metrics, epoch=self.current_epoch, step=self.current_epoch)

    def on_load_checkpoint(self, checkpoint):
        self._restored = checkpoint.get("vitac")

    # ----------------------------------------------------------------------------------- rollout
    @staticmethod
    def _to_torch(obs: dict) -> dict:
        return {k: torch.as_tensor(v) for k, v in obs.items()}

    @torch.no_grad()
    def collect_rollout(self) -> dict:
        buf = self.buffer
        obs = self._to_torch(self._obs)
        if not buf.obs:
            buf.allocate(obs, self.envs.single_action_space.shape[0])
        successes, steps_to_success, broken = [], [], 0
        start_time = time.perf_counter()
        for t in range(self.horizon):
            if t % self.seq_len == 0:
                buf.chunk_states[t // self.seq_len] = (self._state[0].cpu().clone(), self._state[1].cpu().clone())
            inputs, starts = self.policy.step_inputs(obs, self._starts)
            mean, log_std, value, next_state = self.policy(inputs, self._state, starts)
            action = self.act(t, obs, mean[0].cpu(), log_std[0].cpu(), value[0])
            for k, v in obs.items():
                buf.obs[k][t] = v
            buf.actions[t], buf.starts[t] = action, self._starts
            next_obs, reward, terminated, truncated, info = self.envs.step(action.clamp(-1.0, 1.0).numpy())
            ended = torch.as_tensor(terminated | truncated, dtype=torch.float32)
            buf.rewards[t], buf.ends[t] = torch.as_tensor(reward), ended
            self.after_env_step(t, info, terminated, next_state)
            for i in info["final_obs"]:
                env_info = info["env_infos"][i]
                successes.append(float(env_info["success"]))
                broken += env_info.get("outcome") in BROKEN
                if env_info["steps_to_success"] >= 0:
                    steps_to_success.append(env_info["steps_to_success"])
            self._obs, obs = next_obs, self._to_torch(next_obs)
            self._state, self._starts = next_state, ended
        self.finish_rollout(obs)
        steps = self.horizon * self.envs.num_envs
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
                "charts/reward_per_step": float(buf.rewards.mean()), "charts/broken_episodes": float(broken)}

    def training_step(self, batch, batch_idx):
        iteration_start = time.perf_counter()
        self.policy.eval()
        torch.set_num_threads(self.rollout_threads)  # the env workers need the other cores while collecting
        metrics = self.collect_rollout()
        torch.set_num_threads(self.update_threads)
        self.policy.train()
        metrics.update(self.update())
        steps = self.horizon * self.envs.num_envs
        metrics["charts/SPS"] = steps / (time.perf_counter() - iteration_start)
        metrics["charts/env_steps"] = float(self.env_steps)
        metrics["iteration"] = float(self.current_epoch + 1)  # 1-based; names the periodic checkpoints
        self.log_dict(metrics, on_step=False, on_epoch=True)
