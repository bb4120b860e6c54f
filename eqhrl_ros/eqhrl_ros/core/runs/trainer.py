"""Trainer: Algorithm 1's learning half, fed by actor nodes instead of its own env.

Actor nodes act (the policy, D(s), E(s), the gates, the advice) and send every transition;
the trainer stores them in D, and advised ones in D_advising too, and updates at its own
pace: ``updates_per_transition`` updates per transition stored once D holds
``learning_starts`` (the lock-step learner makes ``updates_per_step`` per env step from the
same moment), so that learning matches Algorithm 1 in expectation. Each update is
EQSACLearner.update(), unchanged. No ROS here (nodes/trainer_node.py is the adapter).
"""

from __future__ import annotations

import copy
import dataclasses
import math
from typing import NamedTuple, Optional

import numpy as np
import torch

from ..algorithm.advice_counts import AdviceCounts
from ..algorithm.learner import EQSACLearner
from ..algorithm.learner_state import NETWORK_STATE
from ..algorithm.updater import non_finite
from ..data.summary import EpisodeSummary
from ..data.transitions import MAX_HELD_BATCHES, MAX_MISSING, STORED, SequenceTracker, StepLimits, TransitionBatch

# episodes.csv of a trainer: a learner's columns and the actor each episode came from.
TRAINER_CSV_FIELDS = (*EpisodeSummary.CSV_FIELDS, 'actor')

# What a batch may hold, checked by meaning before anything of it is stored (a finite value can
# still be absurd: ten actions of 1e30 made every network NaN). Actions are normalised to [-1, 1];
# the tolerance covers float32 rounding of the actor's own mapping.
ACTION_TOLERANCE = 1e-3
INT32_MAX = 2**31 - 1
# A batch numbered this far past the last one of its actor is not a gap but a forgery (an actor
# that really lost that many batches of 50 transitions would have lost a day at 1 kHz).
MAX_SEQUENCE_JUMP = 1_000_000


class Receipt(NamedTuple):
    """What Trainer.receive made of a batch: its verdict, the episode rows it ended (with their
    actor), and what was stored by this call, in order: the batch's payload, then those of the
    batches held past it that it let through."""

    verdict: str
    rows: list
    stored: list


class Trainer:
    def __init__(
        self,
        learner: EQSACLearner,
        updates_per_transition: float = 1.0,
        weights_every: int = 50,
        limits: StepLimits = StepLimits(),
    ):
        if not updates_per_transition > 0:
            raise ValueError(f'updates_per_transition must be > 0, got {updates_per_transition}')
        if weights_every < 1:
            raise ValueError(f'weights_every must be >= 1, got {weights_every}')
        self.learner = learner
        # A trainer's learner never proposes (its actors act): its compiled update does not act ahead.
        learner.updater.ahead.enabled = False
        self.limits = limits
        self.updates_per_transition = float(updates_per_transition)
        self.weights_every = int(weights_every)
        self.sequences = SequenceTracker()
        # Transitions stored in this run while D held at least learning_starts: Algorithm 1
        # makes its updates after each of those (and none before).
        self.eligible = 0
        self.updates_here = 0  # updates made by this run (a resumed one starts at 0)
        self.rejected_batches = 0
        self.weights_at = None  # learner.updates when weights last went out
        self.restored = 0  # updates undone because they made the networks non-finite
        # Batches past a missing one, per actor: {sequence: (run, batch, payload)}; batch None for
        # one refused for what it holds (never stored; the stream moves past it when it is due).
        self.held: dict[str, dict[int, tuple]] = {}
        self._finite: Optional[dict] = None  # the networks and optimisers as they last were known finite

    def receive(self, batch: TransitionBatch, payload=None) -> Receipt:
        """Store a batch, and the ones held past it that it lets through. Only the batch due from
        its actor is stored at once (transitions.SequenceTracker); one past a missing batch is
        held (at most MAX_HELD_BATCHES an actor) until the missing ones come; one stored already
        is dropped. ``payload`` (the message, say) is what ``Receipt.stored`` lists for each
        batch stored (the batch itself by default).

        A batch with wrong sizes, a non-finite value, a value that cannot be (an action outside
        its bounds, an absurd magnitude, episode statistics that contradict themselves) or a
        forged sequence number raises ValueError and stores and counts nothing of it.
        """
        state = self.sequences.actors.get(batch.actor)
        if state is not None and state.run == batch.run and batch.sequence - state.expected > MAX_SEQUENCE_JUMP:
            self.rejected_batches += 1  # a forged number: the stream does not move
            raise ValueError(f'batch {batch.sequence} is {batch.sequence - state.expected} past the next one due')
        try:
            self._check(batch)
        except ValueError:
            self.rejected_batches += 1
            # Refused for what it holds, it will never be stored: the stream moves past it (else its
            # actor would send it again for ever, and nothing after it would be stored).
            verdict = self.sequences.receive(batch.actor, batch.sequence, batch.run, batch.oldest_kept)
            self._forget_held(batch.actor)
            if verdict == 'ahead':
                self._hold(batch.actor, batch.sequence, (batch.run, None, None))
            else:
                self._let_through(batch.actor, [], [])
            raise
        verdict = self.sequences.receive(batch.actor, batch.sequence, batch.run, batch.oldest_kept)
        self._forget_held(batch.actor)
        rows: list = []
        stored: list = []
        if verdict == 'ahead':
            self._hold(batch.actor, batch.sequence, (batch.run, batch, payload))
        elif verdict in STORED:
            self._store(batch, payload, rows, stored)
            self._let_through(batch.actor, rows, stored)
        return Receipt(verdict, rows, stored)

    def _store(self, batch: TransitionBatch, payload, rows: list, stored: list) -> None:
        learner = self.learner
        starts = learner.config.learning_starts
        frames = batch.frames
        if frames is not None:
            stacks, following = frames.observation_stacks(), frames.frames[frames.next_frames]
            # A transition goes on from the one before it in the batch when its stack is that one's
            # less the oldest, then that one's next frame (by index): not at an episode's start.
            index = frames.observation_frames
            chained = np.concatenate([index[:-1, 1:], frames.next_frames[:-1, None]], axis=1)
            follows = np.concatenate([[False], (index[1:] == chained).all(axis=1)])
        for i in range(len(batch)):
            values = (batch.observations[i], batch.actions[i], float(batch.rewards[i]), batch.next_observations[i])
            if frames is None:
                learner.store(*values, bool(batch.terminated[i]), bool(batch.advised[i]))
            else:
                learner.memories.store_framed(
                    *values, bool(batch.terminated[i]), bool(batch.advised[i]), stacks[i], following[i], follows[i]
                )
            learner.tally.total_steps += 1  # env steps over all actors
            if len(learner.replay) >= starts:
                self.eligible += 1
        rows += [(self.add_episode(summary), batch.actor) for summary in batch.episodes]
        stored.append(batch if payload is None else payload)

    def _hold(self, actor: str, sequence: int, entry) -> None:
        held = self.held.setdefault(actor, {})
        if len(held) < MAX_HELD_BATCHES or sequence < max(held):
            held[sequence] = entry
            while len(held) > MAX_HELD_BATCHES:
                del held[max(held)]  # the furthest ahead goes: asked for again later

    def _forget_held(self, actor: str) -> None:
        """Held batches of another run of the actor, or already passed, are dropped."""
        held, state = self.held.get(actor), self.sequences.actors.get(actor)
        if not held or state is None:
            return
        for sequence in [s for s, (run, _, _) in held.items() if s < state.expected or run != state.run]:
            del held[sequence]

    def _let_through(self, actor: str, rows: list, stored: list) -> None:
        """The held batches that are now due, in order."""
        held, state = self.held.get(actor), self.sequences.actors[actor]
        while held and state.expected in held:
            _, batch, payload = held.pop(state.expected)
            self.sequences.receive(actor, state.expected, state.run, state.expected)
            if batch is not None:
                self._store(batch, payload, rows, stored)

    def missing(self, actor: str) -> tuple[int, list[int]]:
        """(the highest batch of ``actor`` stored or held, the ones below it not here yet: at most
        MAX_MISSING, the oldest first)."""
        state = self.sequences.actors.get(actor)
        if state is None:
            return -1, []
        held = self.held.get(actor) or {}
        highest = max(held, default=state.received_through)
        gaps = []
        for sequence in range(state.expected, highest):
            if sequence not in held:
                gaps.append(sequence)
                if len(gaps) >= MAX_MISSING:
                    break
        return highest, gaps

    def _check(self, batch: TransitionBatch) -> None:
        n, obs_dim, action_dim = len(batch), self.learner.observation.state_dim, self.learner.action_dim
        shapes = {
            'observations': (batch.observations, (n, obs_dim)),
            'actions': (batch.actions, (n, action_dim)),
            'next_observations': (batch.next_observations, (n, obs_dim)),
            'terminated': (batch.terminated, (n,)),
            'advised': (batch.advised, (n,)),
        }
        for name, (values, shape) in shapes.items():
            if np.shape(values) != shape:
                raise ValueError(
                    f'{name} of actor {batch.actor!r} has shape {np.shape(values)}, the trainer expects {shape}'
                )
        for name in ('observations', 'actions', 'rewards', 'next_observations'):
            if not np.isfinite(getattr(batch, name)).all():
                raise ValueError(f'{name} of actor {batch.actor!r} hold a non-finite value (NaN or inf)')
        bounds = {
            'actions': 1.0 + ACTION_TOLERANCE,
            'observations': self.limits.max_abs_observation,
            'next_observations': self.limits.max_abs_observation,
            'rewards': self.limits.max_abs_reward,
        }
        for name, bound in bounds.items():
            values = getattr(batch, name)
            if values.size and float(np.abs(values).max()) > bound:
                raise ValueError(
                    f'{name} of actor {batch.actor!r} reach {float(np.abs(values).max()):.3g}, beyond {bound:g}'
                )
        camera = self.learner.observation.camera
        if (batch.frames is None) != (camera is None) and n:  # a batch of episode ends alone holds no frames
            has = 'sends no camera frames' if batch.frames is None else 'sends camera frames'
            raise ValueError(f'actor {batch.actor!r} {has}; the trainer learns {"from" if camera else "without"} a camera')
        if camera is not None and batch.frames is not None and (batch.frames.stack, *batch.frames.frames.shape[1:]) != (
            camera.stack, camera.height, camera.width, camera.channels
        ):
            shape = (batch.frames.stack, *batch.frames.frames.shape[1:])
            raise ValueError(
                f'actor {batch.actor!r} sends stacks of (k, H, W, C) = {shape}; the trainer reads '
                f'{(camera.stack, camera.height, camera.width, camera.channels)}'
            )
        if len(batch.episodes) > max(1, n):  # each episode ends with a transition of its batch
            raise ValueError(f'{len(batch.episodes)} episodes end in a batch of {n} transitions')
        for summary in batch.episodes:
            _check_episode(summary)

    def add_episode(self, summary: EpisodeSummary) -> EpisodeSummary:
        """An actor's finished episode as a row of the trainer's record: the index over all
        actors (what the advising budget counts), steps over all actors, the trainer's alpha."""
        learner = self.learner
        counts = AdviceCounts.from_summary(summary)  # failures by kind stay with the actors (the row has their total)
        return learner.tally.close(dataclasses.replace(summary, alpha=learner.alpha), counts)

    def updates_owed(self) -> int:
        """Updates due now to keep updates_per_transition."""
        return int(self.updates_per_transition * self.eligible + 1e-9) - self.updates_here

    def update(self) -> dict:
        """One update; one that leaves a loss or a network non-finite is undone: the networks and
        optimisers go back to their last finite state (the last weights sent) and it is counted."""
        info = self.learner.update()
        self.updates_here += 1
        if non_finite(info):
            self.restore_finite()
            info = {**info, 'restored': True}
        return info

    def networks_finite(self) -> bool:
        learner = self.learner
        tensors = [*learner.actor.parameters(), *learner.critic.parameters(), learner.log_alpha]
        return all(bool(torch.isfinite(t).all()) for t in tensors)

    def keep_finite(self) -> None:
        """Note the networks and optimisers as they are now (finite) as the state to go back to."""
        state = self.learner.state_dict()
        self._finite = {key: copy.deepcopy(state[key]) for key in NETWORK_STATE}

    def restore_finite(self) -> None:
        """The networks and optimisers as last kept; counters, queues and random streams stay."""
        self.restored += 1
        if self._finite is None:
            raise RuntimeError('an update made the networks non-finite before any finite state was kept')
        state = self.learner.state_dict()
        state.update({key: copy.deepcopy(value) for key, value in self._finite.items()})
        self.learner.load_state_dict(state)

    def weights_due(self) -> bool:
        """Time to send weights: never sent yet, or weights_every updates since."""
        return self.weights_at is None or self.learner.updates - self.weights_at >= self.weights_every

    def weights_sent(self) -> None:
        self.weights_at = self.learner.updates


def _check_episode(summary: EpisodeSummary) -> None:
    """Episode statistics an actor can have counted, or ValueError."""
    s = summary
    counts = (
        s.length,
        s.advice_asked,
        s.advice_given,
        s.advice_human,
        s.advice_declined,
        s.advice_failed,
        s.takeovers,
        s.takeover_steps,
        s.stops,
    )
    if any(not 0 <= c <= INT32_MAX for c in counts):
        raise ValueError(f'episode statistics out of range: {counts}')
    if s.advice_asked > s.length or s.takeover_steps > s.length or s.takeovers > s.takeover_steps:
        raise ValueError(
            f'an episode of {s.length} steps with {s.advice_asked} requests and {s.takeover_steps} steps taken over '
            f'in {s.takeovers} stretches'
        )
    if s.advice_given + s.advice_declined + s.advice_failed > s.advice_asked or s.advice_human > s.advice_given:
        raise ValueError(
            f'advice given {s.advice_given} (by a person {s.advice_human}), declined {s.advice_declined} and '
            f'failed {s.advice_failed} of {s.advice_asked} asked'
        )
    if not (
        math.isfinite(s.episode_return)
        and all(math.isfinite(t) and t >= 0 for t in (s.human_time_s, s.takeover_s, s.stopped_s))
    ):
        raise ValueError(
            f"return {s.episode_return}, a person's time {s.human_time_s} s or {s.stopped_s} s stopped that cannot be"
        )
