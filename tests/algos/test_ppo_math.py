"""Math tier: GAE with termination vs truncation, and each PPO loss term against hand-worked values."""

from __future__ import annotations

import math

import pytest
import torch

from vitac.algos import losses
from vitac.algos.lr_schedule import AdaptiveKLSchedule, make_lr_schedule
from vitac.algos.ppo import make_optimizer


def _gae(rewards, values, next_values, ends, gamma=0.9, lam=0.5):
    t = lambda x: torch.tensor(x, dtype=torch.float32)[:, None]  # noqa: E731
    adv, ret = losses.gae(t(rewards), t(values), t(next_values), t(ends), gamma, lam)
    return adv[:, 0].tolist(), ret[:, 0].tolist()


def test_gae_mid_episode_hand_worked():
    # Two mid-episode steps, bootstrapping from V(s_2) = 3 after the rollout.
    adv, ret = _gae([1.0, 2.0], [0.5, 1.0], [1.0, 3.0], [0, 0])
    d1 = 2.0 + 0.9 * 3.0 - 1.0  # 3.7
    d0 = 1.0 + 0.9 * 1.0 - 0.5  # 1.4
    assert adv == pytest.approx([d0 + 0.9 * 0.5 * d1, d1])
    assert ret == pytest.approx([d0 + 0.45 * d1 + 0.5, d1 + 1.0])


def test_gae_termination_does_not_bootstrap():
    adv, _ = _gae([1.0, 2.0], [0.5, 1.0], [1.0, 0.0], [0, 1])
    assert adv[1] == pytest.approx(2.0 - 1.0)


def test_gae_truncation_bootstraps_from_the_final_observation():
    # Episode truncated at t=1 with V(final obs) = 4; the next episode's first value (7) must not leak.
    adv, _ = _gae([1.0, 2.0, 0.0], [0.5, 1.0, 7.0], [1.0, 4.0, 0.0], [0, 1, 1])
    assert adv[1] == pytest.approx(2.0 + 0.9 * 4.0 - 1.0)
    assert adv[0] == pytest.approx((1.0 + 0.9 * 1.0 - 0.5) + 0.45 * adv[1])


def test_gae_next_episode_never_leaks_into_previous_target():
    base, _ = _gae([1.0, 2.0, 5.0], [0.5, 1.0, 7.0], [1.0, 4.0, 2.0], [0, 1, 0])
    changed, _ = _gae([1.0, 2.0, -50.0], [0.5, 1.0, 70.0], [1.0, 4.0, 9.0], [0, 1, 0])
    assert base[:2] == pytest.approx(changed[:2])


def test_policy_loss_hand_worked():
    new = torch.log(torch.tensor([1.5, 0.5, 1.1]))
    old = torch.zeros(3)
    adv = torch.tensor([1.0, 1.0, -2.0])
    loss, kl, clipfrac = losses.policy_loss(new, old, adv, clip=0.2)
    # per sample max(-A r, -A clip(r)): [-1.2, -0.5, 2.2]
    assert float(loss) == pytest.approx((-1.2 - 0.5 + 2.2) / 3, rel=1e-5)
    assert float(clipfrac) == pytest.approx(2 / 3)
    expected_kl = sum((r - 1) - math.log(r) for r in (1.5, 0.5, 1.1)) / 3
    assert float(kl) == pytest.approx(expected_kl, rel=1e-5)


@pytest.mark.parametrize("new,old,ret,expected", [
    (1.1, 1.0, 2.0, 0.81),  # inside the clip range: the unclipped loss
    (3.0, 1.0, 2.0, 1.0),  # clipped value 1.2 -> 0.64 smaller: max picks unclipped 1.0
    (0.0, 1.0, -1.0, 3.24),  # clipped value 0.8 -> (1.8)^2 = 3.24 larger than 1.0
])
def test_value_loss_clipping_cases(new, old, ret, expected):
    t = lambda x: torch.tensor([x])  # noqa: E731
    assert float(losses.value_loss(t(new), t(old), t(ret), clip=0.2)) == pytest.approx(expected, rel=1e-5)


def test_bounds_loss_zero_inside_positive_outside_with_inward_gradient():
    inside = torch.tensor([[0.5, -1.1, 1.0]])
    assert float(losses.bounds_loss(inside)) == 0.0
    mu = torch.tensor([[1.5, -2.0, 0.0]], requires_grad=True)
    loss = losses.bounds_loss(mu)
    assert float(loss.detach()) == pytest.approx(0.4**2 + 0.9**2, rel=1e-5)
    loss.backward()
    assert mu.grad[0, 0] > 0 and mu.grad[0, 1] < 0 and mu.grad[0, 2] == 0  # descent moves mu inward


def test_gaussian_log_prob_matches_torch_distribution():
    mean, log_std, x = torch.randn(5, 6), torch.randn(5, 6) * 0.3, torch.randn(5, 6) * 3
    ref = torch.distributions.Normal(mean, log_std.exp()).log_prob(x).sum(-1)
    assert torch.allclose(losses.gaussian_log_prob(x, mean, log_std), ref, atol=1e-5)
    assert torch.allclose(losses.gaussian_entropy(log_std),
                          torch.distributions.Normal(mean, log_std.exp()).entropy().sum(-1), atol=1e-5)


def test_advantage_normalization_and_single_element_guard():
    adv = losses.normalize_advantages(torch.tensor([1.0, 2.0, 3.0, 10.0]))
    assert float(adv.mean()) == pytest.approx(0.0, abs=1e-6) and float(adv.std()) == pytest.approx(1.0, rel=1e-4)
    assert torch.equal(losses.normalize_advantages(torch.tensor([5.0])), torch.tensor([5.0]))


def test_policy_loss_stays_finite_when_the_ratio_would_overflow():
    loss, kl, _ = losses.policy_loss(torch.tensor([500.0]), torch.tensor([0.0]), torch.tensor([-1.0]), clip=0.2)
    assert torch.isfinite(loss) and torch.isfinite(kl)


def test_adaptive_lr_follows_rl_games_rule_within_bounds():
    schedule = AdaptiveKLSchedule(kl_threshold=0.01)
    assert schedule.update(1e-3, 0.03) == pytest.approx(1e-3 / 1.5)  # KL above twice the threshold
    assert schedule.update(1e-3, 0.001) == pytest.approx(1.5e-3)  # under half of it
    assert schedule.update(1e-3, 0.01) == 1e-3  # near it: unchanged
    assert schedule.update(1.2e-6, 1.0) == 1e-6 and schedule.update(9e-3, 0.0) == 1e-2
    assert make_lr_schedule("fixed", 0.01) is None
    with pytest.raises(ValueError, match=r"algo.lr_schedule='cosine' is not allowed: expected one of fixed, adaptive"):
        make_lr_schedule("cosine", 0.01)
    with pytest.raises(ValueError, match=r"algo.kl_threshold=0.0 is not allowed"):
        make_lr_schedule("adaptive", 0.0)


def test_adaptive_lr_bounds_are_configurable_and_every_move_lands_within_them():
    schedule = make_lr_schedule("adaptive", 0.01, min_lr=1e-5, max_lr=1e-4, lr=1e-4)
    assert schedule.update(1e-4, 0.0) == 1e-4  # at the cap a small KL cannot raise it
    assert schedule.update(1.2e-5, 1.0) == 1e-5  # nor a large one lower it past the floor
    assert schedule.update(5e-5, 0.0) == pytest.approx(7.5e-5)  # within them, rl_games' rule as before
    # A rate above a cap lowered on resume comes down to the cap at its first move, whatever the KL.
    assert schedule.update(1e-2, 0.01) == 1e-4 and schedule.update(1e-2, 0.0) == 1e-4
    with pytest.raises(ValueError, match=r"algo.lr=0.001 is not allowed: expected a number within "
                                         r"\[algo.lr_min, algo.lr_max\] = \[1e-05, 0.0001\]"):
        make_lr_schedule("adaptive", 0.01, min_lr=1e-5, max_lr=1e-4, lr=1e-3)
    with pytest.raises(ValueError, match=r"algo.lr_max=1e-06 is not allowed: expected a number >= algo.lr_min=1e-05"):
        make_lr_schedule("fixed", 0.01, min_lr=1e-5, max_lr=1e-6)  # refused even while the rate is fixed
    with pytest.raises(ValueError, match=r"algo.lr_min=0 is not allowed: expected a number > 0"):
        make_lr_schedule("adaptive", 0.01, min_lr=0, max_lr=1e-2)
    assert make_lr_schedule("fixed", 0.01, lr=1.0) is None  # a fixed rate is not held to the bounds


def test_adaptive_lr_moves_at_its_boundary_on_the_mean_kl_since_it_last_moved():
    kls = [0.001, 0.05, 0.001, 0.001]  # two mini-epochs of two minibatches; threshold 0.01: 0.005 < ok < 0.02

    def run(every: str) -> list[float]:
        schedule, lr, rates = AdaptiveKLSchedule(kl_threshold=0.01, every=every), 1e-3, []
        for epoch in range(2):
            for kl in kls[2 * epoch:2 * epoch + 2]:
                lr = schedule.after_minibatch(lr, kl)
                rates.append(lr)
            lr = schedule.after_mini_epoch(lr)
            rates.append(lr)
        rates.append(schedule.after_iteration(lr))
        return rates

    # minibatch: x1.5, /1.5, x1.5, x1.5 on each KL; the boundaries after them change nothing.
    assert run("minibatch") == pytest.approx([1.5e-3, 1e-3, 1e-3, 1.5e-3, 2.25e-3, 2.25e-3, 2.25e-3])
    # mini_epoch: mean 0.0255 > 0.02 -> /1.5 after the first, mean 0.001 -> x1.5 after the second.
    assert run("mini_epoch") == pytest.approx([1e-3, 1e-3, 1e-3 / 1.5, 1e-3 / 1.5, 1e-3 / 1.5, 1e-3, 1e-3])
    # iteration: the mean of all four, 0.01325, is within the band: unchanged.
    assert run("iteration") == pytest.approx([1e-3] * 7)
    with pytest.raises(ValueError, match=r"algo.lr_schedule_every='epoch' is not allowed: expected one of "
                                         r"minibatch, mini_epoch, iteration"):
        make_lr_schedule("adaptive", 0.01, "epoch")


def test_fused_adam_continues_a_default_adam_state_with_the_same_arithmetic():
    """Checkpoints written before PPO's optimizer was fused resume with it, and both step alike."""
    torch.manual_seed(0)
    weights = [torch.randn(64, 32), torch.randn(32)]
    grads = [[torch.randn_like(w) for w in weights] for _ in range(6)]

    def run(fused_from: int | None):
        params = [w.clone().requires_grad_(True) for w in weights]
        optimizer = torch.optim.Adam(params, lr=1e-2, eps=1e-5)
        for i, step_grads in enumerate(grads):
            if i == fused_from:  # resume: the default Adam's state in the fused optimizer PPO builds
                state = optimizer.state_dict()
                optimizer = make_optimizer(params, lr=1e-2)
                optimizer.load_state_dict(state)
            for p, g in zip(params, step_grads, strict=True):
                p.grad = g.clone()
            optimizer.step()
        return params, optimizer

    reference, _ = run(fused_from=None)
    resumed, optimizer = run(fused_from=3)
    assert optimizer.defaults["fused"]
    for a, b in zip(reference, resumed, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)
    assert not torch.allclose(reference[0], weights[0])  # the steps moved the weights
