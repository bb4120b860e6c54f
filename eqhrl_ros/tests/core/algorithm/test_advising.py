"""Gate semantics of Eq. 7 and Eq. 10 on hand-set queue contents."""

import pytest

from eqhrl_ros.core.algorithm.advising import AdvisingGates, FifoQueue


def full_gates(mode='eqsac', budget=30, d=(1.0, 2.0, 3.0), e=(0.5, 0.6, 0.7), **kw):
    gates = AdvisingGates(mode, budget, queue_length=3, **kw)
    for value in d:
        gates.d_queue.push(value)
    for value in e:
        gates.e_queue.push(value)
    return gates


def test_fifo_keeps_the_last_length_values_in_order():
    queue = FifoQueue(3)
    for value in [1, 2, 3, 4, 5]:
        queue.push(value)
    assert queue.values() == [3.0, 4.0, 5.0]
    assert queue.full() and len(queue) == 3


def test_eqsac_fires_only_when_both_gates_open():
    assert full_gates().decide(0, discrepancy=3.5, entropy=0.4).fire
    assert not full_gates().decide(0, discrepancy=3.5, entropy=0.55).fire  # not sure enough
    assert not full_gates().decide(0, discrepancy=2.5, entropy=0.4).fire  # critics agree


def test_comparisons_are_strict():
    decision = full_gates().decide(0, discrepancy=3.0, entropy=0.4)  # D equal to max
    assert not decision.ask and not decision.fire
    decision = full_gates().decide(0, discrepancy=3.5, entropy=0.5)  # E equal to min
    assert decision.ask and not decision.respond and not decision.fire


def test_compares_with_the_queue_before_pushing_then_pushes():
    gates = full_gates()
    decision = gates.decide(0, discrepancy=10.0, entropy=0.1)
    assert decision.fire
    assert decision.d_threshold == 3.0 and decision.e_threshold == 0.5
    assert gates.d_queue.values() == [2.0, 3.0, 10.0]
    assert gates.e_queue.values() == [0.6, 0.7, 0.1]
    # The same values again no longer exceed the new max/min.
    assert not gates.decide(0, discrepancy=10.0, entropy=0.1).fire


def test_gate_closed_until_queue_holds_length_earlier_values():
    gates = AdvisingGates('qasac', 30, queue_length=3)
    decisions = [gates.decide(0, discrepancy=float(d)) for d in [1, 2, 3, 4]]
    # Steps 1-3 see fewer than 3 earlier values, even though each D is a new maximum.
    assert [d.fire for d in decisions] == [False, False, False, True]
    assert 'filling' in decisions[2].reason


def test_qasac_ignores_entropy_and_eqsac_waits_for_the_entropy_queue():
    qasac = AdvisingGates('qasac', 30, queue_length=2)
    for d in [1.0, 2.0]:
        qasac.decide(0, discrepancy=d)
    assert qasac.decide(0, discrepancy=3.0).fire
    assert len(qasac.e_queue) == 0
    eqsac = full_gates(e=())  # D queue full, E queue empty
    assert not eqsac.decide(0, discrepancy=9.0, entropy=-5.0).fire


def test_budget_edge():
    assert full_gates(budget=5).decide(4, discrepancy=9.0, entropy=0.1).fire
    decision = full_gates(budget=5).decide(5, discrepancy=9.0, entropy=0.1)
    assert not decision.fire and not decision.within_budget and 'budget' in decision.reason
    assert not full_gates(budget=0).decide(0, discrepancy=9.0, entropy=0.1).fire


def test_sac_never_fires():
    gates = full_gates(mode='sac')
    assert not gates.needs_evaluation(0)
    assert not gates.decide(0).fire


def test_outside_budget_queues_are_left_alone():
    gates = full_gates(budget=1)
    gates.decide(1, discrepancy=100.0, entropy=-100.0)
    assert gates.d_queue.values() == [1.0, 2.0, 3.0]


def test_fixed_thresholds():
    gates = AdvisingGates('eqsac', 30, threshold_kind='fixed', fixed_d_threshold=1.0, fixed_e_threshold=0.0)
    assert gates.decide(0, discrepancy=1.5, entropy=-0.1).fire  # no queue warm-up
    assert not gates.decide(0, discrepancy=1.0, entropy=-0.1).fire
    assert not gates.decide(0, discrepancy=1.5, entropy=0.0).fire


@pytest.mark.parametrize(
    'kwargs', [dict(mode='eq'), dict(advising_budget=-1), dict(queue_length=0), dict(threshold_kind='adaptive')]
)
def test_bad_settings_are_refused(kwargs):
    settings = dict(mode='eqsac', advising_budget=30, queue_length=15)
    settings.update(kwargs)
    with pytest.raises(ValueError):
        AdvisingGates(**settings)


def test_a_random_schedule_asks_its_count_in_each_episode_at_uniform_steps():
    import random

    schedule = (0, 3, 1, 7, 0, 2) * 50
    gates = AdvisingGates('random', advising_budget=len(schedule), random_ask_schedule=schedule, random_ask_horizon=100)
    rng = random.Random(0)
    asked_steps = []
    for episode, wanted in enumerate(schedule):
        fired = [step for step in range(100) if gates.decide(episode, draw=rng.random(), step=step).fire]
        assert len(fired) == wanted, episode
        asked_steps += fired
    # Uniform over 0..99: mean 49.5, SD of the mean of n draws about 28.9 / sqrt(n).
    n = len(asked_steps)
    assert abs(sum(asked_steps) / n - 49.5) < 4 * 28.9 / n**0.5
    first_half = sum(step < 50 for step in asked_steps)
    assert abs(first_half - n / 2) < 4 * (n / 4) ** 0.5


def test_a_random_schedule_asks_nothing_past_its_end_or_the_budget():
    gates = AdvisingGates('random', advising_budget=2, random_ask_schedule=(5,), random_ask_horizon=10)
    assert sum(gates.decide(0, draw=0.99, step=s).fire for s in range(10)) == 5  # the last steps must ask
    assert not any(gates.decide(1, draw=0.0, step=s).fire for s in range(10))  # no count for episode 1
    assert not gates.decide(2, draw=0.0, step=0).within_budget


def test_an_episode_shorter_than_the_horizon_asks_fewer():
    gates = AdvisingGates('random', advising_budget=1, random_ask_schedule=(10,), random_ask_horizon=100)
    assert sum(gates.decide(0, draw=0.5, step=s).fire for s in range(20)) < 10


def test_ask_random_thins_the_ask_gate_by_chance_and_never_asks_without_it():
    gates = full_gates('ask_random', random_ask_rate=0.25)
    assert gates.uses_discrepancy and gates.uses_draw and not gates.uses_entropy
    assert not full_gates('ask_random', random_ask_rate=1.0).decide(0, discrepancy=2.5, draw=0.0).fire  # D closed
    opened = full_gates('ask_random', random_ask_rate=0.25).decide(0, discrepancy=3.5, draw=0.2)
    assert opened.fire and opened.ask and not opened.respond
    refused = full_gates('ask_random', random_ask_rate=0.25).decide(0, discrepancy=3.5, draw=0.3)
    assert refused.ask and not refused.fire and 'random draw' in refused.reason


@pytest.mark.parametrize('schedule', [(-1,), (1.5,), ('3',), 'abc', (True,)])
def test_a_bad_random_schedule_is_refused(schedule):
    with pytest.raises(ValueError, match='random_ask_schedule'):
        AdvisingGates('random', 10, random_ask_schedule=schedule)


def test_ask_median_asks_when_d_is_above_its_max_and_e_below_its_median():
    gates = full_gates('ask_median')  # D_queue 1, 2, 3; E_queue 0.5, 0.6, 0.7 (median 0.6)
    assert gates.uses_discrepancy and gates.uses_entropy and not gates.uses_draw
    fired = full_gates('ask_median').decide(0, discrepancy=3.5, entropy=0.55)
    assert fired.fire and fired.e_threshold == 0.6  # EQSAC would not: 0.55 is above min 0.5
    assert not full_gates('eqsac').decide(0, discrepancy=3.5, entropy=0.55).fire
    assert not full_gates('ask_median').decide(0, discrepancy=3.5, entropy=0.65).fire  # above the median
    assert not full_gates('ask_median').decide(0, discrepancy=2.5, entropy=0.1).fire  # the ask gate closed


def test_joint_rank_starts_as_eqsac_and_moves_its_threshold_toward_the_target_rate():
    import random

    # Rank product 1 exactly where EQSAC fires; the threshold starts there.
    first = full_gates('joint_rank').decide(0, discrepancy=3.5, entropy=0.4)
    assert first.fire and first.joint_rank == 1.0 and first.joint_threshold == 1.0
    near = full_gates('joint_rank').decide(0, discrepancy=3.5, entropy=0.55)  # rank_E 2/3
    assert not near.fire and abs(near.joint_rank - 2 / 3) < 1e-12 and 'rank product' in near.reason

    # On values drawn independently, it asks at the target rate in the long run (EQSAC's own rate
    # on such values is about 1/(queue+1)^2 = 0.4 %).
    rng = random.Random(0)
    for target in (0.05, 0.2):
        gates = AdvisingGates('joint_rank', 10**6, queue_length=15, gate_target_rate=target, gate_threshold_step=0.01)
        fires = [gates.decide(0, discrepancy=rng.random(), entropy=rng.random()).fire for _ in range(40_000)]
        rate = sum(fires[10_000:]) / 30_000
        assert abs(rate - target) < 0.2 * target, (target, rate)


def test_joint_rank_keeps_its_threshold_in_a_checkpoint_and_needs_dynamic_thresholds():
    gates = AdvisingGates('joint_rank', 100, queue_length=3, gate_target_rate=0.5)
    for _ in range(20):
        gates.decide(0, discrepancy=0.0, entropy=1.0)  # never fires: the threshold falls
    assert gates.joint_threshold < 1.0
    other = AdvisingGates('joint_rank', 100, queue_length=3)
    other.load_state_dict(gates.state_dict())
    assert other.joint_threshold == gates.joint_threshold
    with pytest.raises(ValueError, match='threshold_kind dynamic'):
        AdvisingGates('joint_rank', 100, threshold_kind='fixed')
