"""The random arm matched step by step (random_ask_steps, an extension): in each episode the
reference's requests, moved round the episode by a random offset; the same count, gaps and runs."""

import re

import numpy as np
import pytest

from eqhrl_ros.core.algorithm.advising import AdvisingGates, place_owed, step_patterns
from eqhrl_ros.core.algorithm.learner_state import check_state


def fired_steps(gates, episode, length, rng):
    return [s for s in range(length) if gates.decide(episode, draw=float(rng.random()), step=s).fire]


def gaps(steps, length):
    """The gaps between successive requests, round the episode (a shift keeps them)."""
    ordered = sorted(steps)
    return sorted((b - a) % length for a, b in zip(ordered, ordered[1:] + ordered[:1]))


def test_each_episode_asks_the_references_count_with_its_gaps_at_a_random_place():
    pattern = (20, 3, 4, 5, 12, -1, 10, -1, 15, 0, 14, -1)  # 4 clustered requests; none; 2 adjacent round the end
    rng = np.random.default_rng(0)
    places = set()
    for _ in range(30):
        gates = AdvisingGates('random', advising_budget=3, random_ask_steps=pattern)
        first = fired_steps(gates, 0, 20, rng)
        assert len(first) == 4 and gaps(first, 20) == gaps([3, 4, 5, 12], 20)
        assert fired_steps(gates, 1, 10, rng) == []
        third = fired_steps(gates, 2, 15, rng)
        assert len(third) == 2 and gaps(third, 15) == gaps([0, 14], 15)
        places.add(tuple(first))
    assert len(places) > 5  # the place is chance's


def test_episodes_past_the_pattern_ask_nothing_and_the_budget_still_ends_advice():
    gates = AdvisingGates('random', advising_budget=5, random_ask_steps=(5, 0, 1, 2, 3, 4, -1))
    rng = np.random.default_rng(1)
    assert len(fired_steps(gates, 0, 5, rng)) == 5
    assert fired_steps(gates, 1, 5, rng) == []
    assert not gates.decide(5, draw=0.0, step=0).within_budget


def test_requests_an_episode_ended_before_are_asked_in_the_next_one_with_their_gaps():
    # The reference's episode 0 lasted 20 steps and asked at 15, 16, 17; this arm's lasts 10.
    pattern = (20, 15, 16, 17, -1, 20, 2, -1, 20, -1)
    rng = np.random.default_rng(2)
    owed_anywhere = 0
    for _ in range(40):
        gates = AdvisingGates('random', advising_budget=3, random_ask_steps=pattern)
        short = fired_steps(gates, 0, 10, rng)
        second, third = fired_steps(gates, 1, 20, rng), fired_steps(gates, 2, 20, rng)
        assert len(short) + len(second) + len(third) == 4  # the run's count holds
        assert third == []  # nothing was owed past the episode that paid it
        owed = 3 - len(short)
        owed_anywhere += owed
        if owed == 3:  # the whole run of three, still a run (round the episode) beside the own request
            runs = [s for s in second if {(s + 1) % 20, (s + 2) % 20} <= set(second)]
            assert len(second) == 4 and runs
    assert owed_anywhere > 40  # the short episode did end before most of them


def test_owed_requests_survive_a_save_between_episodes():
    pattern = (30, 20, 21, 25, -1, 30, 4, -1)
    rng = np.random.default_rng(3)
    for _ in range(20):
        gates = AdvisingGates('random', advising_budget=2, random_ask_steps=pattern)
        fired_steps(gates, 0, 5, rng)
        resumed = AdvisingGates('random', advising_budget=2, random_ask_steps=pattern)
        resumed.load_state_dict(gates.state_dict())
        draws = rng.random(30)
        expected = [s for s in range(30) if gates.decide(1, draw=float(draws[s]), step=s).fire]
        assert [s for s in range(30) if resumed.decide(1, draw=float(draws[s]), step=s).fire] == expected


def test_placing_owed_requests_moves_past_taken_steps_and_never_overfills():
    assert place_owed({3, 4}, [7, 8, 10], length=12, offset=3) == {3, 4, 5, 6, 7}
    assert place_owed({0, 1}, [5, 6, 7, 8], length=4, offset=0) == {0, 1, 2, 3}


@pytest.mark.parametrize('shifted', [[0, 1], [0, 1, [2.5]], [0, True, []], [0, -2, []], 'x'])
def test_a_checkpoint_with_a_bad_shifted_pattern_is_refused(shifted):
    state = {
        'config': {},
        'rng': {},
        'counters': {'episode': 0, 'total_steps': 0, 'updates': 0, 'advice_total': {}},
        'gates': {'d_queue': [], 'e_queue': [], 'shifted': shifted},
    }
    with pytest.raises(ValueError, match='gates.shifted'):
        check_state(state)


@pytest.mark.parametrize(
    'flat, message',
    [
        ((5, 1, 2), 'not ended by -1'),
        ((0, -1), 'starts with its length'),
        ((5, 5, -1), 'in [0, 5)'),
        ((5, 1, 1, -1), 'distinct'),
    ],
)
def test_a_pattern_that_cannot_be_is_refused_with_what_is_wrong(flat, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        step_patterns(flat)


def test_a_refractory_gate_never_asks_twice_within_its_steps_of_one_episode():
    gates = AdvisingGates('random', advising_budget=3, random_ask_rate=1.0, request_refractory_steps=3)
    fired = [s for s in range(12) if gates.decide(0, draw=0.0, step=s).fire]
    assert fired == [0, 4, 8]
    held = gates.decide(0, draw=0.0, step=9)
    assert not held.fire and held.refractory and 'request_refractory_steps' in held.reason
    assert gates.decide(1, draw=0.0, step=0).fire  # a new episode asks again at once
    plain = AdvisingGates('random', advising_budget=3, random_ask_rate=1.0)
    assert all(plain.decide(0, draw=0.0, step=s).fire for s in range(5))  # off by default: the paper's gates
