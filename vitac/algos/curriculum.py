"""Optional curriculum over the initial-state randomization (DESIGN.md: what a CPU budget can learn)."""

from __future__ import annotations

from collections import deque


class RandomizationCurriculum:
    """Scale every randomization range about its midpoint, starting at `start`, and raise the scale by
    `step` (up to 1, the paper's randomization) whenever the success rate over the last `window`
    finished training episodes reaches `threshold`. Evaluation always uses the paper's ranges.

    Args:
        start: initial scale in [0, 1].
        step: increment per promotion.
        threshold: success rate over the window that earns a promotion.
        window: finished episodes the rate is computed over (cleared at each promotion).
    """

    def __init__(self, start: float = 0.0, step: float = 0.1, threshold: float = 0.7, window: int = 32):
        if not 0.0 <= start <= 1.0:
            raise ValueError(f"curriculum.start={start!r} is not allowed: expected a number in [0, 1]")
        if not 0.0 < step <= 1.0:
            raise ValueError(f"curriculum.step={step!r} is not allowed: expected a number in (0, 1]")
        if not 0.0 < threshold <= 1.0:
            raise ValueError(f"curriculum.threshold={threshold!r} is not allowed: expected a number in (0, 1]")
        if window < 1:
            raise ValueError(f"curriculum.window={window!r} is not allowed: expected a positive integer")
        self.scale, self.step, self.threshold = float(start), float(step), float(threshold)
        self.recent: deque = deque(maxlen=window)

    def observe(self, successes) -> bool:
        """Record finished episodes' successes; returns True when the scale was raised."""
        self.recent.extend(float(s) for s in successes)
        full = len(self.recent) == self.recent.maxlen
        if self.scale < 1.0 and full and sum(self.recent) / len(self.recent) >= self.threshold:
            self.scale = min(1.0, round(self.scale + self.step, 6))
            self.recent.clear()
            return True
        return False

    def state_dict(self) -> dict:
        return dict(scale=self.scale, recent=list(self.recent))

    def load_state_dict(self, state: dict) -> None:
        self.scale = state["scale"]
        self.recent.clear()
        self.recent.extend(state["recent"])
