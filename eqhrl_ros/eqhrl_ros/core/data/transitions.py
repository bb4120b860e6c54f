"""Transitions on their way from an actor node to the trainer: batches, the actor's outbox,
and the trainer's count of what was lost. No ROS here (nodes/messages.py converts).

An actor keeps what it could not send yet (the trainer is away: not started, restarting, or
gone) in its outbox, up to a bound; past it, the oldest batch is dropped and counted. Each
batch carries a sequence number per actor run, so the trainer counts the batches it never
received, whatever the reason.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from .summary import EpisodeSummary


@dataclass
class TransitionBatch:
    """n transitions of one actor, in order, and the episodes that ended with them."""

    actor: str
    sequence: int
    observations: np.ndarray  # (n, obs_dim) float32
    actions: np.ndarray  # (n, action_dim) float32, normalised to [-1, 1]
    rewards: np.ndarray  # (n,) float32
    next_observations: np.ndarray  # (n, obs_dim) float32
    terminated: np.ndarray  # (n,) bool
    advised: np.ndarray  # (n,) bool
    episodes: list = field(default_factory=list)  # EpisodeSummary, as the actor counted them

    def __len__(self) -> int:
        return len(self.rewards)


class Outbox:
    """What an actor has to send: the batch being filled, and sealed batches not sent yet.

    A batch is sealed when it holds ``batch_transitions``, when an episode ends (so that the
    episode's statistics travel with its last transitions), or when the node's flush timer
    says so. At most ``limit`` transitions wait; past it the oldest sealed batch is dropped.
    """

    def __init__(self, actor: str, obs_dim: int, action_dim: int, batch_transitions: int, limit: int):
        if batch_transitions < 1 or limit < batch_transitions:
            raise ValueError(f'need 1 <= batch_transitions ({batch_transitions}) <= limit ({limit})')
        self.actor = actor
        self.obs_dim, self.action_dim = obs_dim, action_dim
        self.batch_transitions, self.limit = batch_transitions, limit
        self.sealed: deque[TransitionBatch] = deque()
        self.next_sequence = 0
        self.dropped_batches = 0
        self.dropped_transitions = 0
        self.dropped_episodes = 0
        self._open()

    def _open(self) -> None:
        self._rows: list = []
        self._episodes: list = []
        self._since: float | None = None  # time.monotonic() of the open batch's first transition

    @property
    def waiting(self) -> int:
        """Transitions not sent yet (sealed and open)."""
        return sum(len(b) for b in self.sealed) + len(self._rows)

    def add(self, obs, normalized_action, reward: float, next_obs, terminated: bool, advised: bool) -> None:
        if self._since is None:
            self._since = time.monotonic()
        self._rows.append((obs, normalized_action, reward, next_obs, terminated, advised))
        if len(self._rows) >= self.batch_transitions:
            self.seal()

    def end_episode(self, summary: EpisodeSummary) -> None:
        self._episodes.append(summary)
        self.seal()

    def age(self) -> float:
        """Seconds since the open batch's first transition (0 when it is empty)."""
        return 0.0 if self._since is None else time.monotonic() - self._since

    def seal(self) -> None:
        """Close the open batch (if it holds anything) and queue it for sending."""
        if not self._rows and not self._episodes:
            return
        rows = self._rows
        batch = TransitionBatch(
            self.actor,
            self.next_sequence,
            np.asarray([r[0] for r in rows], dtype=np.float32).reshape(-1, self.obs_dim),
            np.asarray([r[1] for r in rows], dtype=np.float32).reshape(-1, self.action_dim),
            np.asarray([r[2] for r in rows], dtype=np.float32),
            np.asarray([r[3] for r in rows], dtype=np.float32).reshape(-1, self.obs_dim),
            np.asarray([r[4] for r in rows], dtype=bool),
            np.asarray([r[5] for r in rows], dtype=bool),
            list(self._episodes),
        )
        self.next_sequence += 1
        self.sealed.append(batch)
        self._open()
        while self.waiting > self.limit and len(self.sealed) > 1:
            dropped = self.sealed.popleft()
            self.dropped_batches += 1
            self.dropped_transitions += len(dropped)
            self.dropped_episodes += len(dropped.episodes)

    def pop_oldest(self) -> TransitionBatch | None:
        """The oldest sealed batch, to send now (None when there is none)."""
        return self.sealed.popleft() if self.sealed else None


@dataclass
class ActorSequence:
    expected: int = 0  # the next sequence number due
    batches: int = 0
    lost: int = 0
    restarts: int = 0
    last_heard: float = 0.0  # time.monotonic()


class SequenceTracker:
    """The trainer's view of each actor's sequence: lost batches and restarted actors."""

    def __init__(self):
        self.actors: dict[str, ActorSequence] = {}

    def receive(self, actor: str, sequence: int) -> str:
        """Note a batch; returns what it says: 'first', 'next', 'gap' (batches were lost
        before it) or 'restart' (the actor started again from sequence 0)."""
        state = self.actors.get(actor)
        verdict = 'next'
        if state is None:
            state = self.actors[actor] = ActorSequence(expected=sequence)
            verdict = 'first'  # a trainer that (re)started mid-run joins the stream where it is
        elif sequence < state.expected:
            state.restarts += 1
            verdict = 'restart'
        elif sequence > state.expected:
            state.lost += sequence - state.expected
            verdict = 'gap'
        state.expected = sequence + 1
        state.batches += 1
        state.last_heard = time.monotonic()
        return verdict

    @property
    def lost(self) -> int:
        return sum(s.lost for s in self.actors.values())
