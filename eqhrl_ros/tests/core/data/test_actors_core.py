"""Acting apart from learning, without ROS: an actor-side learner that only acts,
the trainer that learns from its transitions, the outbox, sequences and the weights codec."""

import dataclasses

import numpy as np
import pytest
import torch

from eqhrl_ros.core import EQSACLearner, LearnerConfig, heuristic_expert, make_env, run_episode
from eqhrl_ros.core.data.summary import EpisodeSummary
from eqhrl_ros.core.data.transitions import Outbox, SequenceTracker, StepLimits, TransitionBatch
from eqhrl_ros.core.data.weights import WeightsError, apply_weights, encode_weights
from eqhrl_ros.core.runs.in_process import ask_expert
from eqhrl_ros.core.runs.trainer import TRAINER_CSV_FIELDS, Trainer

SETTINGS = dict(
    mode='eqsac',
    hidden=(32, 32),
    batch_size=16,
    learning_starts=40,
    replay_capacity=5000,
    queue_length=3,
    advising_budget=3,
)


def pendulum_learner(**overrides) -> EQSACLearner:
    return EQSACLearner(3, [-2.0], [2.0], LearnerConfig(**{**SETTINGS, **overrides}))


def run_split(env, actor: EQSACLearner, trainer: Trainer, outbox: Outbox, expert, seed) -> EpisodeSummary:
    """One episode with acting and learning apart, in the order the nodes run it when weights
    go out after every update: act, send the transition, the trainer stores and updates,
    the actor applies the new weights before its next step."""
    obs, _ = env.reset(seed=seed)
    while True:
        proposal = actor.propose(obs)
        if proposal.decision.fire:
            action, advised = ask_expert(actor, proposal, expert).action_and_advised()
        else:
            action, advised = proposal.action, False
        next_obs, reward, terminated, truncated, _ = env.step(action)
        summary = actor.step(obs, action, reward, next_obs, terminated, truncated, advised, learn=False)
        outbox.add(obs, actor.normalize(action), reward, next_obs, terminated, advised)
        if summary is not None:
            outbox.end_episode(summary)
        while (batch := outbox.pop_oldest()) is not None:
            trainer.receive(batch)
        for _ in range(trainer.updates_owed()):
            trainer.update()
        if trainer.weights_due():
            apply_weights(actor, encode_weights(trainer.learner))
            trainer.weights_sent()
        if summary is not None:
            return summary
        obs = next_obs


def test_acting_apart_with_fresh_weights_is_algorithm_1_exactly():
    """Same seed, weights after every update: the split computes what the lock-step learner
    does, to the bit: the same actions, gates, advice, returns and final networks."""
    expert = heuristic_expert('Pendulum-v1')
    lock_env, split_env = make_env('Pendulum-v1', 60), make_env('Pendulum-v1', 60)
    lock = pendulum_learner()
    actor, trainer_learner = pendulum_learner(), pendulum_learner()
    trainer = Trainer(trainer_learner, updates_per_transition=1.0, weights_every=1)
    # A trainer's learner never proposes: its compiled update would act ahead for nothing.
    assert lock.updater.ahead.enabled and not trainer_learner.updater.ahead.enabled
    outbox = Outbox('a0', 3, 1, batch_transitions=1, limit=100)
    for episode in range(4):
        seed = 7 if episode == 0 else None
        expected = run_episode(lock_env, lock, expert, seed=seed)
        got = run_split(split_env, actor, trainer, outbox, expert, seed)
        assert got.episode_return == expected.episode_return
        assert (got.advice_asked, got.advice_given) == (expected.advice_asked, expected.advice_given)
    assert lock.advice_total.given > 0  # the gates fired and advice went to D_advising
    assert trainer_learner.updates == lock.updates > 100
    assert len(trainer_learner.advice_replay) == len(lock.advice_replay) > 0
    for a, b in zip(lock.actor.state_dict().values(), trainer_learner.actor.state_dict().values()):
        assert torch.equal(a, b)
    for a, b in zip(lock.critic_target.state_dict().values(), trainer_learner.critic_target.state_dict().values()):
        assert torch.equal(a, b)
    assert trainer_learner.episode == lock.episode == 4
    assert len(actor.replay) == 0  # the actor stores nothing itself


def test_updates_keep_the_ratio_once_learning_starts():
    trainer = Trainer(pendulum_learner(learning_starts=10), updates_per_transition=0.5, weights_every=5)
    outbox = Outbox('a', 3, 1, batch_transitions=7, limit=100)
    for i in range(30):
        outbox.add([0.1, 0.2, float(i)], [0.0], -1.0, [0.1, 0.2, i + 1.0], False, i % 3 == 0)
    outbox.seal()
    while (batch := outbox.pop_oldest()) is not None:
        trainer.receive(batch)
    # 30 stored, the 10th filled D to learning_starts: 21 eligible, half of them due.
    assert trainer.eligible == 21
    assert trainer.updates_owed() == 10
    for _ in range(trainer.updates_owed()):
        trainer.update()
    assert trainer.updates_owed() == 0 and trainer.learner.updates == 10
    assert trainer.weights_due()
    trainer.weights_sent()
    assert not trainer.weights_due()
    assert len(trainer.learner.advice_replay) == 10  # i % 3 == 0: advised, also in D_advising


def test_a_bad_batch_is_refused_whole():
    trainer = Trainer(pendulum_learner())
    n = 4
    good = dict(
        observations=np.zeros((n, 3), np.float32),
        actions=np.zeros((n, 1), np.float32),
        rewards=np.zeros(n, np.float32),
        next_observations=np.zeros((n, 3), np.float32),
        terminated=np.zeros(n, bool),
        advised=np.zeros(n, bool),
    )
    wrong_size = {**good, 'observations': np.zeros((n, 8), np.float32)}
    with pytest.raises(ValueError, match='observations of actor .a. has shape'):
        trainer.receive(TransitionBatch('a', 0, **wrong_size))
    nan = {**good, 'rewards': np.array([0, 0, np.nan, 0], np.float32)}
    with pytest.raises(ValueError, match='non-finite'):
        trainer.receive(TransitionBatch('a', 1, **nan))
    assert len(trainer.learner.replay) == 0 and trainer.learner.total_steps == 0
    assert trainer.rejected_batches == 2
    trainer.receive(TransitionBatch('a', 2, **good))
    assert len(trainer.learner.replay) == n and trainer.sequences.lost == 0


def test_episode_rows_count_over_all_actors():
    trainer = Trainer(pendulum_learner())
    summary = EpisodeSummary(5, -100.0, 10, 2, 1, 1, 1, 0, False, 10, 0.2, human_time_s=1.5)
    rows = [trainer.add_episode(summary), trainer.add_episode(summary)]
    assert [r.episode for r in rows] == [0, 1]  # the trainer's index, not the actor's 5
    assert rows[1].human_time_total_s == 3.0
    assert trainer.learner.advice_total.given == 2 and trainer.learner.episode == 2
    assert TRAINER_CSV_FIELDS[-1] == 'actor'


def test_outbox_seals_at_size_and_episode_end_and_drops_the_oldest_past_its_limit():
    outbox = Outbox('a', 2, 1, batch_transitions=3, limit=7)
    for i in range(2):
        outbox.add([i, i], [0.0], 0.0, [i, i], False, False)
    assert not outbox.sealed and outbox.waiting == 2 and outbox.age() >= 0.0
    outbox.end_episode(EpisodeSummary(0, 0.0, 2, 0, 0, 0, 0, 0, False, 2, 0.2))
    assert [len(b) for b in outbox.sealed] == [2] and len(outbox.sealed[0].episodes) == 1
    for i in range(9):  # three more batches of 3: 11 waiting, over the limit of 7
        outbox.add([i, i], [0.0], 0.0, [i, i], False, False)
    assert [b.sequence for b in outbox.sealed] == [2, 3]  # 0 and 1 dropped, oldest first
    assert (outbox.dropped_batches, outbox.dropped_transitions, outbox.dropped_episodes) == (2, 5, 1)
    assert outbox.pop_oldest().sequence == 2 and outbox.waiting == 6 and outbox.unsent == 6  # kept until saved
    outbox.acknowledge(received_through=2, saved_through=1)
    assert outbox.waiting == 6 and outbox.unsent == 3  # stored, not yet saved: still kept
    outbox.acknowledge(received_through=2, saved_through=2)
    assert outbox.waiting == 3 and outbox.unsent == 3
    with pytest.raises(ValueError):
        Outbox('a', 2, 1, batch_transitions=10, limit=5)


def test_sequences_store_each_batch_once_in_order_and_count_only_what_the_actor_let_go():
    tracker = SequenceTracker()
    # oldest_kept: the oldest batch the actor still holds (everything before it is gone).
    assert tracker.receive('a', 4, oldest_kept=4) == 'first'  # a trainer that joins late starts there
    assert tracker.receive('a', 5, oldest_kept=4) == 'next'
    assert tracker.receive('a', 9, oldest_kept=4) == 'ahead'  # 6-8 missing: not stored yet
    assert tracker.receive('a', 6, oldest_kept=4) == 'next' and tracker.receive('a', 6, oldest_kept=4) == 'duplicate'
    assert tracker.receive('a', 9, oldest_kept=8) == 'ahead'  # the actor let 7 go (its bound): lost
    assert tracker.actors['a'].expected == 8 and tracker.lost == 1
    assert tracker.receive('a', 8, oldest_kept=8) == 'next'
    assert tracker.receive('b', 3, run='b1', oldest_kept=0) == 'ahead'  # a new actor's stream starts at 0
    assert tracker.receive('b', 0, run='b1', oldest_kept=0) == 'first'
    assert tracker.receive('a', 0, run='a2', oldest_kept=0) == 'restart'
    assert tracker.lost == 1 and tracker.actors['a'].restarts == 1 and tracker.actors['a'].duplicates == 1
    # A sender that says nothing of what it keeps keeps nothing: a gap is lost at once.
    assert tracker.receive('c', 2) == 'first' and tracker.receive('c', 5) == 'gap' and tracker.lost == 3


class Link:
    """An actor's outbox and a trainer on a simulated clock, as the nodes drive them: 50 steps a
    second in batches of 5, at most SEND_AT_ONCE batches sent per 0.1 s tick, each batch answered
    by an acknowledgement, and the actor's flush timer probing a silent trainer. ``up(t)`` says
    whether the link carries what is sent at time t (both ways); a checkpoint every 5 s."""

    def __init__(self, up, loss=0.0, seed=0):
        self.rng = np.random.default_rng(seed)
        self.outbox = Outbox('a', 3, 1, batch_transitions=5, limit=1_000_000, run='r1')
        self.trainer = Trainer(pendulum_learner(replay_capacity=20_000))
        self.up, self.loss = up, loss
        self.now, self.last_ack, self.last_probe = 0.0, 0.0, 0.0
        self.made = {'transitions': 0, 'episodes': 0}
        self.sent = 0  # transitions published, first time or again
        self.rows, self.saved = [], None

    def carries(self) -> bool:
        return self.up(self.now) and self.rng.random() >= self.loss

    def tick(self, steps=5):
        from eqhrl_ros.core.data.transitions import ACK_WAIT_S
        from eqhrl_ros.nodes.trainer_msgs import SEND_AT_ONCE

        outbox, made = self.outbox, self.made
        for _ in range(steps):
            number = float(made['transitions'])  # each transition's own number, as its observation
            made['transitions'] += 1
            outbox.add([number, 0.0, 0.0], [0.0], 0.0, [number, 0.0, 0.0], False, False)
            if made['transitions'] % 40 == 0:  # an episode ends: its number travels in human_time_s
                outbox.end_episode(EpisodeSummary(0, 0.0, 1, 0, 0, 0, 0, 0, False, 1, 0.2, False, made['episodes']))
                made['episodes'] += 1
        if self.now - self.last_ack >= ACK_WAIT_S and self.now - self.last_probe >= ACK_WAIT_S:
            if outbox.probe(self.now):
                self.last_probe = self.now
        for _ in range(SEND_AT_ONCE):
            batch = outbox.pop_oldest(self.now)
            if batch is None:
                break
            self.sent += len(batch)
            if not self.carries():
                continue
            verdict, rows, _ = self.trainer.receive(batch)
            assert verdict != 'gap'  # nothing let go: the actor's bound is not reached here
            self.rows += [row for row, _ in rows]
            if self.carries():  # the acknowledgement crosses the same link
                state = self.trainer.sequences.actors['a']
                highest, missing = self.trainer.missing('a')
                outbox.acknowledge(state.received_through, state.saved_through, missing, highest, self.now)
                self.last_ack = self.now
        if int(self.now * 10) % 50 == 0:  # a checkpoint: the replay memory, the record and the streams
            trainer = self.trainer
            self.saved = (trainer.sequences.state_dict(), trainer.learner.replay.state_dict(), list(self.rows))
            trainer.sequences.saved(self.saved[0])
        self.now = round(self.now + 0.1, 6)

    def restart_trainer(self):
        """The trainer is killed (-9) and resumed from its last checkpoint; the actor takes the new
        trainer's weights."""
        sequences, replay, rows = self.saved
        self.trainer = Trainer(pendulum_learner(replay_capacity=20_000))
        self.trainer.learner.replay.load_state_dict(replay)
        self.trainer.sequences.load_state_dict(sequences)
        self.rows = list(rows)
        self.outbox.new_trainer()
        self.last_ack = self.last_probe = -1e9  # as the actor node does for a new trainer

    def settle(self, seconds=20.0):
        """The env stops; the flush timer seals the last batch and the link does the rest."""
        self.outbox.seal()
        for _ in range(int(seconds * 10)):
            self.tick(steps=0)

    def check_exactly_once(self):
        replay = self.trainer.learner.replay
        stored = sorted(replay.rows[: len(replay), :].numpy()[:, 0].tolist())  # each observation's first value
        assert stored == [float(i) for i in range(self.made['transitions'])]  # every one, once
        assert sorted(r.human_time_s for r in self.rows) == [float(i) for i in range(self.made['episodes'])]
        assert self.trainer.sequences.lost == 0 and self.outbox.dropped_batches == 0

    @property
    def ratio(self) -> float:
        return self.sent / self.made['transitions']


def test_every_batch_reaches_d_once_through_a_lossy_link_and_a_trainer_killed_and_resumed():
    """The actor keeps each batch until a trainer's checkpoint holds it; a trainer holds what comes
    past a missing batch and asks for what it lacks. Through 30 % of batches (and of their
    acknowledgements) lost and a trainer that dies and resumes from its last checkpoint, every
    transition reaches D exactly once, and every episode the record exactly once."""
    link = Link(up=lambda t: True, loss=0.3)
    for _ in range(120):
        link.tick()
    link.loss = 0.0
    for _ in range(60):
        link.tick()
    link.loss = 0.3
    for _ in range(33):
        link.tick()  # stored after the checkpoint at 20 s, then the trainer is killed: all of it is gone
    link.restart_trainer()
    for _ in range(100):
        link.tick()
    link.loss = 0.0
    link.settle()
    link.check_exactly_once()
    assert link.outbox.resent_batches > 0


@pytest.mark.parametrize('restart', [False, True])
def test_a_30_s_cut_and_a_trainer_restart_cost_what_was_lost_not_what_came_after(restart):
    """Selective repeat: after a 30 s cut (and a trainer killed 10 s after it, resumed from its
    checkpoint) the actor sends again what the trainer lacks, and little it has: over 5 minutes of
    50 steps a second, under 1.2 transitions go out per transition stepped (go-back-N sent 5.3
    on the real link). No DDS here: every batch sent into the cut is lost, the worst case."""
    link = Link(up=lambda t: not 30.0 <= t < 60.0)
    for _ in range(3000):
        link.tick()
        if restart and link.now == 70.0:
            link.restart_trainer()
    link.settle()
    link.check_exactly_once()
    stepped, cut = link.made['transitions'], 30 * 50  # what the cut swallowed had to go again
    # A restart also costs what was stored after the last checkpoint (at most 5 s of steps).
    lost = cut + (5 * 50 if restart else 0)
    print(f'restart={restart}: {link.sent} sent for {stepped} stepped ({link.ratio:.3f}x), {lost} lost at most')
    assert stepped + cut <= link.sent <= stepped + 1.1 * lost
    assert link.ratio < 1.2


def test_weights_travel_whole_or_not_at_all():
    source, target = pendulum_learner(seed=1), pendulum_learner(seed=2)
    data = encode_weights(source)
    assert data[:8] != b'\x80\x02\x8a\n' and b'actor.' in data[:4096]  # safetensors' JSON header, not pickle
    before = [t.clone() for t in target.actor.state_dict().values()]

    with pytest.raises(WeightsError, match='not safetensors'):
        apply_weights(target, b'\x80\x04garbage')
    with pytest.raises(WeightsError, match='other hidden_sizes'):
        apply_weights(target, encode_weights(pendulum_learner(hidden=(16, 16))))
    poisoned = pendulum_learner(seed=1)
    with torch.no_grad():
        next(poisoned.critic.parameters()).view(-1)[0] = float('nan')
    with pytest.raises(WeightsError, match='non-finite'):
        apply_weights(target, encode_weights(poisoned))
    assert all(torch.equal(a, b) for a, b in zip(before, target.actor.state_dict().values()))

    apply_weights(target, data)
    for a, b in zip(source.critic.state_dict().values(), target.critic.state_dict().values()):
        assert torch.equal(a, b)
    obs = [0.3, -0.2, 0.5]
    assert np.array_equal(source.act(obs, deterministic=True), target.act(obs, deterministic=True))


def test_an_actor_step_counts_but_stores_nothing():
    actor = pendulum_learner()
    obs = [1.0, 0.0, 0.0]
    with pytest.raises(ValueError, match='non-finite'):
        actor.step(obs, [0.5], float('nan'), obs, False, False, learn=False)
    assert actor.total_steps == 0
    summary = actor.step(obs, [0.5], -1.0, obs, False, True, learn=False)
    assert summary.length == 1 and summary.episode_return == -1.0
    assert len(actor.replay) == 0 and actor.updates == 0


def _batch(actor='a', sequence=0, n=10, episodes=(), **values):
    fields = dict(
        observations=np.zeros((n, 3), np.float32),
        actions=np.zeros((n, 1), np.float32),
        rewards=np.zeros(n, np.float32),
        next_observations=np.zeros((n, 3), np.float32),
        terminated=np.zeros(n, bool),
        advised=np.ones(n, bool),
    )
    fields.update(values)
    return TransitionBatch(actor, sequence, episodes=list(episodes), **fields)


def test_batches_past_a_missing_one_are_held_and_stored_in_order_when_it_comes():
    trainer = Trainer(pendulum_learner())
    assert trainer.receive(_batch(oldest_kept=0, sequence=0)).verdict == 'first'
    for sequence in (3, 2, 5):
        assert trainer.receive(_batch(oldest_kept=0, sequence=sequence), payload=f'm{sequence}').verdict == 'ahead'
    assert trainer.missing('a') == (5, [1, 4]) and len(trainer.learner.replay) == 10
    with pytest.raises(ValueError, match='reach 1e[+]30'):  # 4 is refused for what it holds: never stored
        trainer.receive(_batch(oldest_kept=0, sequence=4, actions=np.full((10, 1), 1e30, np.float32)))
    assert trainer.missing('a') == (5, [1])
    receipt = trainer.receive(_batch(oldest_kept=0, sequence=1), payload='m1')
    assert receipt.verdict == 'next' and receipt.stored == ['m1', 'm2', 'm3', 'm5']  # 4 passed over
    assert trainer.sequences.actors['a'].expected == 6 and len(trainer.learner.replay) == 50
    assert trainer.missing('a') == (5, []) and trainer.receive(_batch(oldest_kept=0, sequence=3)).verdict == 'duplicate'
    # A new run of the actor: what was held of the old one goes, refused ones included.
    trainer.receive(_batch(oldest_kept=0, sequence=9))
    with pytest.raises(ValueError):
        trainer.receive(_batch(oldest_kept=0, sequence=8, rewards=np.full(10, 1e9, np.float32)))
    trainer.receive(_batch(oldest_kept=0, sequence=1, run='r2'))
    assert list(trainer.held['a']) == [1] and trainer.missing('a') == (1, [0])


def test_an_actor_sends_again_only_what_the_trainer_names_missing_and_each_once_a_second():
    outbox = Outbox('a', 3, 1, batch_transitions=1, limit=100)
    for _ in range(6):
        outbox.add([0.0] * 3, [0.0], 0.0, [0.0] * 3, False, False)
    assert [outbox.pop_oldest(now=0.0).sequence for _ in range(6)] == list(range(6))
    assert outbox.acknowledge(0, -1, missing=[1, 3], highest_received=4, now=0.5) == 0  # sent 0.5 s ago
    assert outbox.acknowledge(0, -1, missing=[1, 3], highest_received=4, now=1.0) == 2
    assert [outbox.pop_oldest(now=1.0).sequence for _ in range(2)] == [1, 3] and outbox.pop_oldest(1.0) is None
    assert outbox.acknowledge(0, -1, missing=[1, 3], highest_received=4, now=1.5) == 0  # just sent again
    # 5 was sent 2 s ago and nothing covers it: it went into a cut; 2 and 4 the trainer holds.
    assert outbox.acknowledge(3, -1, missing=[], highest_received=4, now=2.0) == 1
    assert outbox.pop_oldest(now=2.0).sequence == 5 and outbox.resent_batches == 3
    # A silent trainer gets one probe: the oldest batch it has not stored.
    assert outbox.probe(now=3.0) == 1 and outbox.pop_oldest(now=3.0).sequence == 4
    assert outbox.probe(now=3.5) == 0  # just sent: not again before ACK_WAIT_S


@pytest.mark.parametrize(
    'values,problem',
    [
        ({'actions': np.full((10, 1), 1e30, np.float32)}, 'actions .* reach 1e[+]30'),
        ({'actions': np.full((10, 1), 1.01, np.float32)}, 'actions .* reach 1.01'),
        ({'observations': np.full((10, 3), 1e7, np.float32)}, 'observations .* beyond 1e[+]06'),
        ({'rewards': np.full(10, -1e5, np.float32)}, 'rewards .* beyond 10000'),
    ],
    ids=['action 1e30', 'action outside bounds', 'observation 1e7', 'reward 1e5'],
)
def test_finite_but_impossible_transitions_are_refused_whole(values, problem):
    trainer = Trainer(pendulum_learner())
    with pytest.raises(ValueError, match=problem):
        trainer.receive(_batch(**values))
    assert len(trainer.learner.replay) == len(trainer.learner.advice_replay) == 0
    assert trainer.rejected_batches == 1
    # It will never be stored, so the stream moves past it: its actor does not send it for ever.
    assert trainer.sequences.actors['a'].expected == 1 and trainer.sequences.lost == 0
    assert trainer.receive(_batch(sequence=1))[0] == 'next' and len(trainer.learner.replay) == 10


def _summary(**changes):
    good = dict(
        episode=0,
        episode_return=-100.0,
        length=10,
        advice_asked=2,
        advice_given=1,
        advice_human=0,
        advice_declined=1,
        advice_failed=0,
        success=False,
        total_steps=10,
        alpha=0.2,
    )
    return EpisodeSummary(**{**good, **changes})


@pytest.mark.parametrize(
    'changes',
    [
        {'episode_return': float('nan')},
        {'length': -5},
        {'advice_asked': 2147483647},
        {'advice_given': 3},
        {'advice_human': 2},
        {'human_time_s': float('inf')},
        {'human_time_s': -1.0},
        {'advice_asked': 2**40, 'length': 2**41},
    ],
)
def test_episode_statistics_that_cannot_be_are_refused_with_their_batch(changes):
    trainer = Trainer(pendulum_learner())
    with pytest.raises(ValueError):
        trainer.receive(_batch(episodes=[_summary(**changes)]))
    assert trainer.learner.episode == 0 and len(trainer.learner.replay) == 0
    _, rows, _ = trainer.receive(_batch(sequence=1, episodes=[_summary()]))
    assert [r.episode for r, _ in rows] == [0] and trainer.learner.episode == 1


def test_a_batch_ending_more_episodes_than_it_has_transitions_is_refused():
    trainer = Trainer(pendulum_learner())
    with pytest.raises(ValueError, match='10000 episodes end in a batch of 4'):
        trainer.receive(
            _batch(n=4, episodes=[_summary(length=1, advice_asked=0, advice_given=0, advice_declined=0)] * 10_000)
        )
    assert trainer.learner.episode == 0  # the budget counts these: no jump from 11 to 10,023
    trainer.receive(_batch(sequence=1, n=0, episodes=[_summary()]))  # its last step went in the batch before
    assert trainer.learner.episode == 1


def test_a_forged_sequence_number_counts_no_loss_and_is_refused():
    trainer = Trainer(pendulum_learner())
    for sequence in range(3):
        trainer.receive(_batch(sequence=sequence))
    with pytest.raises(ValueError, match='past the next one due'):
        trainer.receive(_batch(sequence=2**64 - 1))
    assert trainer.sequences.lost == 0
    assert trainer.receive(_batch(sequence=3))[0] == 'next'


def test_an_update_that_makes_the_networks_non_finite_is_undone():
    trainer = Trainer(pendulum_learner(learning_starts=10))
    trainer.receive(_batch(n=20))
    trainer.update()
    trainer.keep_finite()  # as when weights go out
    kept = {k: v.clone() for k, v in trainer.learner.actor.state_dict().items()}
    # Poison that got past the checks (as it did before them): huge rewards, stored directly.
    for _ in range(300):
        trainer.learner.store(np.zeros(3), np.zeros(1), 3e38, np.zeros(3), False, True)
    for _ in range(3):
        info = trainer.update()
    assert info.get('restored') and trainer.restored >= 1
    assert trainer.networks_finite()
    assert all(torch.equal(v, kept[k]) for k, v in trainer.learner.actor.state_dict().items())
    assert trainer.learner.updates == 4  # counters go on: the update happened, its result was undone


def test_an_actor_follows_the_trainer_it_joined_and_no_stranger_beside_it():
    from eqhrl_ros.core.data.weights import TrainerPin

    pin = TrainerPin()
    assert pin.judge('real', 0, 0, 0, alone=True) == 'apply'
    pin.applied('real', 0)
    assert 'still publishes' in pin.judge('rogue', 5, 0, 0, alone=False)  # a stranger beside the real one
    assert pin.judge('real', 50, 3, 3, alone=False) == 'apply'
    pin.applied('real', 50)
    assert pin.judge('real', 50, 3, 3, alone=False) == 'stale' and pin.judge('real', 10, 3, 3, alone=False) == 'stale'
    assert 'jumps' in pin.judge('real', 2**63, 3, 3, alone=False)  # locked the real trainer out before
    assert 'episode count' in pin.judge('real', 100, 2**31, 3, alone=False)  # int32 wrap, budget ended
    assert 'episode count' in pin.judge('real', 100, 10**7, 3, alone=False)
    # The real trainer restarted (a new id, and the old one left the graph): followed again.
    assert pin.judge('real-2', 0, 3, 3, alone=True) == 'apply'


def test_a_named_trainer_is_the_only_one_followed():
    from eqhrl_ros.core.data.weights import TrainerPin

    pin = TrainerPin('lab-trainer')
    assert 'follows' in pin.judge('rogue', 1, 0, 0, alone=True)
    assert pin.judge('lab-trainer', 1, 0, 0, alone=False) == 'apply'
    pin.name('')  # the person lets the next trainer that publishes alone take over
    assert pin.judge('next', 0, 0, 0, alone=True) == 'apply'


def test_weights_travel_as_float16_and_arrive_as_float32():
    """weights_on_wire float16: half the bytes; the actor's networks stay float32, within float16's
    rounding of the trainer's."""
    source, target = pendulum_learner(), pendulum_learner()
    wide, narrow = encode_weights(source), encode_weights(source, 'float16')
    assert len(narrow) < 0.55 * len(wide)  # the names and shapes (its JSON header) stay
    apply_weights(target, narrow)
    for network in ('actor', 'critic'):
        mine, theirs = getattr(target, network).state_dict(), getattr(source, network).state_dict()
        for key, value in mine.items():
            assert value.dtype == theirs[key].dtype
            assert torch.allclose(value, theirs[key], rtol=1e-3, atol=1e-4), key


def camera_learner(stack: int = 2, seed: int = 0) -> EQSACLearner:
    from eqhrl_ros.core.envs.spec import CameraSpec

    config = LearnerConfig(mode='eqsac', hidden=(16, 16), batch_size=8, learning_starts=8, seed=seed)
    return EQSACLearner(2, [-2.0], [2.0], config, camera=CameraSpec(16, 16, 1, stack))


def test_a_camera_learners_weights_carry_its_encoder_and_a_learner_without_one_refuses_them():
    trainer, actor = camera_learner(seed=1), camera_learner(seed=2)
    apply_weights(actor, encode_weights(trainer))
    for mine, theirs in ((actor.observation.encoder, trainer.observation.encoder), (actor.actor, trainer.actor)):
        assert all(torch.equal(a, b) for a, b in zip(mine.state_dict().values(), theirs.state_dict().values()))
    with pytest.raises(WeightsError, match=r"unexpected tensors \['encoder\."):
        apply_weights(
            EQSACLearner(2, [-2.0], [2.0], LearnerConfig(mode='eqsac', hidden=(16, 16))), encode_weights(trainer)
        )
    with pytest.raises(WeightsError, match='no encoder tensors in these weights'):
        apply_weights(
            actor, encode_weights(EQSACLearner(2, [-2.0], [2.0], LearnerConfig(mode='eqsac', hidden=(16, 16))))
        )


def framed_batch(stack: int, size: int = 16, n: int = 4) -> TransitionBatch:
    from eqhrl_ros.core.data.transitions import BatchFrames

    frames = np.random.default_rng(0).integers(0, 256, (n + stack, size, size, 1), dtype=np.uint8)
    stacks = np.stack([frames[t : t + stack] for t in range(n)])
    zeros = np.zeros((n, 2), np.float32)
    return _batch(
        n=n, observations=zeros, next_observations=zeros, frames=BatchFrames.of(stacks, frames[stack : stack + n])
    )


@pytest.mark.parametrize(
    'batch, problem',
    [
        (lambda: framed_batch(3), r"stacks of \(k, H, W, C\) = \(3, 16, 16, 1\); the trainer reads \(2, 16, 16, 1\)"),
        (lambda: framed_batch(2, size=17), r'sends stacks of .* = \(2, 17, 17, 1\)'),
        (lambda: _batch(n=4, observations=np.zeros((4, 2), np.float32), next_observations=np.zeros((4, 2), np.float32)),
         'sends no camera frames; the trainer learns from a camera'),
    ],
)  # fmt: skip
def test_a_camera_trainer_refuses_a_batch_of_another_camera_or_none_whole(batch, problem):
    trainer = Trainer(camera_learner(), updates_per_transition=1.0, weights_every=10)
    trainer.receive(framed_batch(2))
    assert len(trainer.learner.replay) == 4
    with pytest.raises(ValueError, match=problem):
        trainer.receive(dataclasses.replace(batch(), sequence=1))
    assert len(trainer.learner.replay) == 4


def test_a_step_beyond_the_limits_is_refused_saying_which_limit():
    """The learner and actors drop such a step where it arrives (nodes), as the trainer refuses a
    batch holding one (above): the same limits, the same defaults."""
    limits = StepLimits()
    assert limits.refusal(np.array([1e6, -1e6, 0.0]), -1e4) == ''
    assert 'beyond max_abs_observation 1e+06' in limits.refusal(np.array([0.0, -1.5e6]), 0.0)
    assert 'a reward of magnitude 3e+38 is beyond max_abs_reward 10000' in limits.refusal(np.zeros(3), 3e38)
    assert 'a reward of magnitude 2e+04' in limits.refusal(np.zeros((5, 3)), np.array([1.0, -2e4]))  # many
    assert limits.refusal(np.zeros(0), 0.0) == ''  # pixels alone: no state vector
    assert StepLimits(1e9, 1e9).refusal(np.array([1e7]), 1e5) == ''
