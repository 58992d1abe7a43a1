"""PPO math as small pure tensor functions (cleanrl's names, rl_games' loss forms)."""

from __future__ import annotations

import math

import torch


def gae(rewards, values, next_values, episode_ends, gamma: float, lam: float):
    """Generalized advantage estimation over (T, N) tensors, torchrl's bootstrap form.

    Args:
        rewards: r_t.
        values: V(s_t).
        next_values: value of the state after s_t *in the same episode*: V(s_{t+1}) mid-episode, the
            value of the final observation at a truncation, 0 at a termination.
        episode_ends: 1 where the episode ended at t (terminated or truncated): the lambda-trace is cut.
    Returns:
        advantages, returns (T, N).
    """
    advantages = torch.zeros_like(rewards)
    last = torch.zeros_like(rewards[0])
    for t in reversed(range(rewards.shape[0])):
        delta = rewards[t] + gamma * next_values[t] - values[t]
        last = delta + gamma * lam * (1.0 - episode_ends[t]) * last
        advantages[t] = last
    return advantages, advantages + values


def normalize_advantages(advantages: torch.Tensor) -> torch.Tensor:
    """(adv - mean) / (std + 1e-8); a single element is returned unchanged (its std is undefined)."""
    if advantages.numel() <= 1:
        return advantages
    return (advantages - advantages.mean()) / (advantages.std() + 1e-8)


def gaussian_log_prob(actions, mean, log_std):
    """Sum over action dimensions of the diagonal Gaussian log-density."""
    var = torch.exp(2.0 * log_std)
    return (-0.5 * (actions - mean) ** 2 / var - log_std - 0.5 * math.log(2 * math.pi)).sum(-1)


def gaussian_entropy(log_std):
    return (log_std + 0.5 * (1.0 + math.log(2 * math.pi))).sum(-1)


def policy_loss(new_log_prob, old_log_prob, advantages, clip: float):
    """Clipped surrogate (to minimise), approx KL ((r-1) - log r) and clip fraction.

    The log-ratio is clamped to +-20 before exponentiating: when the policy's std collapses, a stale
    action can be millions of nats unlikely and exp() would overflow to inf (then NaN gradients).
    """
    log_ratio = (new_log_prob - old_log_prob).clamp(-20.0, 20.0)
    ratio = log_ratio.exp()
    loss = torch.max(-advantages * ratio, -advantages * ratio.clamp(1.0 - clip, 1.0 + clip)).mean()
    with torch.no_grad():
        approx_kl = ((ratio - 1.0) - log_ratio).mean()
        clipfrac = ((ratio - 1.0).abs() > clip).float().mean()
    return loss, approx_kl, clipfrac


def value_loss(new_values, old_values, returns, clip: float | None):
    """max((v - R)^2, (v_clipped - R)^2) averaged, v_clipped = old + clamp(new - old, +-clip); rl_games' form."""
    unclipped = (new_values - returns) ** 2
    if clip is None:
        return unclipped.mean()
    clipped = old_values + (new_values - old_values).clamp(-clip, clip)
    return torch.max(unclipped, (clipped - returns) ** 2).mean()


def bounds_loss(mean, soft_bound: float = 1.1):
    """rl_games' bound loss: squared excess of the action mean beyond +-soft_bound, summed over actions."""
    return ((mean - soft_bound).clamp_min(0.0) ** 2 + (mean + soft_bound).clamp_max(0.0) ** 2).sum(-1).mean()


def explained_variance(values, returns) -> float:
    var = returns.var()
    return float("nan") if var == 0 else float(1.0 - (returns - values).var() / var)
