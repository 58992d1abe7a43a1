"""The learning-rate schedules of rl_games (`lr_schedule: fixed | adaptive`)."""

from __future__ import annotations

LR_SCHEDULES = ("fixed", "adaptive")


class AdaptiveKLSchedule:
    """rl_games' adaptive schedule: after each minibatch step, divide the learning rate by `factor` when the
    KL divergence from the rollout policy exceeds twice `kl_threshold`, multiply it by `factor` when the KL is
    under half of it, and keep it within [min_lr, max_lr]. It holds PPO's step size near the threshold whatever
    the learning rate it starts from (TacSL trains its critic with it, threshold 0.008).

    Args:
        kl_threshold: the target approximate KL per minibatch.
        min_lr, max_lr: bounds of the learning rate (rl_games' defaults).
        factor: the multiplicative step.
    """

    def __init__(self, kl_threshold: float = 0.008, min_lr: float = 1e-6, max_lr: float = 1e-2, factor: float = 1.5):
        if not kl_threshold > 0.0:
            raise ValueError(f"algo.kl_threshold={kl_threshold!r} is not allowed: expected a positive number")
        self.kl_threshold, self.min_lr, self.max_lr, self.factor = float(kl_threshold), min_lr, max_lr, factor

    def update(self, lr: float, kl: float) -> float:
        """The learning rate for the next minibatch, given the current one and this minibatch's KL."""
        if kl > 2.0 * self.kl_threshold:
            return max(lr / self.factor, self.min_lr)
        if kl < 0.5 * self.kl_threshold:
            return min(lr * self.factor, self.max_lr)
        return lr


def make_lr_schedule(name: str, kl_threshold: float) -> AdaptiveKLSchedule | None:
    """`algo.lr_schedule` -> a schedule (None: the learning rate stays fixed), checked before any simulation."""
    if name not in LR_SCHEDULES:
        raise ValueError(f"algo.lr_schedule={name!r} is not allowed: expected one of {', '.join(LR_SCHEDULES)}")
    return AdaptiveKLSchedule(kl_threshold) if name == "adaptive" else None
