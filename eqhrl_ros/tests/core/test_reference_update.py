"""The optimised update computes the paper's maths: checked against a plain reference.

The learner's update is tuned for speed (fused Adam, numpy's tanh, the twin critics
as one batched network, both Eq. 4 targets in one pass, packed replay rows). The
reference below is the straightforward version, written from the equations with
plain torch ops on the same weights, the default (unfused) Adam, the same random
streams and the paper's order: critic step on D, critic step on D_advising, actor,
temperature, target critics. After several updates both must hold the same weights.
"""

import math

import numpy as np
import torch
import torch.nn.functional as F

from eqhrl_ros.core import EQSACLearner, LearnerConfig
from eqhrl_ros.core.networks import LOG_STD_MAX, LOG_STD_MIN


def actor_forward(layers, obs):
    """layers: the actor's (weight, bias) pairs. Tanh hidden layers, then the mean and log-std heads."""
    h = obs
    for weight, bias in layers[:-1]:
        h = torch.tanh(F.linear(h, weight, bias))
    mean, raw = F.linear(h, *layers[-1]).chunk(2, dim=-1)
    return mean, LOG_STD_MIN + 0.5 * (LOG_STD_MAX - LOG_STD_MIN) * (torch.tanh(raw) + 1.0)


def sample(mean, log_std, noise):
    u = mean + log_std.exp() * noise
    a = torch.tanh(u)
    normal = torch.distributions.Normal(mean, log_std.exp())
    return a, (normal.log_prob(u) - torch.log(1 - a.pow(2) + 1e-12)).sum(-1)


def critic_forward(critics, obs, action, k):
    """Critic k (0 or 1): its (weight, bias) pairs as an ordinary ReLU MLP."""
    h = torch.cat([obs, action], -1)
    layers = critics[k]
    for i, (weight, bias) in enumerate(layers):
        h = h @ weight + bias
        if i < len(layers) - 1:
            h = torch.relu(h)
    return h.squeeze(-1)


def parameters(critics):
    return [t for critic in critics for layer in critic for t in layer]


def reference_update(ref, learner, gamma=0.99, tau=0.005):
    """One EQSAC update, Algorithm 1, written out plainly. ``ref`` holds copies of the
    learner's tensors (as leaf tensors) and its own plain Adam optimisers."""
    cfg = learner.config
    rng = ref['rng']
    batch = learner.replay.sample(cfg.batch_size, rng['replay'])
    advice = learner.advice_replay.sample(
        cfg.batch_size, rng['replay'], replacement=len(learner.advice_replay) < cfg.batch_size
    )
    alpha = ref['log_alpha'].detach().exp()

    def target(b):  # Eq. 4
        with torch.no_grad():
            mean, log_std = actor_forward(ref['actor'], b.next_obs)
            noise = torch.randn(mean.shape, generator=rng['update'])
            a, logp = sample(mean, log_std, noise)
            q = torch.min(
                critic_forward(ref['target'], b.next_obs, a, 0), critic_forward(ref['target'], b.next_obs, a, 1)
            )
            return b.reward + gamma * (1 - b.terminated) * (q - alpha * logp)

    y, y_advice = target(batch), target(advice)
    for b, yb in ((batch, y), (advice, y_advice)):  # Eq. 5 on D, then on D_advising
        loss = sum(F.mse_loss(critic_forward(ref['critic'], b.obs, b.action, k), yb) for k in (0, 1))
        ref['critic_opt'].zero_grad()
        loss.backward()
        ref['critic_opt'].step()

    mean, log_std = actor_forward(ref['actor'], batch.obs)  # Eq. 6
    noise = torch.randn(mean.shape, generator=rng['update'])
    a, logp = sample(mean, log_std, noise)
    q = torch.min(critic_forward(ref['critic'], batch.obs, a, 0), critic_forward(ref['critic'], batch.obs, a, 1))
    actor_loss = (alpha * logp - q).mean()
    ref['actor_opt'].zero_grad()
    actor_loss.backward(inputs=[t for layer in ref['actor'] for t in layer])
    ref['actor_opt'].step()
    alpha_loss = -(ref['log_alpha'].exp() * (logp.detach() - learner.action_dim)).mean()
    ref['alpha_opt'].zero_grad()
    alpha_loss.backward()
    ref['alpha_opt'].step()
    with torch.no_grad():
        for value, online in zip(parameters(ref['target']), parameters(ref['critic'])):
            value.mul_(1 - tau).add_(tau * online)


def leaves(layers, grad=True):
    return [tuple(t.detach().clone().requires_grad_(grad) for t in layer) for layer in layers]


def test_optimised_update_matches_the_plain_reference():
    torch.manual_seed(0)
    learner = EQSACLearner(
        3, [-2.0], [2.0], LearnerConfig(mode='eqsac', hidden=(64, 64), batch_size=32, learning_starts=10**9, seed=5)
    )
    rng = np.random.default_rng(0)
    for i in range(200):
        obs, next_obs = rng.standard_normal(3), rng.standard_normal(3)
        learner.replay.add(obs, rng.uniform(-1, 1, 1), rng.standard_normal(), next_obs, i % 50 == 49)
        if i % 10 == 0:
            learner.advice_replay.add(obs, rng.uniform(-1, 1, 1), rng.standard_normal(), next_obs, False)

    cfg = learner.config
    ref = {
        'actor': leaves(learner.actor.linear_layers()),
        'critic': [leaves(learner.critic.linear_layers(k)) for k in (0, 1)],
        'target': [leaves(learner.critic_target.linear_layers(k), grad=False) for k in (0, 1)],
        'log_alpha': learner.log_alpha.detach().clone().requires_grad_(True),
        'rng': {name: torch.Generator() for name in learner.rng},
    }
    for name, gen in learner.rng.items():
        ref['rng'][name].set_state(gen.get_state())
    ref['actor_opt'] = torch.optim.Adam([t for layer in ref['actor'] for t in layer], lr=cfg.actor_lr, foreach=False)
    ref['critic_opt'] = torch.optim.Adam(parameters(ref['critic']), lr=cfg.critic_lr, foreach=False)
    ref['alpha_opt'] = torch.optim.Adam([ref['log_alpha']], lr=cfg.alpha_lr, foreach=False)

    replay_state = learner.replay.state_dict()  # sampling must not change the buffers
    for _ in range(5):
        reference_update(ref, learner)
        learner.update()

    def close(ours, reference, what):
        for i, (a, b) in enumerate(zip(ours, reference)):
            torch.testing.assert_close(a.detach(), b.detach(), rtol=1e-4, atol=1e-5, msg=f'{what} tensor {i}')

    close(
        [t for layer in learner.actor.linear_layers() for t in layer],
        [t for layer in ref['actor'] for t in layer],
        'actor',
    )
    close(parameters([learner.critic.linear_layers(k) for k in (0, 1)]), parameters(ref['critic']), 'critic')
    close(parameters([learner.critic_target.linear_layers(k) for k in (0, 1)]), parameters(ref['target']), 'target')
    assert math.isclose(float(learner.log_alpha.detach()), float(ref['log_alpha'].detach()), rel_tol=1e-5)
    # The weights moved: a no-op update would not pass for the wrong reason.
    untrained = EQSACLearner(3, [-2.0], [2.0], LearnerConfig(mode='eqsac', hidden=(64, 64), seed=5))
    assert not torch.allclose(ref['critic'][0][1][0], untrained.critic.linear_layers(0)[1][0])
    torch.testing.assert_close(learner.replay.state_dict()['obs'], replay_state['obs'])
