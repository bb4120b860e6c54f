"""nodes/person_wheel.py without a graph: what it says on learner/advice_request and learner/driver."""

import logging

import numpy as np
import pytest

from eqhrl_interfaces.msg import AdviceRequest as AdviceRequestMsg
from eqhrl_ros.core.algorithm.learner import EQSACLearner, LearnerConfig
from eqhrl_ros.core.envs.spec import EnvSpec
from eqhrl_ros.nodes.person_wheel import PersonWheel


def wheel_and_learner(**config):
    learner = EQSACLearner(3, [-2.0], [2.0], LearnerConfig(mode='random', random_ask_rate=1.0, hidden=(8, 8), **config))
    said, drivers = [], []
    return PersonWheel(learner, 0.0, said.append, drivers.append, logging.getLogger('test')), learner, said, drivers


def pace(max_steps, rate_hz):
    return EnvSpec('Pendulum-v1', 3, [-2.0], [2.0], max_episode_steps=max_steps, realtime=True, rate_hz=rate_hz)


def test_the_countdown_never_promises_more_than_the_episode_or_the_budget_has():
    wheel, learner, said, drivers = wheel_and_learner(wheel_take_s=4.0)
    proposal = learner.propose(np.zeros(3, np.float32))
    wheel.ask(proposal, 100.0, env_step=90, pace=pace(100, 10.0))  # 10 steps of 0.1 s left
    assert said[-1].outcome == AdviceRequestMsg.PENDING and said[-1].wheel
    assert said[-1].timeout_s == pytest.approx(1.0)
    wheel.open = None
    learner.set_advising_budget_s(2.5)
    wheel.ask(proposal, 100.0, env_step=0, pace=pace(0, 0.0))  # the episode's length unknown: the budget cuts
    assert said[-1].timeout_s == pytest.approx(2.5)
    assert drivers == ['learner']  # said once, at the start, and on each change only


def test_a_stretch_is_said_taken_and_given_and_who_drives_follows():
    wheel, learner, said, drivers = wheel_and_learner(wheel_agree_steps=0)
    proposal = learner.propose(np.zeros(3, np.float32))
    wheel.ask(proposal, 10.0, 0, pace(0, 0.0))
    wheel.heard(np.array([1.0], np.float32), True, False, 10.5)  # pressed after the alert
    action, advised, source = wheel.turn(proposal, 10.5)
    assert action.tolist() == [1.0] and advised and source == 'asked'
    assert said[-1].outcome == AdviceRequestMsg.TAKEN and drivers[-1] == 'person_asked'
    wheel.heard(np.array([1.0], np.float32), False, False, 10.6)
    action, advised, source = wheel.turn(proposal, 10.6)
    assert source == 'learner' and not advised and action.tolist() == proposal.action.tolist()
    assert said[-1].outcome == AdviceRequestMsg.GIVEN and said[-1].detail == 'released' and said[-1].human
    assert said[-1].response_time_s == pytest.approx(0.6) and drivers[-1] == 'learner'
    assert learner.episode_advice.given == 1 and learner.human_time_total_s == pytest.approx(0.6)
