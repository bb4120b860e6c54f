"""Whether advice is open now has one home (core/algorithm/advice_window.py): the learner, its
gates, the acting node's health and the person's page all read it, and the budgets are stored once."""

import math

import pytest

from eqhrl_ros.core.algorithm.advice_window import AdviceBudget, advice_window
from eqhrl_ros.core.algorithm.config import LearnerConfig
from eqhrl_ros.core.algorithm.learner import EQSACLearner
from eqhrl_ros.core.data.advice import Advice


def test_the_window_closes_at_the_episode_budget_the_persons_seconds_or_a_mode_that_does_not_ask():
    open_now = advice_window('eqsac', 3, 0.0, 2, 100.0)
    assert open_now.open and open_now.episodes_left == 1 and math.isinf(open_now.seconds_left)
    over = advice_window('eqsac', 3, 0.0, 3, 0.0)
    assert not over.open and 'advising budget is used up' in over.why_closed and over.episodes_left == 0
    spent = advice_window('qasac', 30, 10.0, 0, 10.5)
    assert not spent.open and spent.seconds_left == 0.0 and "person's 10 s" in spent.why_closed
    assert advice_window('qasac', 30, 10.0, 0, 4.0).seconds_left == pytest.approx(6.0)
    sac = advice_window('sac', 30, 0.0, 0, 0.0)
    assert not sac.open and 'mode sac' in sac.why_closed
    assert sac.to_dict()['seconds_left'] is None  # JSON has no inf


def test_a_budget_set_on_the_learner_is_the_one_its_gates_and_its_window_read():
    learner = EQSACLearner(3, [-2.0], [2.0], LearnerConfig(mode='eqsac', advising_budget=5, hidden=(8, 8)))
    assert learner.gates.budget is learner.budget and learner.budget.config is learner.config
    learner.set_advising_budget(0)
    assert learner.config.advising_budget == 0 and learner.gates.advising_budget == 0
    assert not learner.advice_window().open and not learner.gates.needs_evaluation(0)
    assert not learner.propose([0.0, 0.0, 0.0]).decision.within_budget
    with pytest.raises(ValueError):
        learner.set_advising_budget(-1)
    assert learner.config.advising_budget == 0  # a refused value changes nothing


def test_the_persons_seconds_close_the_window_as_the_learner_counts_them():
    learner = EQSACLearner(3, [-2.0], [2.0], LearnerConfig(mode='eqsac', advising_budget_s=2.0, hidden=(8, 8)))
    assert learner.advice_window().seconds_left == 2.0
    proposal = learner.propose([0.0, 0.0, 0.0])
    learner.resolve_advice(proposal, Advice([0.5], human=True, response_time_s=1.5))
    assert learner.advice_window().seconds_left == pytest.approx(0.5)
    learner.resolve_advice(proposal, Advice([0.5], human=True, response_time_s=1.0))
    assert not learner.advice_window().open and learner.person_budget_left_s == 0.0


def test_gates_made_on_their_own_have_a_budget_of_their_own():
    budget = AdviceBudget(LearnerConfig(mode='qasac', advising_budget=2))
    assert budget.within_episodes(1) and not budget.within_episodes(2)
    budget.set_seconds(30.0)
    assert budget.seconds == 30.0 and budget.window(0, 30.0).why_closed
