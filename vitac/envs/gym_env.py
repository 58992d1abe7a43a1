"""gymnasium adapter of any composer task here: terminated vs truncated, success info, exact state."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from dm_env import StepType

from vitac.sim.environment import build_environment
from vitac.tasks import make_task_config
from vitac.tasks.config import GraspTaskConfig


def _space(spec) -> gym.spaces.Box:
    if spec.dtype == np.uint8:
        return gym.spaces.Box(0, 255, spec.shape, np.uint8)
    return gym.spaces.Box(-np.inf, np.inf, spec.shape, np.float32)


RESET_ATTEMPTS = 3


def _finite(obs: dict) -> bool:
    return all(np.isfinite(v).all() for v in obs.values() if v.dtype != np.uint8)


class TaskEnv(gym.Env):
    """One environment of a task with gymnasium's API.

    composer ends an episode at the time limit with discount 1: that is reported as `truncated`
    (bootstrap), and a discount of 0 (a task's success or failure, or diverged physics) as `terminated`.
    `info` carries `success` (judged at the last step), `steps_to_success` (first step the criterion held,
    -1 if never) and `keypoint_distance`; an episode's last also its `outcome` (the task's label and
    measurements) and `factors` (the values its randomization drew, by factor name).

    Args:
        config: task settings (a task's config, or a dict of its keys with `_target_` naming its class;
            without it, the insertion task's).
        seed: seed of the episode random state.
        offscreen_size: offscreen render buffer in pixels (larger only for tools that render big views).
    """

    metadata = {"render_modes": ["rgb_array"]}

    def __init__(self, config: GraspTaskConfig | dict | None = None, seed: int | None = None,
                 offscreen_size: int | None = None):
        self.config = config if isinstance(config, GraspTaskConfig) else make_task_config(config)
        self._env = build_environment(self.config.build_task(offscreen_size), seed=seed)
        obs_spec = self._env.observation_spec()
        self.observation_space = gym.spaces.Dict({k: _space(v) for k, v in obs_spec.items()})
        self.action_space = gym.spaces.Box(-1.0, 1.0, (6,), np.float32)
        self._needs_reset = True

    @property
    def task(self):
        return self._env.task

    @property
    def physics(self):
        return self._env.physics

    def _info(self) -> dict:
        task, physics = self._env.task, self._env.physics
        return dict(success=bool(task.is_success(physics)), steps_to_success=int(task.first_success_step),
                    keypoint_distance=float(task.keypoint_distance(physics)))

    def reset(self, *, seed: int | None = None, options=None):
        super().reset(seed=seed)
        if seed is not None:
            self._env.random_state.seed(seed)
        for _ in range(RESET_ATTEMPTS):  # a start whose observation is not finite is drawn again
            self._env.reset()
            # dm_control's reset ends with a forward pass with actuation disabled, so composer's first
            # observation misses the grip force; recompute it with the actuators on.
            self._env.physics.forward()
            obs = self.observation()
            if _finite(obs):
                break
        else:
            bad = sorted(k for k, v in obs.items() if v.dtype != np.uint8 and not np.isfinite(v).all())
            raise RuntimeError(f"{RESET_ATTEMPTS} episode starts in a row gave non-finite observations {bad}")
        self._needs_reset = False
        return obs, self._info()

    def step(self, action):
        if self._needs_reset:
            raise RuntimeError("TaskEnv.step called after the episode ended: call reset() first")
        if not np.all(np.isfinite(action)):
            raise ValueError(f"action={np.asarray(action).tolist()} is not allowed: expected 6 finite numbers in [-1, 1]")
        timestep = self._env.step(np.asarray(action, dtype=np.float64))
        obs, reward = dict(timestep.observation), float(timestep.reward)
        terminated = timestep.step_type == StepType.LAST and timestep.discount == 0.0
        truncated = timestep.step_type == StepType.LAST and not terminated
        # A NaN or Inf reaching the learner would poison its normalizers and weights: such a step ends the
        # episode as a failure, its values zeroed (the observation is only the episode's last, never acted on).
        finite = np.isfinite(reward) and _finite(obs)
        if not finite:
            obs = {k: v if v.dtype == np.uint8 else np.nan_to_num(v, nan=0.0, posinf=0.0, neginf=0.0)
                   for k, v in obs.items()}
            reward, terminated, truncated = 0.0, True, False
        self._needs_reset = terminated or truncated
        info = self._info()
        if self._needs_reset:  # how the episode ended, and what it started from, for evaluation reports
            task = self._env.task
            info.update(task.outcome(self._env.physics), factors=dict(task.episode_factors))
            if task.config.measure_force_balance:
                info.update(force_balance=task.force_balance.summary())
            if self._env.diverged:  # composer ended a diverged simulation
                info.update(outcome="physics diverged", success=False)
            elif not finite:
                info.update(outcome="non-finite observation or reward", success=False)
        return obs, reward, bool(terminated), bool(truncated), info

    def render(self):
        return self._env.task.render_wrist(self._env.physics)

    def new_oracle(self, **oracle_options):
        """The task's scripted controller for one episode: `oracle(physics)` -> action."""
        from vitac.tasks import import_object

        return import_object(self.config.ORACLE)(self.task, **oracle_options)

    def run_oracle_episode(self, seed: int, **oracle_options) -> dict:
        """One episode driven by the task's scripted oracle (it reads the true state; insertion's takes
        `observed_socket=True` to aim at the noisy socket position the actor sees)."""
        oracle = self.new_oracle(**oracle_options)
        self.reset(seed=seed)
        done = False
        while not done:
            _, _, terminated, truncated, info = self.step(oracle(self.physics))
            done = terminated or truncated
        return info

    def set_randomization_scale(self, scale: float) -> None:
        """Shrink (scale < 1) or restore (1) every randomization range from the next episode on."""
        if not 0.0 <= scale <= 1.0:
            raise ValueError(f"randomization scale={scale!r} is not allowed: expected a number in [0, 1]")
        self._env.task.randomization_scale = float(scale)

    def get_state(self) -> dict:
        """Everything needed to continue this environment exactly: physics, task (with randomized model
        fields), RNG and episode flags."""
        physics = self._env.physics
        # qacc_warmstart seeds the next constraint solve: without it a restored environment's contacts solve from
        # another start and its trajectory drifts from the original's within a few steps.
        return dict(physics=physics.get_state().copy(), time=physics.data.time, ctrl=physics.data.ctrl.copy(),
                    qacc_warmstart=physics.data.qacc_warmstart.copy(),
                    task=self._env.task.get_state(physics), rng=self._env.random_state.get_state(),
                    needs_reset=self._needs_reset, composer_reset_next=self._env._reset_next_step)

    def set_state(self, state: dict) -> None:
        physics = self._env.physics
        self._env.task.set_state(physics, state["task"])
        physics.data.ctrl[:] = state["ctrl"]
        physics.set_state(state["physics"])
        if "time" in state:  # dm_control's state leaves it out; the task's per-state values are keyed by it
            physics.data.time = state["time"]
        physics.forward()
        if "qacc_warmstart" in state:  # absent from checkpoints written before it was kept
            physics.data.qacc_warmstart[:] = state["qacc_warmstart"]
        self._env.random_state.set_state(state["rng"])
        self._needs_reset = state["needs_reset"]
        self._env._reset_next_step = state["composer_reset_next"]

    def observation(self) -> dict:
        """The current observation, recomputed from physics."""
        return self._env.task.observe(self._env.physics)

    def close(self):
        if getattr(self, "_closed", False):  # closed already: gymnasium lets close() be called again
            return
        self._env.task.close()
        self._env.close()
        self._closed = True
