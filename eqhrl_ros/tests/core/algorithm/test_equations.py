"""The paper's equations against hand computations and numerical integration."""

import math

import numpy as np
import pytest
import torch
from scipy import integrate, special, stats

from eqhrl_ros.core.algorithm import equations as eq
from eqhrl_ros.core.algorithm.networks import TwinCritic


def test_bellman_target_eq4_matches_hand_computation_on_tiny_network():
    torch.manual_seed(0)
    critic = TwinCritic(obs_dim=1, action_dim=1, hidden=(2,))
    with torch.no_grad():
        # Q1(s,a) = relu(s + a) * 1; Q2(s,a) = relu(2s) * 3 (+ biases 0.5 and -1)
        critic.weights[0][0] = torch.tensor([[1.0, 0.0], [1.0, 0.0]])
        critic.weights[0][1] = torch.tensor([[2.0, 0.0], [0.0, 0.0]])
        critic.biases[0].zero_()
        critic.weights[1][0] = torch.tensor([[1.0], [0.0]])
        critic.weights[1][1] = torch.tensor([[3.0], [0.0]])
        critic.biases[1][0] = 0.5
        critic.biases[1][1] = -1.0
    s_next = torch.tensor([[1.0], [2.0]])
    a_next = torch.tensor([[0.5], [-0.5]])
    q1, q2 = critic(s_next, a_next)
    assert q1.tolist() == pytest.approx([2.0, 2.0])  # relu(1.5)+0.5, relu(1.5)+0.5
    assert q2.tolist() == pytest.approx([5.0, 11.0])  # 3*2-1, 3*4-1
    reward = torch.tensor([1.0, -2.0])
    terminated = torch.tensor([0.0, 1.0])
    log_prob = torch.tensor([-0.3, 0.7])
    y = eq.soft_bellman_target(reward, terminated, q1, q2, log_prob, alpha=0.2, gamma=0.9)
    # y0 = 1 + 0.9 * (min(2, 5) - 0.2 * -0.3) = 1 + 0.9 * 2.06; y1 terminal = -2
    assert y.tolist() == pytest.approx([1.0 + 0.9 * 2.06, -2.0])


def test_critic_loss_eq5_is_mean_squared_error():
    q = torch.tensor([1.0, 2.0, 4.0])
    y = torch.tensor([0.0, 2.0, 1.0])
    assert float(eq.critic_loss(q, y)) == pytest.approx((1 + 0 + 9) / 3)


def test_actor_loss_eq6_uses_the_smaller_critic():
    log_prob = torch.tensor([-1.0, 0.5])
    q1 = torch.tensor([3.0, -1.0])
    q2 = torch.tensor([2.0, 4.0])
    loss = eq.actor_loss(log_prob, q1, q2, alpha=0.5)
    assert float(loss) == pytest.approx(((0.5 * -1 - 2) + (0.5 * 0.5 - -1)) / 2)


def test_soft_update_moves_targets_by_tau():
    target = [torch.zeros(3)]
    online = [torch.ones(3) * 10]
    eq.soft_update(target, online, tau=0.1)
    assert target[0].tolist() == pytest.approx([1.0] * 3)


def test_log_one_minus_tanh_squared_is_stable_and_exact():
    u = torch.tensor([-30.0, -3.0, 0.0, 0.7, 30.0], dtype=torch.float64)
    stable = eq.log_one_minus_tanh_squared(u)
    assert torch.isfinite(stable).all()
    naive = torch.log(1 - torch.tanh(u[1:4]) ** 2)
    assert stable[1:4].tolist() == pytest.approx(naive.tolist(), rel=1e-9)


def test_squashed_log_prob_matches_change_of_variables():
    mean, log_std = torch.tensor([[0.3]]), torch.tensor([[math.log(0.8)]])
    noise = torch.tensor([[0.4]])
    a, log_prob = eq.squashed_gaussian_sample(mean, log_std, noise)
    u = 0.3 + 0.8 * 0.4
    expected = stats.norm(0.3, 0.8).logpdf(u) - math.log(1 - math.tanh(u) ** 2)
    assert float(a) == pytest.approx(math.tanh(u))
    assert float(log_prob) == pytest.approx(expected, rel=1e-5)


def _entropy_by_integration(mu: float, sigma: float) -> float:
    """E(s) = -int p(a) log p(a) da over a in (-1, 1), p the density of tanh(N(mu, sigma^2))."""

    def density(a):
        u = math.atanh(a)
        return stats.norm(mu, sigma).pdf(u) / (1 - a * a)

    def integrand(a):
        p = density(a)
        return -p * math.log(p) if p > 0 else 0.0

    return integrate.quad(integrand, -1 + 1e-12, 1 - 1e-12, limit=400, points=[math.tanh(mu)])[0]


def _t(*values) -> torch.Tensor:
    return torch.tensor([list(values)], dtype=torch.float64)


@pytest.mark.parametrize('mu,sigma', [(0.0, 0.5), (0.3, 0.8), (-1.2, 1.5), (2.0, 0.2)])
def test_eq9_exact_entropy_is_the_integral_over_actions(mu, sigma):
    """The definition of Eq. 9 integrated in action space, against the quadrature in u."""
    exact = eq.policy_entropy(_t(mu), _t(math.log(sigma)))
    assert float(exact) == pytest.approx(_entropy_by_integration(mu, sigma), abs=1e-6)


def test_expected_log_jacobian_is_exact_over_the_whole_log_std_range():
    """Against scipy's adaptive quadrature of E[log(1 - tanh(u)^2)] on a grid of means and
    log-stds spanning the actor's clamp [-5, 2] (both rules, and the switch between them)."""
    from eqhrl_ros.core.algorithm.networks import LOG_STD_MAX, LOG_STD_MIN

    def reference(mu, sigma):
        def f(u):
            return float(eq.log_one_minus_tanh_squared(torch.tensor(u, dtype=torch.float64))) * stats.norm.pdf(
                u, mu, sigma
            )

        return integrate.quad(f, mu - 40 * sigma, mu + 40 * sigma, points=sorted({0.0, mu}), limit=500)[0]

    means = [-9.0, -2.5, -0.4, 0.0, 0.7, 3.0, 10.0]
    log_stds = [LOG_STD_MIN, -2.0, -0.5, -0.01, 0.01, 0.6, 1.3, LOG_STD_MAX]
    grid = [(m, s) for m in means for s in log_stds]
    got = eq.expected_log_jacobian(
        torch.tensor([m for m, _ in grid], dtype=torch.float64), torch.tensor([s for _, s in grid], dtype=torch.float64)
    )
    want = [reference(m, math.exp(s)) for m, s in grid]
    assert got.tolist() == pytest.approx(want, abs=1e-7)


@pytest.mark.parametrize('mu,log_std', [(0.0, 2.0), (0.5, 0.0), (-1.5, -1.0), (3.0, 1.0), (0.2, -4.0)])
def test_eq9_exact_entropy_matches_a_million_samples(mu, log_std):
    """Brute force: a million stratified draws u_i = mu + sigma * Phi^-1((i + 1/2) / N) of the
    Jacobian term (error ~1e-6), within 1e-3 nats; and a million plain random draws within
    four of their standard errors."""
    n = 1_000_000
    sigma = math.exp(log_std)
    gaussian = 0.5 * math.log(2 * math.pi * math.e) + log_std
    u = mu + sigma * special.ndtri((np.arange(n) + 0.5) / n)
    jacobian = eq.log_one_minus_tanh_squared(torch.from_numpy(u)).numpy()
    exact = float(eq.policy_entropy(_t(mu), _t(log_std)))
    assert exact == pytest.approx(gaussian + jacobian.mean(), abs=1e-3)

    noise = torch.randn((n, 1, 1), generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    draws = eq.log_one_minus_tanh_squared(mu + sigma * noise).flatten()
    monte_carlo = float(eq.policy_entropy_monte_carlo(_t(mu), _t(log_std), noise))
    assert exact == pytest.approx(monte_carlo, abs=4 * float(draws.std()) / math.sqrt(n) + 1e-9)


def test_eq9_exact_entropy_is_deterministic_and_draws_nothing():
    mean, log_std = torch.tensor([[0.3, -1.1]]), torch.tensor([[-0.7, 1.6]])  # one narrow, one wide dim
    state = torch.random.get_rng_state()
    first = eq.policy_entropy(mean, log_std)
    assert torch.equal(torch.random.get_rng_state(), state)
    assert all(torch.equal(first, eq.policy_entropy(mean, log_std)) for _ in range(5))


def test_entropy_is_additive_over_action_dimensions():
    mean = torch.tensor([[0.1, -0.4]])
    log_std = torch.tensor([[-0.5, 1.2]])
    joint = eq.policy_entropy(mean, log_std)
    parts = sum(float(eq.policy_entropy(mean[:, i : i + 1], log_std[:, i : i + 1])) for i in range(2))
    assert float(joint) == pytest.approx(parts, rel=1e-5)
    noise = torch.randn((4000, 1, 2), generator=torch.Generator().manual_seed(1))
    joint = eq.policy_entropy_monte_carlo(mean, log_std, noise)
    parts = sum(
        float(eq.policy_entropy_monte_carlo(mean[:, i : i + 1], log_std[:, i : i + 1], noise[..., i : i + 1]))
        for i in range(2)
    )
    assert float(joint) == pytest.approx(parts, rel=1e-5)


def test_sharper_policy_has_lower_entropy():
    wide = eq.policy_entropy(torch.zeros(1, 1), torch.zeros(1, 1))
    narrow = eq.policy_entropy(torch.zeros(1, 1), torch.full((1, 1), -2.0))
    assert float(narrow) < float(wide)


def test_discrepancy_eq8_and_budget_eq7():
    assert eq.q_discrepancy(torch.tensor(1.5), torch.tensor(-0.5)).item() == pytest.approx(2.0)
    assert eq.early_advising(29, 30) and not eq.early_advising(30, 30)
    assert not eq.early_advising(0, 0)


def test_eq10_comparisons_are_strict():
    assert eq.ask_condition(2.0, [1.0, 1.9]) and not eq.ask_condition(2.0, [2.0, 1.0])
    assert eq.respond_condition(0.5, [0.6, 1.0]) and not eq.respond_condition(0.6, [0.6, 1.0])
