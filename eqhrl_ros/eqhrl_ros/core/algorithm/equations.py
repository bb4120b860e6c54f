"""Every equation of the EQ-HRL paper, in one place, named as the paper names it.

Paper: "An Efficient Human-in-the-loop Method for Stochastic Policy Reinforcement
Learning" (EQ-HRL). Equation numbers below are the paper's.

Conventions used throughout the package:
- The policy pi is a tanh-squashed Gaussian on the normalised action box [-1, 1]^m;
  actions are scaled affinely to the env's bounds only when they leave the learner.
  log pi, the entropy E(s) and SAC's target entropy (-m) all live in that normalised
  space, as in Stable-Baselines3. The entropy of the action in env units is
  E(s) + sum_i log(scale_i), a constant shift that does not change any gate decision.
- ``done`` in the Bellman target is the env's *termination* flag only: a time-limit
  truncation still bootstraps.

Eq. 1 and Eq. 2 (V^pi and Q^pi) are definitions the critics approximate, and
Eq. 3 (the maximum-entropy objective J(pi)) is what Eqs. 4-6 optimise; they have
no code of their own.
"""

from __future__ import annotations

import math
from typing import Iterable, Sequence

import numpy as np
import torch
import torch.nn.functional as F

LOG_2 = math.log(2.0)


# --------------------------------------------------------------------------- SAC (Section 2.2)


def soft_bellman_target(
    reward: torch.Tensor,
    terminated: torch.Tensor,
    next_q1_target: torch.Tensor,
    next_q2_target: torch.Tensor,
    next_log_prob: torch.Tensor,
    alpha: torch.Tensor | float,
    gamma: float,
) -> torch.Tensor:
    """Eq. 4: y_t = r_t + gamma * E_{a' ~ pi}[ Q_theta^-(s', a') - alpha * log pi(a'|s') ].

    Q_theta^- is the smaller of the two target critics (clipped double Q, the reason
    SAC keeps twin critics); the expectation is estimated with one sample a' ~ pi(.|s').
    Terminal transitions do not bootstrap.
    """
    next_value = torch.min(next_q1_target, next_q2_target) - alpha * next_log_prob
    return reward + gamma * (1.0 - terminated) * next_value


def critic_loss(q: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Eq. 5: L_Q(theta_i) = E[(Q_theta_i(s_t, a_t) - y_t)^2], the mean squared Bellman error.

    Algorithm 1's listing drops the square; the squared form of Eq. 5 is the one used.
    """
    return F.mse_loss(q, y)


def actor_loss(log_prob: torch.Tensor, q1: torch.Tensor, q2: torch.Tensor, alpha: torch.Tensor | float) -> torch.Tensor:
    """Eq. 6: L_pi(phi) = E[ alpha * log pi_phi(a|s) - Q(s, a) ], a ~ pi_phi(.|s).

    Q is min_i Q_theta_i of the *current* critics, as in Algorithm 1's actor update
    (Eq. 6 writes Q_theta^-; the listing and standard SAC use the online critics).
    """
    return (alpha * log_prob - torch.min(q1, q2)).mean()


def temperature_loss(log_alpha: torch.Tensor, log_prob: torch.Tensor, target_entropy: float) -> torch.Tensor:
    """Learned temperature (Table 1: 'Learning rate (alpha)', 'Target alpha: negative action dim').

    Minimising -alpha * (log pi + H_target) raises alpha when the policy's entropy
    -log pi falls below the target and lowers it otherwise (Haarnoja et al., 2018).
    """
    return -(log_alpha.exp() * (log_prob.detach() + target_entropy)).mean()


@torch.no_grad()
def soft_update(target_params: Sequence[torch.Tensor], online_params: Sequence[torch.Tensor], tau: float) -> None:
    """Algorithm 1, last line: theta_i^- <- tau * theta_i + (1 - tau) * theta_i^-."""
    # lerp(target, online, tau) = target + tau * (online - target), in one fused call.
    torch._foreach_lerp_(list(target_params), list(online_params), tau)


# --------------------------------------------------------------------------- the policy pi


def log_one_minus_tanh_squared(u: torch.Tensor) -> torch.Tensor:
    """log(1 - tanh(u)^2), the log-Jacobian of the tanh squashing, computed stably.

    1 - tanh(u)^2 = 4 / (e^u + e^-u)^2, so its log is 2 * (log 2 - u - softplus(-2u)).
    """
    return 2.0 * (LOG_2 - u - F.softplus(-2.0 * u))


def squashed_gaussian_action(mean: torch.Tensor, log_std: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
    """a = tanh(mean + std * noise): the action of ``squashed_gaussian_sample`` without log pi
    (acting needs no log-probability)."""
    return torch.tanh(mean + log_std.exp() * noise)


def squashed_gaussian_sample(
    mean: torch.Tensor, log_std: torch.Tensor, noise: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Sample a = tanh(u), u = mean + std * noise, and return (a, log pi(a|s)).

    log pi(a|s) = log N(u; mean, std) - sum_i log(1 - tanh(u_i)^2) (change of variables).
    """
    u = mean + log_std.exp() * noise
    gaussian_log_prob = (-0.5 * noise.pow(2) - log_std - 0.5 * math.log(2.0 * math.pi)).sum(-1)
    log_prob = gaussian_log_prob - log_one_minus_tanh_squared(u).sum(-1)
    return torch.tanh(u), log_prob


# --------------------------------------------------------------------------- advising (Section 3)


def early_advising(episode: int, advising_budget: int) -> bool:
    """Eq. 7: Iteration < AdvisingBudget. Advice only in the first ``advising_budget`` episodes."""
    return episode < advising_budget


def q_discrepancy(q1: torch.Tensor, q2: torch.Tensor) -> torch.Tensor:
    """Eq. 8: D(s) = |Q_theta1(s, a) - Q_theta2(s, a)|, a ~ pi(.|s) the action about to be taken."""
    return (q1 - q2).abs()


def policy_entropy(mean: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
    """Eq. 9: E(s) = -integral pi(a|s) log pi(a|s) da for the tanh-squashed Gaussian policy, exactly.

    With a = tanh(u), u ~ N(mean, std^2), the change of variables gives
        E(s) = H[N(mean, std^2)] + E_u[ sum_i log(1 - tanh(u_i)^2) ].
    The Gaussian part is sum_i (0.5 * log(2 * pi * e) + log std_i). The Jacobian part is a
    sum of one-dimensional Gaussian expectations, one per action dimension, each computed
    by ``expected_log_jacobian`` to float precision with fixed nodes: deterministic, no draws.
    """
    gaussian_entropy = (0.5 * math.log(2.0 * math.pi * math.e) + log_std).sum(-1)
    return gaussian_entropy + expected_log_jacobian(mean, log_std).sum(-1)


def policy_entropy_monte_carlo(mean: torch.Tensor, log_std: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
    """Eq. 9 estimated with the K standard-normal draws in ``noise`` (shape [K, ..., m]):
    the Jacobian part of ``policy_entropy`` as a Monte Carlo average (entropy_estimator
    monte_carlo; the default before the exact one, kept for comparison)."""
    gaussian_entropy = (0.5 * math.log(2.0 * math.pi * math.e) + log_std).sum(-1)
    u = mean + log_std.exp() * noise
    return gaussian_entropy + log_one_minus_tanh_squared(u).sum(-1).mean(0)


# Fixed nodes for expected_log_jacobian (numpy's Gauss-Hermite and Gauss-Legendre rules).
# 64 of each give the expectation to within 1e-8 over the actor's whole log-std range
# (tests/core/algorithm/test_equations.py checks it against adaptive quadrature).
_WIDE = 1.0  # std above which the folded rule is used
_FOLD_END = 16.0  # log(1 + e^{-2u}) < 1e-13 past it
_NODES: dict = {}


def quadrature_nodes(like: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """(Hermite nodes * sqrt 2, Hermite weights / sqrt pi, fold nodes, fold weights * log(1 + e^-2u)),
    made once per dtype and device, by numpy: so before torch.compile traces a function that
    needs them (a compiled program reads them as constants; numpy cannot be traced)."""
    key = (like.dtype, like.device)
    if key not in _NODES:
        x, w = np.polynomial.hermite.hermgauss(64)
        t, v = np.polynomial.legendre.leggauss(64)
        u = 0.5 * _FOLD_END * (t + 1.0)
        fold_w = 0.5 * _FOLD_END * v * np.log1p(np.exp(-2.0 * u)) / math.sqrt(2.0 * math.pi)
        arrays = (x * math.sqrt(2.0), w / math.sqrt(math.pi), u, fold_w)
        _NODES[key] = tuple(torch.as_tensor(a, dtype=like.dtype, device=like.device) for a in arrays)
    return _NODES[key]


def expected_log_jacobian(mean: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
    """E_u[log(1 - tanh(u)^2)] for u ~ N(mean, std^2), elementwise.

    log(1 - tanh(u)^2) = -2 log cosh(u) is smooth on the real line, but its poles at
    u = +-i pi/2 come close to the real axis once std is large, where a Gauss-Hermite rule
    in the standardised variable converges slowly (3.7e-3 nats off with 128 nodes at std e^2).
    So two rules, each where it converges fast:
    - std <= 1: Gauss-Hermite, E f(u) = pi^-1/2 sum_k w_k f(mean + sqrt(2) std x_k);
    - std > 1: -2 log cosh u = 2 log 2 - 2|u| - 2 log(1 + e^{-2|u|}). E|u| has a closed form
      (the folded normal's mean); the last term is even, smooth on u >= 0 and gone by u = 16,
      so it is integrated over [0, 16] against the folded density N(u; m, s) + N(-u; m, s)
      with Gauss-Legendre nodes.
    """
    hermite_x, hermite_w, fold_u, fold_w = quadrature_nodes(mean)
    std = log_std.exp()
    m, s = mean.unsqueeze(-1), std.unsqueeze(-1)
    narrow = log_one_minus_tanh_squared(torch.addcmul(m, s, hermite_x)) @ hermite_w
    # A trained policy has no dimension this wide (compiled, both rules: a program has no branch on data).
    if not torch.compiler.is_dynamo_compiling() and not bool((std > _WIDE).any()):
        return narrow
    s = torch.clamp(s, min=_WIDE)  # keeps the unused branch finite for narrow dimensions
    z = m / s
    mean_abs = s * math.sqrt(2.0 / math.pi) * torch.exp(-0.5 * z * z) + m * torch.erf(z / math.sqrt(2.0))
    folded_density = (torch.exp(-0.5 * ((fold_u - m) / s) ** 2) + torch.exp(-0.5 * ((fold_u + m) / s) ** 2)) / s
    wide = 2.0 * LOG_2 - 2.0 * mean_abs.squeeze(-1) - 2.0 * (folded_density @ fold_w)
    return torch.where(std > _WIDE, wide, narrow)


def ask_condition(discrepancy: float, d_queue: Iterable[float]) -> bool:
    """Eq. 10, left: D(s) > max(D_queue). The agent is uncertain, so it asks."""
    return discrepancy > max(d_queue)


def respond_condition(entropy: float, e_queue: Iterable[float]) -> bool:
    """Eq. 10, right: E(s) < min(E_queue). The state is important, so the expert responds."""
    return entropy < min(e_queue)
