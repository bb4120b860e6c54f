"""The learner is made of parts with one job each (core/algorithm/learner.py's docstring), and
both update paths, the lone learner's and stacked seeds', go through the same Updater interface:
each returns its losses and counts an update whose losses are not finite."""

import math

import numpy as np
import torch

from eqhrl_ros.core.algorithm.config import LearnerConfig
from eqhrl_ros.core.algorithm.learner import EQSACLearner
from eqhrl_ros.core.algorithm.stacked_seeds import StackedSeeds
from eqhrl_ros.core.algorithm.updater import non_finite

LOSSES = {'critic_loss', 'actor_loss', 'alpha_loss'}


def learner(seed=0, **extra):
    settings = {'mode': 'eqsac', 'hidden': (8, 8), 'batch_size': 8, 'learning_starts': 10, 'compile_update': False}
    config = LearnerConfig(**{**settings, **extra}, seed=seed)
    made = EQSACLearner(3, [-2.0], [2.0], config)
    rng = np.random.default_rng(seed)
    for i in range(12):  # fills D (a few advised: D_advising too), no update yet
        obs, next_obs = rng.normal(size=3), rng.normal(size=3)
        made.count_step(obs, [float(rng.uniform(-2, 2))], -1.0, next_obs, False, advised=i % 3 == 0)
    return made


def test_the_parts_hold_what_the_learner_shows():
    one = learner()
    assert one.actor is one.policy.actor and one.critic is one.critics.critic
    assert one.replay is one.memories.replay and one.advice_replay is one.memories.advice_replay
    assert one.log_alpha is one.updater.log_alpha and one.rng is one.streams
    assert one.ready_to_learn and len(one.advice_replay) == 4


def test_a_lone_update_returns_its_losses_and_counts_a_non_finite_one():
    one = learner()
    info = one.update()
    assert LOSSES | {'advice_critic_loss'} <= set(info) and not non_finite(info)
    assert one.updates == 1 and one.updater.non_finite_updates == 0
    with torch.no_grad():
        next(one.critic.parameters()).fill_(math.inf)  # a diverged critic
    info = one.update()
    assert 'critic_loss' in non_finite(info) and one.updater.non_finite_updates == 1 and one.updates == 2


def test_stacked_seeds_return_their_losses_and_count_each_seeds_update_as_a_lone_update_does():
    seeds = [learner(seed) for seed in (0, 1)]
    stacked = StackedSeeds(seeds)
    try:
        info = stacked.updates_after_a_step()[0]  # updates_per_step 1, D ready
        assert LOSSES | {'advice_critic_loss'} <= set(info) and not non_finite(info)
        assert len(info['alpha']) == 2 and all(s.updates == 1 for s in seeds)
        with torch.no_grad():
            stacked.critic.weights[0].fill_(math.nan)
        assert non_finite(stacked.update())
        assert [s.updater.non_finite_updates for s in seeds] == [1, 1]  # the stacked loss is the seeds' mean
    finally:
        stacked.release()


def test_the_updates_inputs_are_gathered_again_only_when_what_holds_them_changes():
    one = learner()
    updater = one.updater
    first = updater.inputs()
    assert updater.inputs() is first  # nothing changed: the same views, not gathered again
    actor_weight = next(one.actor.parameters())
    actor_weight.data = actor_weight.data.clone()  # new storage behind the same parameter (as stacked seeds do)
    second = updater.inputs()
    assert second is not first
    assert second[0]['actor'][next(iter(second[0]['actor']))].data_ptr() == actor_weight.data_ptr()
    one.load_state_dict(learner(seed=1).state_dict())  # a checkpoint: new networks and optimisers
    third = updater.inputs()
    assert third is not second
    assert all(
        view.data_ptr() == live.data_ptr()
        for view, live in zip(third[0]['critic'].values(), one.critic.parameters(), strict=True)
    )


def test_the_compiled_update_acts_ahead_only_where_the_gates_read_d_or_e():
    """SAC's eager acting is only the actor on one observation: its program does not act ahead
    (acting_ahead.py's measurement). A mode whose gates read D(s) or E(s) does, with the exact
    E(s) only where the gates use it (a Monte Carlo E(s) draws from its own stream, eagerly)."""
    obs_t = torch.zeros(1, 3)
    expected = {
        ('sac', 'exact'): None,
        ('random', 'exact'): None,
        ('qasac', 'exact'): (True, False),
        ('respond', 'exact'): (False, True),
        ('eqsac', 'exact'): (True, True),
        ('eqsac', 'monte_carlo'): (True, False),
    }
    for (mode, estimator), flags in expected.items():
        made = learner(mode=mode, entropy_estimator=estimator)
        ahead = made.updater.ahead.inputs(obs_t, 3)
        assert (ahead if ahead is None else tuple(ahead[2:])) == flags, (mode, estimator)
        if ahead is not None:  # its noise: the 'act' stream's next draw, made early
            assert made.streams.drawn_ahead('act') is ahead[1] and ahead[0] is obs_t
