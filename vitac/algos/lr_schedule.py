"""The learning-rate schedules of rl_games (`lr_schedule: fixed | adaptive`)."""

from __future__ import annotations

from vitac.utils.checks import is_number, refuse

LR_SCHEDULES = ("fixed", "adaptive")
# When the adaptive rate moves, and on which KL: rl_games' schedule_type legacy, standard and standard_epoch.
LR_SCHEDULE_EVERY = ("minibatch", "mini_epoch", "iteration")


class AdaptiveKLSchedule:
    """rl_games' adaptive schedule: divide the learning rate by `factor` when the KL divergence from the rollout
    policy exceeds twice `kl_threshold`, multiply it by `factor` when the KL is under half of it, and keep it
    within [min_lr, max_lr]. It holds PPO's step size near the threshold whatever the learning rate it starts
    from (TacSL trains its critic with it, threshold 0.008).

    Args:
        kl_threshold: the target approximate KL.
        every: when the rate moves: after each minibatch step on that minibatch's KL (rl_games' default
            `legacy`), after each mini-epoch on the mean KL of its minibatches (`standard`), or once per
            iteration on the mean over all of them (`standard_epoch`). The means move the rate less often and
            on less noisy KLs.
        min_lr, max_lr: bounds of the learning rate (rl_games' defaults 1e-6 and 1e-2; `algo.lr_min`,
            `algo.lr_max`). Every move lands within them, so a rate restored from a checkpoint above a lowered
            cap comes down to it at the first move.
        factor: the multiplicative step.
    """

    def __init__(self, kl_threshold: float = 0.008, every: str = "minibatch", min_lr: float = 1e-6,
                 max_lr: float = 1e-2, factor: float = 1.5):
        if not kl_threshold > 0.0:
            raise ValueError(f"algo.kl_threshold={kl_threshold!r} is not allowed: expected a positive number")
        check_every(every)
        check_bounds(min_lr, max_lr)
        self.kl_threshold, self.min_lr, self.max_lr, self.factor = float(kl_threshold), min_lr, max_lr, factor
        self.every = every
        self._kls: list[float] = []  # since the rate last moved; always emptied within one iteration

    def after_minibatch(self, lr: float, kl: float) -> float:
        """The rate after a minibatch step whose approximate KL was `kl`."""
        self._kls.append(kl)
        return self._at("minibatch", lr)

    def after_mini_epoch(self, lr: float) -> float:
        return self._at("mini_epoch", lr)

    def after_iteration(self, lr: float) -> float:
        return self._at("iteration", lr)

    def _at(self, boundary: str, lr: float) -> float:
        if boundary != self.every or not self._kls:
            return lr
        kl = sum(self._kls) / len(self._kls)
        self._kls.clear()
        return self.update(lr, kl)

    def update(self, lr: float, kl: float) -> float:
        """rl_games' rule: the next learning rate, given the current one and a KL."""
        if kl > 2.0 * self.kl_threshold:
            lr = lr / self.factor
        elif kl < 0.5 * self.kl_threshold:
            lr = lr * self.factor
        return min(max(lr, self.min_lr), self.max_lr)


def check_every(every: str) -> str:
    if every not in LR_SCHEDULE_EVERY:
        raise ValueError(f"algo.lr_schedule_every={every!r} is not allowed: expected one of {', '.join(LR_SCHEDULE_EVERY)}")
    return every


def check_bounds(min_lr, max_lr) -> None:
    for key, value in (("algo.lr_min", min_lr), ("algo.lr_max", max_lr)):
        if not is_number(value) or not value > 0:
            refuse(key, value, "a number > 0")
    if not min_lr <= max_lr:
        refuse("algo.lr_max", max_lr, f"a number >= algo.lr_min={min_lr!r}")


def make_lr_schedule(name: str, kl_threshold: float, every: str = "minibatch", min_lr: float = 1e-6,
                     max_lr: float = 1e-2, lr: float | None = None) -> AdaptiveKLSchedule | None:
    """`algo.lr_schedule` -> a schedule (None: the learning rate stays fixed), checked before any simulation.
    With the adaptive schedule the starting rate `lr` (`algo.lr`) must lie within its bounds."""
    if name not in LR_SCHEDULES:
        raise ValueError(f"algo.lr_schedule={name!r} is not allowed: expected one of {', '.join(LR_SCHEDULES)}")
    if name == "adaptive":
        schedule = AdaptiveKLSchedule(kl_threshold, every, min_lr, max_lr)
        if lr is not None and not min_lr <= lr <= max_lr:
            refuse("algo.lr", lr, f"a number within [algo.lr_min, algo.lr_max] = [{min_lr!r}, {max_lr!r}] "
                                  "with algo.lr_schedule=adaptive")
        return schedule
    check_every(every)  # typos are refused even while the rate is fixed
    check_bounds(min_lr, max_lr)
    return None
