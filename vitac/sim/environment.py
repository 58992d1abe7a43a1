"""composer's Environment with a lean control step, for any task that steps its own physics substeps."""

from __future__ import annotations

import logging

import dm_env
from dm_control import composer
from dm_control.rl import control


class LeanEnvironment(composer.Environment):
    """composer's Environment with a leaner control step: the physics substeps in one call (the task's
    `step_physics`, MuJoCo's own loop) and the observation computed once, by the task, after them.

    Between substeps composer calls the substep hooks and the observation updater. This task and its entities
    have no substep hooks, and each observable keeps one value taken after the last substep (no delay, no
    buffer), so the trajectory and the observations are composer's own bit for bit (tested; the contact
    forces apart, which this step takes from the last substep's solve), without eight Python round trips
    through composer and dm_control per control step (docs/benchmarks.md). Reset, specs and the step's hooks,
    reward, discount, time limit and physics-error handling are composer's (dm-control 1.0.50).
    """

    def __init__(self, task: composer.Task, **kwargs):
        substep_hooks = [f"{type(owner).__name__}.{hook}" for owner, base in
                         [(task, composer.Task)] + [(e, composer.Entity) for e in task.root_entity.iter_entities()]
                         for hook in ("before_substep", "after_substep")
                         if getattr(type(owner), hook) is not getattr(base, hook)]
        sampled = [name for name, obs in task.observables.items()
                   if obs.update_interval != 1 or obs.buffer_size not in (None, 1) or obs.delay not in (None, 0)
                   or obs.aggregator is not None or obs.corruptor is not None]
        if substep_hooks or sampled:
            raise ValueError(f"{type(self).__name__} steps the physics substeps in one call: it cannot run substep "
                             f"hooks {substep_hooks} or buffer, delay or transform observables {sampled}")
        super().__init__(task, **kwargs)
        self.diverged = False  # whether the last step ended its episode because the physics diverged

    def add_extra_hook(self, hook_name, hook_callable):
        if hook_name in ("before_substep", "after_substep"):
            raise ValueError(f"hook_name={hook_name!r} is not allowed: {type(self).__name__} steps the physics "
                             "substeps in one call")
        super().add_extra_hook(hook_name, hook_callable)

    def step(self, action) -> dm_env.TimeStep:
        if self._reset_next_step:
            self._reset_next_step = False
            return self.reset()
        physics = self._physics_proxy
        self._hooks.before_step(physics, action, self._random_state)
        try:
            self._task.step_physics(self._physics, self._n_sub_steps)
            diverged = False
        except control.PhysicsError as error:
            if self._raise_exception_on_physics_error:
                raise
            logging.warning(error)
            diverged = True
        self.diverged = diverged
        self._hooks.after_step(physics, self._random_state)
        if diverged:
            reward, discount, last = 0.0, 0.0, True
        else:
            reward, discount = self._task.get_reward(physics), self._task.get_discount(physics)
            last = self._task.should_terminate_episode(physics) or self._physics.time() >= self._time_limit
        self._reset_next_step = last
        return dm_env.TimeStep(dm_env.StepType.LAST if last else dm_env.StepType.MID, reward, discount,
                               self._task.observe(physics))


def build_environment(task: composer.Task, seed: int | None = None) -> LeanEnvironment:
    """A composer Environment over `task`, whose episodes the task ends (`should_terminate_episode`)."""
    # Tasks randomize model fields in place and never edit the MJCF: recompiling it at every reset (composer's
    # default) would only cost ~25 ms an episode. A diverged simulation (rare: a part wedged between stiff contacts)
    # ends its episode as a termination with reward 0, which the adapter reports, instead of killing a long run.
    return LeanEnvironment(task, random_state=seed, time_limit=float("inf"), strip_singleton_obs_buffer_dim=True,
                           raise_exception_on_physics_error=False, recompile_mjcf_every_episode=False)
