"""A person as the expert, without ROS: the answer window of TeleopExpert, the simulated
person, and what the learner counts of a person's time."""

import math

import numpy as np
import pytest

from eqhrl_ros.core.algorithm.learner import EQSACLearner, LearnerConfig
from eqhrl_ros.core.data.advice import SKIPPED, Advice, AdviceRequest
from eqhrl_ros.core.experts.factory import make_expert
from eqhrl_ros.core.experts.simulated_human import HumanLimits, SimulatedHuman
from eqhrl_ros.core.experts.teleop import Command, TeleopExpert


def request(step=0, n=1):
    return AdviceRequest(
        np.zeros(3, np.float32), np.zeros(n, np.float32), -2 * np.ones(n, np.float32), 2 * np.ones(n, np.float32),
        1.0, -1.0, 0, step,
    )  # fmt: skip


class FakeClock:
    def __init__(self):
        self.now = 50.0

    def __call__(self):
        return self.now


def command(value, enabled=True, answer=False, skip=False):
    return Command(np.array([value], np.float32), enabled, '' if enabled else 'deadman released', answer, skip)


# ------------------------------------------------------------------ the answer window


def test_a_held_command_does_not_answer_a_request_a_changed_one_that_holds_still_does():
    clock = FakeClock()
    expert = TeleopExpert(name='person', clock=clock, answer_change=0.05)
    expert.update(command(0.5))
    expert.open(request())
    clock.now += 0.4
    assert expert.update(command(0.52)) is None  # the same stick position, re-published
    clock.now += 0.9
    assert expert.update(command(3.0)) is None  # the person moves: steering, not yet an answer
    clock.now += 0.3
    advice = expert.settled()  # held still for settle_s: the answer, clipped to the bounds
    assert advice.advised and advice.human and advice.action.tolist() == [2.0]
    assert advice.response_time_s == pytest.approx(1.6)
    assert expert.pending is None and expert.update(command(-1.0)) is None  # nothing open any more


def test_the_answer_button_answers_with_the_held_command_and_skip_declines():
    clock = FakeClock()
    expert = TeleopExpert(name='person', clock=clock)
    expert.update(command(0.5, answer=True))  # held before the request: not a press
    expert.open(request())
    assert expert.update(command(0.5, answer=True)) is None
    expert.update(command(0.5))
    clock.now += 0.7
    advice = expert.update(command(0.5, answer=True))  # pressed
    assert advice.advised and advice.action.tolist() == [0.5] and advice.response_time_s == pytest.approx(0.7)

    expert.open(request(1))
    clock.now += 0.2
    skipped = expert.update(command(0.5, skip=True))
    assert not skipped.advised and skipped.reason == SKIPPED and skipped.human and not skipped.timed_out
    assert skipped.response_time_s == pytest.approx(0.2)


def test_without_the_deadman_nothing_answers_and_pressing_it_does():
    clock = FakeClock()
    expert = TeleopExpert(name='person', clock=clock)
    expert.update(command(0.0, enabled=False))
    expert.open(request())
    clock.now += 0.2
    assert expert.update(command(1.0, enabled=False, answer=True)) is None
    clock.now += 0.8
    assert expert.update(command(1.0, enabled=True)) is None
    clock.now += 0.3
    advice = expert.update(command(1.0, enabled=True))  # the same command, re-sent, now settled
    assert advice.advised and advice.action.tolist() == [1.0] and advice.response_time_s == pytest.approx(1.3)


def test_silence_times_out_and_a_newer_request_supersedes_an_open_one():
    clock = FakeClock()
    expert = TeleopExpert(name='person', clock=clock)
    assert expert.expire(3.0) is None  # nothing open
    expert.open(request())
    late = expert.expire(3.0)
    assert late.timed_out and late.human and not late.advised and late.response_time_s == 3.0
    expert.open(request(1))
    clock.now += 0.3
    withdrawn = expert.withdraw('superseded by a newer request')
    assert not withdrawn.advised and not withdrawn.timed_out and withdrawn.response_time_s == pytest.approx(0.3)


def test_a_wrongly_sized_command_is_declined_when_the_person_answers():
    clock = FakeClock()
    expert = TeleopExpert(name='person', clock=clock, settle_s=0.0)
    expert.open(request(n=2))
    clock.now += 0.5
    advice = expert.update(command(1.0))
    assert not advice.advised and 'has 1 values' in advice.reason


# ------------------------------------------------------------------ the simulated person


def test_the_simulated_persons_draws_follow_its_limits():
    limits = HumanLimits(
        reaction_median_s=0.8, reaction_sigma=0.3, skip_probability=0.1, miss_probability=0.2, action_noise=0.5
    )
    human = SimulatedHuman(make_expert('heuristic', 'Pendulum-v1'), limits, seed=3)
    plans = [human.plan(request()) for _ in range(4000)]
    kinds = [p.kind for p in plans]
    assert kinds.count('miss') / 4000 == pytest.approx(0.2, abs=0.025)
    assert kinds.count('skip') / 4000 == pytest.approx(0.1, abs=0.02)
    delays = [p.delay_s for p in plans if p.kind != 'miss']
    assert np.median(delays) == pytest.approx(0.8, rel=0.05)
    assert np.std(np.log(delays)) == pytest.approx(0.3, rel=0.1)
    actions = np.array([p.action[0] for p in plans if p.kind == 'answer'])
    assert actions.min() >= -2.0 and actions.max() <= 2.0 and actions.std() > 0.3  # noisy, inside the bounds


def test_the_simulated_persons_outcome_respects_the_answer_window():
    human = SimulatedHuman(make_expert('heuristic', 'Pendulum-v1'), HumanLimits(answer_window_s=2.0), seed=0)
    from eqhrl_ros.core.experts.simulated_human import HumanPlan

    answer = HumanPlan('answer', 1.5, np.array([0.3], np.float32))
    assert human.outcome(answer).advised and human.outcome(answer).response_time_s == 1.5
    late = human.outcome(answer, window_s=1.0)
    assert late.timed_out and late.response_time_s == 1.0
    missed = human.outcome(HumanPlan('miss', math.inf))
    assert missed.timed_out and missed.response_time_s == 2.0
    skip = human.outcome(HumanPlan('skip', 0.4))
    assert skip.reason == SKIPPED and not skip.timed_out
    with pytest.raises(ValueError, match='skip_probability \\+ miss_probability'):
        HumanLimits(skip_probability=0.6, miss_probability=0.6)
    with pytest.raises(ValueError, match='HumanLimits.reaction_sigma'):
        HumanLimits(reaction_sigma=-1.0)


# ------------------------------------------------------------------ what the learner counts


def test_the_learner_counts_a_persons_time_and_a_window_let_pass_as_a_timeout():
    learner = EQSACLearner(3, [-2.0], [2.0], LearnerConfig(mode='qasac', hidden=(8,), seed=0))
    obs = np.zeros(3, np.float32)
    proposal = learner.propose(obs)
    answers = [
        Advice(np.array([1.0], np.float32), expert_name='p', human=True, response_time_s=1.25),
        Advice.decline(SKIPPED, 'p', human=True, response_time_s=0.5),
        Advice.no_answer(3.0, 'p'),
        Advice(np.array([1.0], np.float32), expert_name='controller', response_time_s=9.0),  # not a person
    ]
    outcomes = [learner.resolve_advice(proposal, a).outcome for a in answers]
    assert outcomes == ['given', 'declined', 'failed', 'given']
    counts = learner.episode_advice
    assert counts.failed['timeout'] == 1 and counts.human == 1
    assert counts.human_time_s == pytest.approx(4.75)
    for t in range(3):
        summary = learner.step(obs, [0.0], 0.0, obs, False, t == 2)
    assert summary.human_time_s == pytest.approx(4.75) and summary.human_time_total_s == pytest.approx(4.75)
    row = dict(zip(summary.CSV_FIELDS, summary.csv_row()))
    assert row['human_time_s'] == '4.750' and row['human_time_total_s'] == '4.750'
    learner.resolve_advice(learner.propose(obs), answers[1])
    for t in range(3):
        summary = learner.step(obs, [0.0], 0.0, obs, False, t == 2)
    assert summary.human_time_s == pytest.approx(0.5) and summary.human_time_total_s == pytest.approx(5.25)
    restored = EQSACLearner(3, [-2.0], [2.0], LearnerConfig(mode='qasac', hidden=(8,), seed=0))
    restored.load_state_dict(learner.state_dict())
    assert restored.advice_total.human_time_s == pytest.approx(5.25)


def test_the_deadman_pressed_alone_does_not_answer_with_the_command_held_before():
    """Hold Shift first, then steer: before, the press alone answered with the old command
    (+0.00 or +2.00 where the person steered to -2, 3 times of 5)."""
    clock = FakeClock()
    expert = TeleopExpert(name='person', clock=clock, answer_change=0.05)
    expert.update(command(0.0, enabled=False))
    expert.open(request())
    assert expert.update(command(0.0, enabled=True)) is None  # the deadman alone
    clock.now += 0.4
    assert expert.update(command(-0.6, enabled=True)) is None  # then the steer
    clock.now += 0.3
    advice = expert.settled()
    assert advice.advised and advice.action.tolist() == pytest.approx([-0.6])


def test_steering_key_by_key_answers_where_the_person_stopped_not_with_the_first_step():
    """Deadman first, then steer: 0 of 8 answers used to equal what the person steered to
    (+0.50 sent against +2.00 meant): the first key step answered."""
    clock = FakeClock()
    expert = TeleopExpert(name='person', clock=clock, settle_s=0.3)
    expert.update(command(0.0, enabled=False))
    expert.open(request())
    clock.now += 0.5
    expert.update(command(0.0, enabled=True))
    for value in (0.5, 1.0, 1.5, 2.0):  # a key press every 0.1 s
        clock.now += 0.1
        assert expert.update(command(value)) is None
        assert expert.settled() is None
    clock.now += 0.3
    advice = expert.settled()
    assert advice.advised and advice.action.tolist() == [2.0] and advice.response_time_s == pytest.approx(1.2)


def test_a_key_pressed_before_the_request_appeared_never_answers_it():
    """Presses that went on from the request before answered the next one, which the person
    had not seen, 33-83 ms after it appeared."""
    from eqhrl_ros.core.experts.wheel import MIN_REACTION_S

    clock = FakeClock()
    expert = TeleopExpert(name='person', clock=clock, settle_s=0.0)
    expert.update(command(0.5))
    expert.open(request())
    clock.now += MIN_REACTION_S / 2
    assert expert.update(command(1.0)) is None  # too soon to be a reaction: now the held command
    clock.now += 0.5
    assert expert.update(command(1.0)) is None and expert.pending is not None  # still where it was
    advice = expert.update(command(1.5))  # a change of the person's own, later
    assert advice.advised and advice.action.tolist() == [1.5]


def test_a_budget_in_the_persons_seconds_ends_the_requests_when_spent():
    from eqhrl_ros.core import EQSACLearner, LearnerConfig
    from eqhrl_ros.core.data.advice import Advice

    learner = EQSACLearner(
        3,
        [-2.0],
        [2.0],
        LearnerConfig(mode='random', random_ask_rate=1.0, advising_budget=100, advising_budget_s=2.5, hidden=(8, 8)),
    )
    obs = np.zeros(3, np.float32)
    asked = 0
    for _ in range(10):
        proposal = learner.propose(obs)
        if proposal.decision.fire:
            asked += 1
            learner.resolve_advice(proposal, Advice(np.zeros(1), human=True, response_time_s=1.0))
    assert asked == 3  # 1 s each: 0, 1 and 2 s spent before each ask
    # The third answer came after the person's seconds ran out: a timeout at the budget, never past it.
    assert learner.human_time_total_s == pytest.approx(2.5) and learner.episode_advice.failed['timeout'] == 1
    assert learner.person_budget_left_s == 0.0 and 'seconds' in learner.propose(obs).decision.reason
    learner.set_advising_budget_s(10.0)  # as ros2 param set does
    assert learner.propose(obs).decision.fire
    learner.set_advising_budget_s(0.0)  # 0: no budget in seconds
    assert learner.person_budget_left_s == float('inf')


def test_a_press_meant_for_the_request_on_screen_never_lands_on_a_newer_one():
    """A skip meant for episode 5, step 195 used to be counted on episode 6, step 2, shown 0.3 s before."""
    from eqhrl_ros.core.experts.teleop import Command

    clock = FakeClock()
    expert = TeleopExpert(name='person', clock=clock, settle_s=0.0)
    old, new = request(0), request(1)
    expert.update(Command(np.zeros(1, np.float32), True))
    expert.open(new)  # the newer request, not yet on the person's screen
    clock.now += 0.3
    seen = (old.episode, old.step)
    assert expert.update(Command(np.zeros(1, np.float32), True, skip=True, request=seen)) is None
    assert expert.pending is not None
    answered = expert.update(Command(np.array([0.7], np.float32), True, request=(new.episode, new.step)))
    assert answered.advised and answered.action.tolist() == pytest.approx([0.7])


def test_a_takeover_replaces_the_action_and_is_counted_apart_from_requests():
    from eqhrl_ros.core import EQSACLearner, LearnerConfig

    learner = EQSACLearner(3, [-2.0], [2.0], LearnerConfig(mode='sac', hidden=(8, 8)))
    obs = np.zeros(3, np.float32)
    for i, starts in enumerate((True, False, False, True)):
        proposal = learner.propose(obs)
        action, advised = learner.take_over(
            proposal, np.array([1.5], np.float32), 0.05 * i, starts
        ).action_and_advised()
        assert action.tolist() == [1.5] and advised  # as advice, into D_advising by default
        learner.step(obs, action, -1.0, obs, False, False, advised=advised)
    refused = learner.take_over(learner.propose(obs), np.array([9.0], np.float32), 0.0, True)
    assert refused.outcome == 'failed' and refused.detail == 'out_of_bounds'
    summary = learner.end_episode()
    assert (summary.takeovers, summary.takeover_steps) == (2, 4) and summary.takeover_s == pytest.approx(0.3)
    assert summary.advice_asked == 0  # not requests
    row = dict(zip(summary.CSV_FIELDS, summary.csv_row()))
    assert (row['takeovers'], row['takeover_steps'], row['takeover_s']) == (2, 4, '0.300')
    learner.config.takeover_to_advice_memory = False
    assert not learner.take_over(learner.propose(obs), np.array([0.5], np.float32), 0.0, True).advised


@pytest.mark.parametrize(
    'limits',
    [HumanLimits(), HumanLimits(reaction_median_s=2.5, reaction_sigma=0.8, answer_window_s=3.0, miss_probability=0.3)],
)
def test_the_expected_seconds_per_request_is_the_simulated_persons_mean_time(limits):
    from eqhrl_ros.core.experts.simulated_human import expected_seconds_per_request

    person = SimulatedHuman(lambda r: Advice(np.zeros(1, np.float32)), limits, seed=3)
    times = [person.outcome(person.plan(request())).response_time_s for _ in range(40_000)]
    mean, standard_error = float(np.mean(times)), float(np.std(times)) / math.sqrt(len(times))
    assert abs(expected_seconds_per_request(limits) - mean) < 4 * standard_error


class ConstantExpert:
    """A person's model that always wants ``value`` (env units)."""

    def __init__(self, value):
        self.value = value

    def __call__(self, req):
        return Advice(np.full(len(req.action_low), self.value, np.float32))


def takeover_request(learner_action):
    return AdviceRequest(
        np.zeros(3, np.float32), np.array([learner_action], np.float32), np.array([-2.0], np.float32),
        np.array([2.0], np.float32), math.nan, math.nan, 0, 0,
    )  # fmt: skip


def test_a_simulated_person_takes_over_after_reacting_to_a_departure_and_hands_back_once_close():
    from eqhrl_ros.core.experts.simulated_human import TakeoverRule

    limits = HumanLimits(reaction_median_s=0.2, reaction_sigma=0.0, action_noise=0.0)
    person = SimulatedHuman(ConstantExpert(1.0), limits, takeover=TakeoverRule(delta=0.5, step_s=0.05))
    assert person.intervene(takeover_request(0.9), new_episode=True) is None  # 0.05 apart: within delta
    # 1.0 apart in [-1, 1] units (2.0 in env units): noticed, and taken over after 0.2 s = 4 steps.
    seen = [person.intervene(takeover_request(-1.0)) for _ in range(4)]
    assert seen[:3] == [None, None, None]
    action, seconds, starts = seen[3]
    assert action.tolist() == [1.0] and seconds == 0.05 and starts
    action, _, starts = person.intervene(takeover_request(0.0))  # 0.5 apart: above delta / 2, still theirs
    assert not starts
    assert person.intervene(takeover_request(0.6)) is None  # 0.2 apart: handed back
    # A departure shorter than their reaction is let pass.
    assert [person.intervene(takeover_request(-1.0)) for _ in range(2)] == [None, None]
    assert person.intervene(takeover_request(1.0)) is None
    assert [person.intervene(takeover_request(-1.0)) for _ in range(3)] == [None, None, None]
    assert SimulatedHuman(ConstantExpert(1.0), limits).intervene(takeover_request(-1.0)) is None  # no rule


def test_a_run_with_a_simulated_takeover_counts_it_apart_and_only_inside_the_budget():
    from eqhrl_ros.core.envs.gymnasium_envs import make_env
    from eqhrl_ros.core.experts.simulated_human import TakeoverRule
    from eqhrl_ros.core.runs.in_process import train

    def run(mode, rate=0.0):
        env = make_env('Pendulum-v1', 50)
        config = LearnerConfig(
            mode=mode, hidden=(16, 16), batch_size=16, learning_starts=10**6, advising_budget=2, random_ask_rate=rate
        )
        learner = EQSACLearner(3, env.action_space.low, env.action_space.high, config)
        person = make_expert(
            'simulated_human', 'Pendulum-v1', human_limits=HumanLimits(reaction_median_s=0.1, miss_probability=0.0),
            takeover=TakeoverRule(delta=0.5),
        )  # fmt: skip
        return learner, train(env, learner, 4, person, seed=0)

    learner, summaries = run('random')  # rate 0: no request ever, takeover alone
    assert all(s.advice_asked == 0 for s in summaries)
    assert summaries[0].takeovers >= 1 and summaries[0].takeover_steps >= summaries[0].takeovers
    assert summaries[0].takeover_s == pytest.approx(0.05 * summaries[0].takeover_steps)
    assert all(s.takeover_steps == 0 for s in summaries[2:])  # outside the two-episode budget
    taken = sum(s.takeover_steps for s in summaries)
    assert len(learner.advice_replay) == taken  # stored as advice, into D_advising
    _, plain = run('sac')  # SAC keeps no advice: nobody takes over
    assert all(s.takeover_steps == 0 for s in plain)
    with pytest.raises(ValueError, match='only a simulated person takes over'):
        make_expert('heuristic', 'Pendulum-v1', takeover=TakeoverRule(delta=0.5))
