"""The scores of the novelty and advice_gain gates (extensions; core/algorithm/state_scores.py)."""

import numpy as np
import pytest
import torch

from eqhrl_ros.core.algorithm.advising import AdvisingGates
from eqhrl_ros.core.algorithm.learner import EQSACLearner, LearnerConfig
from eqhrl_ros.core.algorithm.state_scores import StateScores
from eqhrl_ros.core.data.advice import Advice


def test_novelty_is_large_far_from_the_states_seen_and_small_among_them():
    rng = np.random.default_rng(0)
    scores = StateScores(2, neighbours=5, memory=500, device='cpu')
    assert scores.novelty(torch.zeros(2)) is None  # nothing seen yet
    for point in rng.normal(0.0, 1.0, (400, 2)):
        scores.observe(torch.tensor(point, dtype=torch.float32))
    near, far = scores.novelty(torch.zeros(2)), scores.novelty(torch.tensor([6.0, 6.0]))
    assert far > 10 * near


def test_the_memory_keeps_the_latest_states_only():
    scores = StateScores(1, neighbours=1, memory=3, device='cpu')
    for value in (100.0, 0.0, 1.0, 2.0):  # 100 falls out
        scores.observe(torch.tensor([value]))
    assert len(scores.seen) == 3 and 100.0 not in scores.seen.states[:, 0].tolist()


def test_advice_gain_predicts_the_change_answers_made_nearby():
    scores = StateScores(1, neighbours=3, memory=100, device='cpu')
    for value in np.linspace(-1, 1, 50):
        scores.observe(torch.tensor([value], dtype=torch.float32))
    assert scores.advice_gain(torch.tensor([0.0])) is None  # too few answers
    for value in (-0.9, -0.8, -0.7):
        scores.answered_with(torch.tensor([value]), 0.05)  # the expert agreed there
    for value in (0.7, 0.8, 0.9):
        scores.answered_with(torch.tensor([value]), 1.5)  # the expert changed the action a lot
    assert scores.advice_gain(torch.tensor([0.8])) > 1.0 > 0.1 > scores.advice_gain(torch.tensor([-0.8]))


def test_a_scored_gate_asks_above_its_queue_and_tunes_its_threshold_to_the_target_rate():
    gates = AdvisingGates('novelty', advising_budget=10, gate_target_rate=0.1, score_queue_length=50)
    for score in range(50):
        assert not gates.decide(0, score=float(score)).fire  # the queue filling
    decision = gates.decide(0, score=99.0)
    assert decision.fire and decision.score == 99.0 and 'ranks' in decision.reason
    rng = np.random.default_rng(1)
    fired = [gates.decide(0, score=float(s)).fire for s in rng.normal(size=3000)]
    assert np.mean(fired[1000:]) == pytest.approx(0.1, abs=0.04)
    assert not gates.decide(10, score=100.0).fire  # outside Eq. 7's budget


def test_advice_gain_asks_by_chance_until_it_has_answers_and_learns_from_them():
    config = LearnerConfig(
        mode='advice_gain', gate_target_rate=1.0, hidden=(8, 8), gate_neighbours=2, gate_score_queue=2
    )
    learner = EQSACLearner(3, [-2.0], [2.0], config)
    proposal = learner.propose(np.zeros(3, np.float32))
    assert proposal.decision.fire and np.isnan(proposal.decision.score)  # by chance: nothing to score from
    for x in (0.1, 0.2):
        proposal = learner.propose(np.full(3, x, np.float32))
        learner.resolve_advice(proposal, Advice(np.asarray([2.0], np.float32)))
    assert len(learner.scores.answered) >= 2
    scored = learner.propose(np.full(3, 0.15, np.float32))
    assert not np.isnan(scored.decision.score)
