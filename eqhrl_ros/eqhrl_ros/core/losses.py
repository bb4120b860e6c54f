"""The losses of one update, each one call into equations.py: what the eager update (learner.py)
and the compiled one (compiled_update.py) both compute. No state here."""

from __future__ import annotations

import torch

from . import equations as eq


def soft_bellman_targets(actor, critic_target, next_obs, reward, terminated, noise, alpha, gamma) -> torch.Tensor:
    """Eq. 4's y, a' = tanh(mean + std * noise) drawn from the current actor."""
    next_mean, next_log_std = actor(next_obs)
    next_action, next_log_prob = eq.squashed_gaussian_sample(next_mean, next_log_std, noise)
    next_q1, next_q2 = critic_target(next_obs, next_action)
    return eq.soft_bellman_target(reward, terminated, next_q1, next_q2, next_log_prob, alpha, gamma)


def twin_critic_loss(critic, obs, action, y) -> torch.Tensor:
    q1, q2 = critic(obs, action)
    return eq.critic_loss(q1, y) + eq.critic_loss(q2, y)  # Eq. 5, i = 1, 2


def policy_loss(actor, critic, obs, noise, alpha) -> tuple[torch.Tensor, torch.Tensor]:
    """Eq. 6 with a = tanh(mean + std * noise); also log pi(a|s) for the temperature."""
    mean, log_std = actor(obs)
    action, log_prob = eq.squashed_gaussian_sample(mean, log_std, noise)
    q1, q2 = critic(obs, action)
    return eq.actor_loss(log_prob, q1, q2, alpha), log_prob
