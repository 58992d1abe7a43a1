"""The randomization curriculum: promotions, and what a scale does to the initial state."""

from __future__ import annotations

import numpy as np
import pytest

from vitac.algos.curriculum import RandomizationCurriculum
from vitac.envs.gym_env import TaskEnv


def test_promotes_only_on_a_full_successful_window_and_stops_at_one():
    c = RandomizationCurriculum(start=0.8, step=0.15, threshold=0.5, window=4)
    assert not c.observe([1, 1, 1])  # window not full yet
    assert c.observe([0]) and c.scale == pytest.approx(0.95)
    assert not c.observe([0, 0, 0, 1])  # 25% < 50%
    assert c.observe([1, 1, 1, 1]) and c.scale == 1.0
    assert not c.observe([1, 1, 1, 1]) and c.scale == 1.0
    restored = RandomizationCurriculum(window=4)
    restored.load_state_dict(c.state_dict())
    assert restored.scale == 1.0 and list(restored.recent) == list(c.recent)


def test_bad_curriculum_values_are_refused():
    with pytest.raises(ValueError, match=r"curriculum\.threshold"):
        RandomizationCurriculum(threshold=0.0)


def test_scale_zero_starts_every_episode_at_the_midpoints_and_one_restores_the_ranges():
    env = TaskEnv({"observations": ["proprio", "peg_state"]}, seed=0)
    env.set_randomization_scale(0.0)
    a, _ = env.reset(seed=1)
    b, _ = env.reset(seed=2)
    np.testing.assert_allclose(a["peg_state"], b["peg_state"], atol=1e-6)
    env.set_randomization_scale(1.0)
    c, _ = env.reset(seed=1)
    assert np.abs(c["peg_state"] - a["peg_state"]).max() > 1e-3
    with pytest.raises(ValueError, match="scale"):
        env.set_randomization_scale(1.5)
    env.close()
