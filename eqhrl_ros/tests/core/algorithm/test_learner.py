"""EQSACLearner behaviour: advice handling, dual replay, update order, determinism, checkpoints."""

import os

import numpy as np
import pytest
import torch

from eqhrl_ros.core import (
    Advice,
    CheckpointError,
    EQSACLearner,
    LearnerConfig,
    PolicyExpert,
    export_policy,
    load_checkpoint,
    make_env,
    run_episode,
    save_checkpoint,
)

LOW, HIGH = [-2.0], [2.0]


def small_learner(mode='eqsac', **overrides) -> EQSACLearner:
    settings = dict(
        mode=mode,
        hidden=(32, 32),
        batch_size=16,
        learning_starts=32,
        replay_capacity=5000,
        queue_length=3,
        advising_budget=10,
    )
    settings.update(overrides)
    return EQSACLearner(3, LOW, HIGH, LearnerConfig(**settings))


class ScriptedExpert:
    """Gives ``answer`` for every request and remembers the requests."""

    def __init__(self, answer):
        self.answer = answer
        self.requests = []

    def __call__(self, request):
        self.requests.append(request)
        return self.answer(request) if callable(self.answer) else self.answer


def pendulum_episode(learner, expert, seed=0):
    env = make_env('Pendulum-v1', max_episode_steps=30)
    try:
        return run_episode(env, learner, expert, seed=seed)
    finally:
        env.close()


def test_config_refuses_bad_values_with_the_field_name():
    with pytest.raises(ValueError, match='gamma'):
        LearnerConfig(gamma=1.5)
    with pytest.raises(ValueError, match='mode'):
        LearnerConfig(mode='ddpg')


def test_propose_validates_observations():
    learner = small_learner()
    with pytest.raises(ValueError, match='3'):
        learner.propose([0.0, 1.0])
    with pytest.raises(ValueError, match='non-finite'):
        learner.propose([0.0, float('nan'), 1.0])


def test_actions_stay_in_env_bounds():
    learner = small_learner()
    actions = np.array([learner.propose(np.random.randn(3)).action for _ in range(200)])
    assert actions.min() >= -2.0 and actions.max() <= 2.0 and actions.std() > 0.1


def test_advice_is_requested_exactly_when_gates_fire_and_used():
    learner = small_learner(advising_budget=100)
    expert = ScriptedExpert(Advice(np.array([1.5], dtype=np.float32), expert_name='x'))
    summary = pendulum_episode(learner, expert)
    assert summary.advice_asked == len(expert.requests) > 0
    assert summary.advice_given == summary.advice_asked
    assert len(learner.advice_replay) == summary.advice_given
    stored = learner.advice_replay.action[: len(learner.advice_replay), 0]
    assert torch.allclose(stored, torch.full_like(stored, 0.75))  # 1.5 normalised by scale 2
    request = expert.requests[0]
    assert request.episode == 0 and np.isfinite(request.entropy) and request.discrepancy >= 0


def test_sac_never_asks_and_keeps_one_buffer():
    learner = small_learner(mode='sac')
    expert = ScriptedExpert(Advice(np.array([1.0], dtype=np.float32)))
    summary = pendulum_episode(learner, expert)
    assert expert.requests == [] and summary.advice_asked == 0 and len(learner.advice_replay) == 0


def test_no_advice_outside_the_budget():
    learner = small_learner(advising_budget=1)
    expert = ScriptedExpert(Advice(np.array([1.0], dtype=np.float32)))
    pendulum_episode(learner, expert)
    asked_in_budget = len(expert.requests)
    second = pendulum_episode(learner, expert)
    assert asked_in_budget > 0
    assert second.episode == 1 and second.advice_asked == 0 and len(expert.requests) == asked_in_budget


@pytest.mark.parametrize(
    'answer,field',
    [
        (Advice.decline('deadman not held'), 'declined'),
        (Advice(np.array([5.0], dtype=np.float32)), 'out_of_bounds'),
        (Advice(np.array([np.nan], dtype=np.float32)), 'non_finite'),
        (Advice(np.array([0.1, 0.2], dtype=np.float32)), 'wrong_size'),
    ],
)
def test_refused_or_bad_advice_keeps_own_action_and_is_counted_apart(answer, field):
    learner = small_learner(advising_budget=100)
    summary = pendulum_episode(learner, ScriptedExpert(answer))
    assert summary.advice_asked > 0 and summary.advice_given == 0
    assert len(learner.advice_replay) == 0
    counts = learner.advice_total
    if field == 'declined':
        assert counts.declined == summary.advice_asked
    else:
        assert counts.failed[field] == summary.advice_asked == summary.advice_failed


def test_a_crashing_expert_does_not_stop_training():
    def broken(request):
        raise RuntimeError('expert bug')

    learner = small_learner(advising_budget=100)
    summary = pendulum_episode(learner, broken)
    assert summary.length == 30 and learner.advice_total.failed['error'] == summary.advice_asked > 0


def test_non_finite_transition_never_reaches_the_buffer():
    learner = small_learner()
    with pytest.raises(ValueError, match='non-finite'):
        learner.step([0, 0, 0], [0.0], float('nan'), [0, 0, 0], False, False)
    with pytest.raises(ValueError):
        learner.step([0, 0, 0], [0.0], 1.0, [0, np.inf, 0], False, False)
    assert len(learner.replay) == 0 and learner.total_steps == 0


def optimiser_steps(learner):
    """How many steps each optimiser has taken (Adam's per-parameter step count)."""
    return {
        name: int(next(iter(learner.updater.optimizers[name].state.values()))['step'])
        for name in ('critic', 'actor', 'alpha')
    }


def test_each_update_steps_the_critics_twice_with_advice_and_the_actor_once():
    learner = small_learner()
    for _ in range(40):
        learner.replay.add(np.random.randn(3), [0.1], -1.0, np.random.randn(3), False)

    learner.update()  # advice buffer empty: the second critic step is skipped
    assert optimiser_steps(learner) == {'critic': 1, 'actor': 1, 'alpha': 1}

    for _ in range(3):  # fewer than a batch: sampled with replacement
        learner.advice_replay.add(np.ones(3), [0.5], 1.0, np.ones(3), True)
    info = learner.update()
    assert optimiser_steps(learner) == {'critic': 3, 'actor': 2, 'alpha': 2}
    assert 'advice_critic_loss' in info and 'advice_actor_loss' not in info  # the actor trains on D only
    # The order of the steps and which batch each uses: tests/core/algorithm/test_reference_update.py.


def test_qasac_also_uses_the_advice_critic_step_but_sac_does_not():
    for mode, expected in [('qasac', 2), ('sac', 1)]:
        learner = small_learner(mode=mode)
        for _ in range(20):
            learner.replay.add(np.random.randn(3), [0.1], -1.0, np.random.randn(3), False)
            learner.advice_replay.add(np.random.randn(3), [0.1], -1.0, np.random.randn(3), False)
        learner.update()
        assert optimiser_steps(learner)['critic'] == expected, mode


def test_updates_change_the_networks():
    learner = small_learner(learning_starts=8)
    before = [p.clone() for p in learner.critic.parameters()]
    pendulum_episode(learner, None)
    assert learner.updates == 30 - 8 + 1
    assert any(not torch.equal(a, b) for a, b in zip(before, learner.critic.parameters()))


def test_same_seed_same_actions_and_gate_decisions():
    def trace(seed):
        learner = small_learner(seed=seed, advising_budget=100)
        log = []
        expert = ScriptedExpert(lambda r: log.append((r.step, round(r.discrepancy, 6))) or Advice(r.proposed_action))
        summary = pendulum_episode(learner, expert)
        return summary.episode_return, log, learner.propose(np.ones(3)).action.tolist()

    assert trace(7) == trace(7)
    assert trace(7)[2] != trace(8)[2]


def test_checkpoint_round_trip_gives_identical_actions_and_counters(tmp_path):
    learner = small_learner(advising_budget=100)
    pendulum_episode(learner, ScriptedExpert(Advice(np.array([1.0], dtype=np.float32))))
    save_checkpoint(learner, tmp_path / 'ckpt.pt', tmp_path / 'replay.pt')

    restored = small_learner(advising_budget=100, seed=999)
    load_checkpoint(restored, tmp_path / 'ckpt.pt', tmp_path / 'replay.pt')
    assert restored.episode == learner.episode == 1
    assert restored.total_steps == learner.total_steps
    assert restored.advice_total.to_dict() == learner.advice_total.to_dict()
    assert restored.gates.d_queue.values() == learner.gates.d_queue.values()
    assert len(restored.replay) == len(learner.replay) and len(restored.advice_replay) == len(learner.advice_replay)
    for _ in range(5):
        obs = np.random.randn(3)
        a, b = learner.propose(obs), restored.propose(obs)
        assert np.array_equal(a.action, b.action) and a.decision == b.decision
    learner.update()
    restored.update()
    assert all(torch.equal(p, q) for p, q in zip(learner.actor.parameters(), restored.actor.parameters()))


def test_a_state_loaded_in_process_shares_no_tensor_with_the_learner_it_came_from():
    """load_state_dict(other.state_dict()) without a file between (a copy of a learner, weights
    handed over in memory): torch's optimisers keep the given state tensors, so the two
    learners' Adam moments and step counts were one, and each of them stepped both."""
    donor, twin = small_learner(seed=1, learning_starts=1), small_learner(seed=2, learning_starts=1)
    for learner in (donor, twin):
        pendulum_episode(learner, ScriptedExpert(Advice(np.array([1.0], dtype=np.float32))))
        learner.update()
    assert donor.updater.optimizers['critic'].state  # there are moments to share
    twin.load_state_dict(donor.state_dict())
    mine = {t.data_ptr() for t in _state_tensors(twin)}
    assert mine.isdisjoint(t.data_ptr() for t in _state_tensors(donor))
    steps = [float(s['step']) for s in donor.updater.optimizers['critic'].state.values()]
    twin.update()  # steps the twin alone
    assert [float(s['step']) for s in donor.updater.optimizers['critic'].state.values()] == steps


def _state_tensors(learner):
    modules = (learner.actor, learner.critic, learner.critic_target)
    optimizers = (
        learner.updater.optimizers['actor'],
        learner.updater.optimizers['critic'],
        learner.updater.optimizers['alpha'],
    )
    return [
        *(t for m in modules for t in m.state_dict().values()),
        learner.log_alpha,
        *(t for o in optimizers for s in o.state.values() for t in s.values()),
    ]


def test_a_resume_names_the_settings_it_changes_from_the_checkpoints(tmp_path):
    """Before, a run resumed with another mode or learning rate went on with them unsaid. Speed
    settings (compile_update, device) and the run-time budgets (which come back as saved) are
    not changes of the run."""
    save_checkpoint(small_learner('random'), tmp_path / 'run.pt')
    same = small_learner('random', compile_update=True)
    load_checkpoint(same, tmp_path / 'run.pt')
    assert same.resumed_changes == []
    other = small_learner('eqsac', critic_lr=5e-4, advising_budget=3)
    load_checkpoint(other, tmp_path / 'run.pt')
    assert other.resumed_changes == ["mode 'eqsac' (was 'random')", 'critic_lr 0.0005 (was 0.001)']
    assert other.config.advising_budget == 10  # as saved


def test_corrupt_and_foreign_checkpoints_give_clear_errors_and_change_nothing(tmp_path):
    learner = small_learner()
    save_checkpoint(learner, tmp_path / 'good.pt')
    data = (tmp_path / 'good.pt').read_bytes()
    (tmp_path / 'truncated.pt').write_bytes(data[: len(data) // 2])
    (tmp_path / 'text.pt').write_text('not a checkpoint')
    torch.save({'weights': torch.zeros(3)}, tmp_path / 'other.pt')
    other_env = EQSACLearner(8, [-1, -1], [1, 1], LearnerConfig(hidden=(32, 32)))
    save_checkpoint(other_env, tmp_path / 'lunar.pt')

    target = small_learner(seed=5)
    before = [p.clone() for p in target.actor.parameters()]
    for name, message in [
        ('truncated.pt', 'not a readable'),
        ('text.pt', 'not a readable'),
        ('other.pt', 'expected an eqhrl_ros.checkpoint'),
        ('lunar.pt', 'observations of 8'),
        ('missing.pt', 'no such file'),
        ('.', 'a folder, not a file'),  # a run's folder where its checkpoint was meant
    ]:
        with pytest.raises(CheckpointError, match=message):
            load_checkpoint(target, tmp_path / name)
    assert all(torch.equal(a, b) for a, b in zip(before, target.actor.parameters()))


class _Payload:
    def __reduce__(self):
        return (os.system, ('touch /tmp/eqhrl_pwned',))


def test_a_malicious_pickle_is_refused_without_running_code(tmp_path):
    marker = '/tmp/eqhrl_pwned'
    if os.path.exists(marker):
        os.remove(marker)
    torch.save({'format': 'eqhrl_ros.checkpoint', 'version': 1, 'evil': _Payload()}, tmp_path / 'evil.pt')
    with pytest.raises(CheckpointError):
        load_checkpoint(small_learner(), tmp_path / 'evil.pt')
    with pytest.raises(CheckpointError):
        PolicyExpert(tmp_path / 'evil.pt')
    assert not os.path.exists(marker)
    with pytest.raises(CheckpointError, match='a folder, not a file'):  # before: 'no such file'
        PolicyExpert(tmp_path)


def test_exported_policy_serves_the_learners_deterministic_action(tmp_path):
    learner = small_learner()
    export_policy(learner, tmp_path / 'policy.pt')
    expert = PolicyExpert(tmp_path / 'policy.pt')
    obs = np.array([0.2, -0.3, 1.0], dtype=np.float32)
    assert np.allclose(expert.action(obs), learner.act(obs, deterministic=True))
    assert (tmp_path / 'policy.pt').stat().st_size < 100_000


def test_networks_that_cannot_fit_in_memory_are_refused_naming_the_sizes():
    """Before: hidden_sizes [100000, 100000] died in torch's allocator (40 GB for one layer) with a
    traceback, or later by the out-of-memory killer; a ValueError is a node's one-line refusal."""
    with pytest.raises(ValueError, match=r'hidden sizes \[100000, 100000\] make networks of 30,002,100,004'):
        EQSACLearner(3, [-2.0], [2.0], LearnerConfig(hidden=(100000, 100000)))


def test_a_replay_capacity_whose_transitions_cannot_fit_is_refused_before_anything_is_allocated(monkeypatch):
    """From outside: `learner -p env_id:=CarRacing-v3` (27,648 observation values) at the default
    replay_capacity ended in a traceback of a failed 110 GB allocation. Now refused as a camera's
    frames are, with the capacity that would take half of the machine's memory (here a machine of
    0.1 GB, so that what fits stays small)."""
    from eqhrl_ros.core.algorithm import memories

    monkeypatch.setattr(memories, 'physical_memory_bytes', lambda: 10**8)
    spaces = (2_000, [-1.0, 0.0, 0.0], [1.0, 1.0, 1.0])
    with pytest.raises(
        ValueError,
        match=r'^replay_capacity 500,000 with observations of 2,000 values needs 16.0 GB for D and D_advising; '
        r'this machine has 0.1 GB \(replay_capacity 1,560 would take half of it\)$',
    ):
        EQSACLearner(*spaces, LearnerConfig(hidden=(8,), replay_capacity=500_000))
    fits = EQSACLearner(*spaces, LearnerConfig(hidden=(8,), replay_capacity=1_560))
    assert fits.replay.capacity == fits.advice_replay.capacity == 1_560
    assert fits.replay.rows.shape == (1_560, 2 * 2_000 + 3 + 2)  # what the check counted
