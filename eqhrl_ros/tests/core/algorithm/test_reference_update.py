"""Every update path computes the paper's maths: each checked against a plain reference,
for every mode and option.

The update (update.algorithm1_update) is tuned for speed (fused Adam, numpy's tanh, the twin
critics as one batched network, both Eq. 4 targets in one pass, packed replay rows) and runs
three ways: eagerly, compiled (compile_update) and for stacked seeds (StackedSeeds). The
reference below is the straightforward version, written from the equations with plain
torch ops on the same weights, the default (unfused) Adam, the same random streams and the
paper's order: critic step on D, critic step on D_advising, actor and temperature (and again
on advice with actor_on_advice), target critics. After several updates both must hold the
same weights, to float rounding.
"""

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from eqhrl_ros.core import EQSACLearner, LearnerConfig
from eqhrl_ros.core.algorithm.config import MODES, asks_for_advice
from eqhrl_ros.core.algorithm.networks import LOG_STD_MAX, LOG_STD_MIN
from eqhrl_ros.core.algorithm.stacked_seeds import StackedSeeds, batchable
from eqhrl_ros.core.algorithm.update import refusal


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
    # log(1 - tanh(u)^2) in its stable form: 1 - a^2 rounds to 0 in float32 once |u| > 9.
    return a, (normal.log_prob(u) - 2 * (math.log(2.0) - u - F.softplus(-2 * u))).sum(-1)


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
    """One update of Algorithm 1, written out plainly. ``ref`` holds copies of the learner's
    tensors (as leaf tensors) and its own plain Adam optimisers; the options are the learner's."""
    cfg = learner.config
    rng = ref['rng']
    batch = learner.replay.sample(cfg.batch_size, rng['replay'])
    advice = None
    if asks_for_advice(cfg.mode) and len(learner.advice_replay) > 0:
        size = cfg.batch_size
        if cfg.advice_batch == 'proportional':
            size = max(1, round(cfg.batch_size * len(learner.advice_replay) / len(learner.replay)))
        advice = learner.advice_replay.sample(size, rng['replay'], replacement=len(learner.advice_replay) < size)
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

    steps = [(batch, target(batch))] + ([(advice, target(advice))] if advice is not None else [])
    for b, yb in steps:  # Eq. 5 on D, then on D_advising
        loss = sum(F.mse_loss(critic_forward(ref['critic'], b.obs, b.action, k), yb) for k in (0, 1))
        ref['critic_opt'].zero_grad()
        loss.backward()
        ref['critic_opt'].step()

    def actor_and_alpha(b):  # Eq. 6, then the temperature
        alpha = ref['log_alpha'].detach().exp()
        mean, log_std = actor_forward(ref['actor'], b.obs)
        noise = torch.randn(mean.shape, generator=rng['update'])
        a, logp = sample(mean, log_std, noise)
        q = torch.min(critic_forward(ref['critic'], b.obs, a, 0), critic_forward(ref['critic'], b.obs, a, 1))
        actor_loss = (alpha * logp - q).mean()
        ref['actor_opt'].zero_grad()
        actor_loss.backward(inputs=[t for layer in ref['actor'] for t in layer])
        ref['actor_opt'].step()
        alpha_loss = -(ref['log_alpha'].exp() * (logp.detach() - learner.action_dim)).mean()
        ref['alpha_opt'].zero_grad()
        alpha_loss.backward()
        ref['alpha_opt'].step()

    actor_and_alpha(batch)
    if cfg.actor_on_advice and advice is not None:
        actor_and_alpha(advice)
    with torch.no_grad():
        for value, online in zip(parameters(ref['target']), parameters(ref['critic'])):
            value.mul_(1 - tau).add_(tau * online)


def leaves(layers, grad=True):
    return [tuple(t.detach().clone().requires_grad_(grad) for t in layer) for layer in layers]


def filled_learner(seed=5, advised_every=10, **options) -> EQSACLearner:
    learner = EQSACLearner(
        3,
        [-2.0],
        [2.0],
        LearnerConfig(**{'hidden': (32, 32), 'batch_size': 32, 'learning_starts': 10**9, 'seed': seed, **options}),
    )
    rng = np.random.default_rng(seed)
    for i in range(200):
        obs, next_obs = rng.standard_normal(3), rng.standard_normal(3)
        learner.replay.add(obs, rng.uniform(-1, 1, 1), rng.standard_normal(), next_obs, i % 50 == 49)
        if advised_every and i % advised_every == 0:
            learner.advice_replay.add(obs, rng.uniform(-1, 1, 1), rng.standard_normal(), next_obs, False)
    return learner


def reference_of(learner) -> dict:
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
    return ref


# Two correct paths part where float rounding tips a pre-activation across ReLU's kink: that
# sample's gradient through the unit is there in one path and not in the other, and Adam carries
# the difference on (docs/performance.md). It touches a few weights, by at most about the steps'
# size (lr per update); a wrong update moves many. So a tensor holds the reference when all but
# MAX_KINKED of its values are within rounding, and those within KINK_ATOL.
MAX_KINKED = 0.001
KINK_ATOL = 2e-3


def assert_holds_the_reference(learner, ref, what=''):
    def close(ours, reference, part):
        for i, (a, b) in enumerate(zip(ours, reference)):
            a, b = a.detach(), b.detach()
            within = torch.isclose(a, b, rtol=1e-4, atol=1e-5)
            message = f'{what} {part} tensor {i}: {int((~within).sum())} of {a.numel()} apart'
            assert (~within).float().mean() <= MAX_KINKED, message
            torch.testing.assert_close(a, b, rtol=0.0, atol=KINK_ATOL, msg=message)

    close(
        [t for layer in learner.actor.linear_layers() for t in layer],
        [t for layer in ref['actor'] for t in layer],
        'actor',
    )
    close(parameters([learner.critic.linear_layers(k) for k in (0, 1)]), parameters(ref['critic']), 'critic')
    close(parameters([learner.critic_target.linear_layers(k) for k in (0, 1)]), parameters(ref['target']), 'target')
    assert math.isclose(float(learner.log_alpha.detach()), float(ref['log_alpha'].detach()), rel_tol=1e-5), what
    # The random streams were drawn as the reference drew them.
    for name in ('replay', 'update'):
        assert torch.equal(learner.rng[name].get_state(), ref['rng'][name].get_state()), (what, name)


# Every option of the update, each alone (a mode only decides whether D_advising is used).
OPTIONS = [{'mode': mode} for mode in MODES] + [
    {'mode': 'eqsac', 'actor_on_advice': True},
    {'mode': 'eqsac', 'advice_batch': 'proportional'},
    {'mode': 'qasac', 'dual_replay': False},  # D_advising stays empty: no second critic step
]


def option_id(options):
    return ','.join(f'{k}={v}' for k, v in options.items())


@pytest.mark.parametrize('options', OPTIONS, ids=option_id)
def test_the_eager_update_matches_the_plain_reference(options):
    learner = filled_learner(advised_every=0 if options.get('dual_replay') is False else 10, **options)
    ref = reference_of(learner)
    replay_state = learner.replay.state_dict()  # sampling must not change the buffers
    for _ in range(5):
        reference_update(ref, learner)
        learner.update()
    assert_holds_the_reference(learner, ref, option_id(options))
    # The weights moved: a no-op update would not pass for the wrong reason.
    untrained = EQSACLearner(3, [-2.0], [2.0], LearnerConfig(mode='eqsac', hidden=(32, 32), seed=5))
    assert not torch.allclose(ref['critic'][0][1][0], untrained.critic.linear_layers(0)[1][0])
    torch.testing.assert_close(learner.replay.state_dict()['obs'], replay_state['obs'])


@pytest.mark.parametrize('options', OPTIONS, ids=option_id)
def test_seeds_together_match_each_seeds_plain_reference(options):
    # Seed 0 without advice (no second critic step), seeds 1 and 2 with some.
    learners = [filled_learner(seed, advised_every=every, **options) for seed, every in ((5, 0), (6, 9), (7, 4))]
    why = batchable(learners)
    if options.get('advice_batch') == 'proportional':  # refused, in one place: update.refusal
        assert why == refusal(learners[0].config, 'stacked') and 'proportional' in why
        with pytest.raises(ValueError, match='proportional'):
            StackedSeeds(learners)
        return
    refs = [reference_of(learner) for learner in learners]
    together = StackedSeeds(learners)
    for _ in range(5):
        for ref, learner in zip(refs, learners):
            reference_update(ref, learner)
        together.update()
    together.release()
    for seed, (learner, ref) in enumerate(zip(learners, refs)):
        assert learner.updates == 5
        assert_holds_the_reference(learner, ref, f'{option_id(options)} seed {seed}')


@pytest.mark.slow  # the compiler, once per option
@pytest.mark.parametrize(
    'options',
    [{'mode': 'sac'}, {'mode': 'eqsac', 'actor_on_advice': True}, {'mode': 'qasac', 'dual_replay': False}],
    ids=option_id,
)
def test_the_compiled_update_matches_the_plain_reference(options):
    learner = filled_learner(
        advised_every=0 if options.get('dual_replay') is False else 10, compile_update=True, **options
    )
    learner.log = None
    # The update alone: what this test checks (acting ahead has tests of its own, in
    # test_compiled_update.py). Its program is then SAC's for every option without an advice
    # batch, which inductor's cache compiles once: about 17 s less with an empty cache.
    learner.updater.ahead.enabled = False
    ref = reference_of(learner)
    learner.updater.make_optimizers()
    compiled = learner.start_compiling(background=False)
    assert compiled.ready, compiled.failed
    for _ in range(5):
        reference_update(ref, learner)
        learner.update()
    assert_holds_the_reference(learner, ref, option_id(options))


def test_an_option_no_compiled_program_can_hold_is_refused_in_one_place():
    learner = filled_learner(mode='eqsac', advice_batch='proportional', compile_update=True)
    assert learner.start_compiling() is None and learner.compiled_update is None and learner.updater.compile_refused
    assert 'proportional' in refusal(learner.config, 'compiled')
    ref = reference_of(learner)
    for _ in range(3):  # it stays eager, and right
        reference_update(ref, learner)
        learner.update()
    assert_holds_the_reference(learner, ref, 'proportional')
