"""Asking for the wheel (core/experts/wheel.py): taking it, driving, handing back, the person's
seconds, STOP; and the same protocol in simulated time (the in-process loop, a simulated person)."""

import math

import gymnasium as gym
import numpy as np
import pytest

from eqhrl_ros.core.algorithm.learner import EQSACLearner, LearnerConfig
from eqhrl_ros.core.envs.spec import ActionScaler
from eqhrl_ros.core.experts.controllers import PendulumSwingUpExpert
from eqhrl_ros.core.experts.simulated_human import HumanLimits, SimulatedHuman
from eqhrl_ros.core.experts.takeover import PersonCommand, heard
from eqhrl_ros.core.experts.wheel import MIN_REACTION_S, AskedWheel, WheelRules
from eqhrl_ros.core.runs.in_process import run_episode

SCALER = ActionScaler([-2.0], [2.0])


def person(value, deadman=True, at=10.0, pressed_at=10.5):
    return PersonCommand(np.asarray([value], np.float32), deadman, False, at, pressed_at)


def test_the_deadman_press_time_is_its_rising_edge():
    first = heard(None, [0.0], True, False, 1.0)
    held = heard(first, [0.5], True, False, 1.3)
    assert first.pressed_at == 1.0 and held.pressed_at == 1.0  # held on: the same press
    released = heard(held, [0.5], False, False, 1.4)
    again = heard(released, [0.5], True, False, 2.0)
    assert released.pressed_at == -math.inf and again.pressed_at == 2.0


def test_a_press_made_before_the_alert_never_takes_the_wheel():
    wheel = AskedWheel(10.0, WheelRules(take_s=4.0), SCALER)
    # The deadman held since before the alert (pressed at 9.0), and one pressed too soon to be a reaction.
    assert wheel.step(person(1.0, at=10.2, pressed_at=9.0), [0.0], 10.2).action is None
    too_soon = 10.0 + MIN_REACTION_S / 2
    assert wheel.step(person(1.0, at=too_soon, pressed_at=too_soon), [0.0], too_soon).action is None
    turn = wheel.step(person(1.5, at=10.6, pressed_at=10.5), [0.0], 10.6)
    assert turn.starts and turn.taken and turn.action[0] == 1.5 and wheel.taken


def test_while_waiting_the_learner_drives_and_an_untaken_request_times_out():
    wheel = AskedWheel(10.0, WheelRules(take_s=1.0), SCALER)
    waiting = wheel.step(None, [0.3], 10.5)
    assert waiting.action is None and not waiting.ended and abs(waiting.seconds - 0.5) < 1e-9
    ended = wheel.step(None, [0.3], 11.0)
    assert ended.ended == 'timeout' and not ended.taken and abs(ended.seconds - 0.5) < 1e-9


@pytest.mark.parametrize(
    'rules, commands, ended',
    [
        (WheelRules(agree_steps=0), [person(1.0, at=11.0), person(1.0, deadman=False, at=11.1)], 'released'),
        (WheelRules(agree_steps=0), [person(1.0, at=11.0), (person(1.0, at=11.0), 11.6)], 'released'),  # stale
        (
            WheelRules(max_s=0.15, agree_steps=0),
            [person(1.0, at=11.0), person(1.0, at=11.1), person(1.0, at=11.2)],
            'longest',
        ),
        (
            WheelRules(agree=0.1, agree_steps=2),
            [person(0.1, at=11.0), person(0.1, at=11.1), person(0.1, at=11.2)],
            'agreed',
        ),
    ],
)
def test_each_hand_back_rule_gives_the_wheel_back(rules, commands, ended):
    wheel = AskedWheel(10.0, rules, SCALER)
    steps = [c if isinstance(c, tuple) else (c, c.at) for c in commands]  # (command, when the step comes)
    turns = [wheel.step(c, [0.0], now) for c, now in steps]
    assert turns[0].starts and turns[-1].ended == ended and turns[-1].taken and turns[-1].action is None
    assert all(t.action is not None for t in turns[:-1])


def test_the_person_s_seconds_run_from_the_alert_to_the_hand_back_and_stop_within_the_budget():
    wheel = AskedWheel(10.0, WheelRules(agree_steps=0, max_s=0), SCALER)
    budget, spent, turns = 0.9, 0.0, []
    for t in (10.2, 10.4, 10.6, 10.8, 11.0):  # a step every 0.2 s; the deadman pressed at 10.3
        turn = wheel.step(person(1.0, at=t, pressed_at=10.3) if t > 10.3 else None, [0.0], t, budget - spent)
        spent += turn.seconds
        turns.append(turn)
        if turn.ended:
            break
    assert turns[1].starts and turns[0].seconds == pytest.approx(0.2)  # the reaction counts
    # Handed back at the last step before the one that would pass the budget: 0.8 s of 0.9.
    assert turns[-1].ended == 'budget' and len(turns) == 4 and spent == pytest.approx(0.8) and spent <= budget


def test_stop_pauses_the_request_and_its_countdown():
    wheel = AskedWheel(10.0, WheelRules(take_s=2.0), SCALER)
    wheel.step(None, [0.0], 10.5)
    wheel.pause(10.5)
    assert wheel.seconds_left(15.0) == pytest.approx(1.5)  # held at what was left
    late = wheel.step(None, [0.0], 16.0)  # a step already on its way when STOP came
    assert not late.ended and late.seconds == 0.0 and wheel.paused_at == 10.5
    wheel.resume(30.0)  # released 20 s later: nothing timed out, the stop is nobody's time
    turn = wheel.step(None, [0.0], 30.0)
    assert not turn.ended and turn.seconds == pytest.approx(0.0) and wheel.seconds_left(30.0) == pytest.approx(1.5)


def test_in_simulated_time_the_person_takes_the_wheel_drives_and_it_is_counted():
    config = LearnerConfig(
        mode='random',
        random_ask_rate=0.05,
        advice_protocol='wheel',
        learning_starts=10_000,
        seed=3,
        wheel_agree_steps=0,
        hidden=(16, 16),
    )
    env = gym.make('Pendulum-v1')
    learner = EQSACLearner(3, env.action_space.low, env.action_space.high, config)
    limits = HumanLimits(miss_probability=0.0, skip_probability=0.0, reaction_median_s=0.5, stretch_s=1.0)
    human = SimulatedHuman(PendulumSwingUpExpert(), limits, seed=1)
    summary = run_episode(env, learner, human, seed=0)
    assert summary.advice_asked >= 2 and summary.advice_given == summary.advice_human >= 1
    # Each taken request drives about stretch_s / 0.05 steps (less at the episode's end), all into D_advising.
    assert 1 <= summary.asked_steps <= summary.advice_given * 21
    assert len(learner.advice_replay) == summary.asked_steps
    # Seconds: the reaction and the stretch, counted step by step (0.05 s each).
    assert summary.human_time_s >= summary.asked_steps * 0.05 - 1e-6
    assert summary.human_time_total_s == pytest.approx(summary.human_time_s)


def test_in_process_the_wheel_needs_an_expert_that_can_take_it():
    config = LearnerConfig(mode='random', advice_protocol='wheel', hidden=(16, 16))
    env = gym.make('Pendulum-v1')
    learner = EQSACLearner(3, env.action_space.low, env.action_space.high, config)
    with pytest.raises(ValueError, match='take the wheel'):
        run_episode(env, learner, PendulumSwingUpExpert(), seed=0)
