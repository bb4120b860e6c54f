"""The paper's equations against hand computations and numerical integration."""

import math

import pytest
import torch
from scipy import integrate, stats

from eqhrl_ros.core import equations as eq
from eqhrl_ros.core.networks import TwinCritic


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


@pytest.mark.parametrize('mu,sigma', [(0.0, 0.5), (0.3, 0.8), (-1.2, 1.5), (2.0, 0.2)])
def test_entropy_estimator_eq9_matches_numerical_integration(mu, sigma):
    """E(s) = -int p(a) log p(a) da over a in (-1, 1), p the density of tanh(N(mu, sigma^2))."""

    def density(a):
        u = math.atanh(a)
        return stats.norm(mu, sigma).pdf(u) / (1 - a * a)

    def integrand(a):
        p = density(a)
        return -p * math.log(p) if p > 0 else 0.0

    reference, _ = integrate.quad(integrand, -1 + 1e-12, 1 - 1e-12, limit=400, points=[math.tanh(mu)])
    generator = torch.Generator().manual_seed(0)
    # 200k draws: the Monte Carlo standard error stays below 0.007 even for sigma = 1.5.
    noise = torch.randn((200_000, 1, 1), generator=generator, dtype=torch.float64)
    estimate = eq.policy_entropy(
        torch.tensor([[mu]], dtype=torch.float64), torch.tensor([[math.log(sigma)]], dtype=torch.float64), noise
    )
    assert float(estimate) == pytest.approx(reference, abs=0.03)


def test_entropy_is_additive_over_action_dimensions():
    mean = torch.tensor([[0.1, -0.4]])
    log_std = torch.tensor([[-0.5, 0.2]])
    noise = torch.randn((4000, 1, 2), generator=torch.Generator().manual_seed(1))
    joint = eq.policy_entropy(mean, log_std, noise)
    parts = sum(
        float(eq.policy_entropy(mean[:, i : i + 1], log_std[:, i : i + 1], noise[..., i : i + 1])) for i in range(2)
    )
    assert float(joint) == pytest.approx(parts, rel=1e-5)


def test_sharper_policy_has_lower_entropy():
    noise = torch.randn((256, 1, 1), generator=torch.Generator().manual_seed(2))
    wide = eq.policy_entropy(torch.zeros(1, 1), torch.zeros(1, 1), noise)
    narrow = eq.policy_entropy(torch.zeros(1, 1), torch.full((1, 1), -2.0), noise)
    assert float(narrow) < float(wide)


def test_discrepancy_eq8_and_budget_eq7():
    assert eq.q_discrepancy(torch.tensor(1.5), torch.tensor(-0.5)).item() == pytest.approx(2.0)
    assert eq.early_advising(29, 30) and not eq.early_advising(30, 30)
    assert not eq.early_advising(0, 0)


def test_eq10_comparisons_are_strict():
    assert eq.ask_condition(2.0, [1.0, 1.9]) and not eq.ask_condition(2.0, [2.0, 1.0])
    assert eq.respond_condition(0.5, [0.6, 1.0]) and not eq.respond_condition(0.6, [0.6, 1.0])
