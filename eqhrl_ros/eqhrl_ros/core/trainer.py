"""Trainer: Algorithm 1's learning half, fed by actor nodes instead of its own env.

Actor nodes act (the policy, D(s), E(s), the gates, the advice) and send every transition;
the trainer stores them in D, and advised ones in D_advising too, and updates at its own
pace: ``updates_per_transition`` updates per transition stored once D holds
``learning_starts`` (the lock-step learner makes ``updates_per_step`` per env step from the
same moment), so that learning matches Algorithm 1 in expectation. Each update is
EQSACLearner.update(), unchanged. No ROS here (nodes/trainer_node.py is the adapter).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .learner import AdviceCounts, EQSACLearner
from .summary import EpisodeSummary
from .transitions import SequenceTracker, TransitionBatch

# episodes.csv of a trainer: a learner's columns and the actor each episode came from.
TRAINER_CSV_FIELDS = (*EpisodeSummary.CSV_FIELDS, 'actor')


class Trainer:
    def __init__(self, learner: EQSACLearner, updates_per_transition: float = 1.0, weights_every: int = 50):
        if not updates_per_transition > 0:
            raise ValueError(f'updates_per_transition must be > 0, got {updates_per_transition}')
        if weights_every < 1:
            raise ValueError(f'weights_every must be >= 1, got {weights_every}')
        self.learner = learner
        self.updates_per_transition = float(updates_per_transition)
        self.weights_every = int(weights_every)
        self.sequences = SequenceTracker()
        # Transitions stored in this run while D held at least learning_starts: Algorithm 1
        # makes its updates after each of those (and none before).
        self.eligible = 0
        self.updates_here = 0  # updates made by this run (a resumed one starts at 0)
        self.rejected_batches = 0
        self.weights_at = None  # learner.updates when weights last went out

    def receive(self, batch: TransitionBatch) -> tuple[str, list[tuple[EpisodeSummary, str]]]:
        """Store a batch: (what its sequence number says, [(episode row, actor)]).

        A batch with wrong sizes or a non-finite value raises ValueError and stores nothing.
        """
        verdict = self.sequences.receive(batch.actor, batch.sequence)
        try:
            self._check(batch)
        except ValueError:
            self.rejected_batches += 1
            raise
        learner = self.learner
        starts = learner.config.learning_starts
        for i in range(len(batch)):
            learner.store(
                batch.observations[i],
                batch.actions[i],
                float(batch.rewards[i]),
                batch.next_observations[i],
                bool(batch.terminated[i]),
                bool(batch.advised[i]),
            )
            learner.total_steps += 1  # env steps over all actors
            if len(learner.replay) >= starts:
                self.eligible += 1
        return verdict, [(self.add_episode(summary), batch.actor) for summary in batch.episodes]

    def _check(self, batch: TransitionBatch) -> None:
        n, obs_dim, action_dim = len(batch), self.learner.obs_dim, self.learner.action_dim
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

    def add_episode(self, summary: EpisodeSummary) -> EpisodeSummary:
        """An actor's finished episode as a row of the trainer's record: the index over all
        actors (what the advising budget counts), steps over all actors, the trainer's alpha."""
        learner = self.learner
        counts = AdviceCounts(
            asked=summary.advice_asked,
            given=summary.advice_given,
            human=summary.advice_human,
            declined=summary.advice_declined,
            human_time_s=summary.human_time_s,
        )
        row = dataclasses.replace(
            summary,
            episode=learner.episode,
            total_steps=learner.total_steps,
            alpha=learner.alpha,
            human_time_total_s=learner.advice_total.human_time_s + summary.human_time_s,
        )
        learner.advice_total.add(counts)  # failures by kind stay with the actors (the row has their total)
        learner.episode += 1
        return row

    def owed(self) -> int:
        """Updates due now to keep updates_per_transition."""
        return int(self.updates_per_transition * self.eligible + 1e-9) - self.updates_here

    def update(self) -> dict:
        info = self.learner.update()
        self.updates_here += 1
        return info

    def weights_due(self) -> bool:
        """Time to send weights: never sent yet, or weights_every updates since."""
        return self.weights_at is None or self.learner.updates - self.weights_at >= self.weights_every

    def weights_sent(self) -> None:
        self.weights_at = self.learner.updates
