"""Transitions on their way from an actor node to the trainer: batches, the actor's outbox,
and the trainer's view of each actor's stream. No ROS here (nodes/trainer_msgs.py converts).

Nothing is lost in an ordinary fault (a cut link, a trainer killed and resumed), and what was
lost is all that is sent again (selective repeat, not go-back-N): each batch carries its actor
run and a sequence number; the trainer stores an actor's batches in order, holds (bounded) the
ones that arrive past a missing one, drops the ones it already has, and acknowledges what it
has stored (``received``), the highest batch it has or holds, the ones it lacks below that
(``missing``), and what its last checkpoint holds (``saved``). The actor keeps every batch
until a checkpoint holds it, sends again only what an acknowledgement names as missing or what
no acknowledgement has covered for ``ACK_WAIT_S``, and each batch at most once per
``RESEND_AFTER_S``. A trainer resumed from its checkpoint thus asks for, and gets, everything
after it. What an actor may keep is bounded (``limit`` transitions); past it the oldest batch
goes, counted as lost when the trainer never had it.
"""

from __future__ import annotations

import dataclasses
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from .advice import ACTION_SOURCES
from .batch_frames import BatchFrames, frame_fields, frames_from
from .summary import EpisodeSummary

# A sent batch no acknowledgement has covered for this long went into a cut link (or its
# acknowledgement did): it is sent again. Also the actor's wait before it probes a silent trainer.
ACK_WAIT_S = 2.0
# A batch named missing is sent again at most once in this time: every acknowledgement until it
# arrives names it again.
RESEND_AFTER_S = 1.0
# What the trainer holds past a missing batch, per actor, and names as missing in one acknowledgement.
MAX_HELD_BATCHES = 1024
MAX_MISSING = 256


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
    run: str = ''  # the actor process's run (a restarted actor numbers its batches from 0 again)
    # The oldest sequence this actor still holds (anything before it is gone); None: unknown, this one.
    oldest_kept: int | None = None
    # (n,) uint8, who chose each action: an index into advice.ACTION_SOURCES; empty: not said.
    sources: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint8))
    frames: BatchFrames | None = None  # a camera learner's frames; None without a camera

    def __len__(self) -> int:
        return len(self.rewards)


@dataclass(frozen=True)
class StepLimits:
    """Magnitudes an env step may have (the parameters max_abs_observation and max_abs_reward of
    the learner, actors and trainer). Beyond them a value cannot come from the env (a glitch, a slip
    of units, a forgery), and one in the replay memory spoils every batch that draws it: the
    learner and actors drop such a step where it arrives, the trainer refuses a batch holding one."""

    max_abs_observation: float = 1e6
    max_abs_reward: float = 1e4

    def refusal(self, observations, rewards) -> str:
        """'' when the observations (a step's state vector, or many) and rewards (one, or many) are
        within these, else why not."""
        largest = float(np.abs(np.asarray(observations, dtype=np.float64)).max(initial=0.0))
        if largest > self.max_abs_observation:
            return (
                f'an observation value of magnitude {largest:.3g} is beyond max_abs_observation '
                f'{self.max_abs_observation:g} (it cannot come from the env)'
            )
        largest = float(np.abs(np.asarray(rewards, dtype=np.float64)).max(initial=0.0))
        if largest > self.max_abs_reward:
            return (
                f'a reward of magnitude {largest:.3g} is beyond max_abs_reward {self.max_abs_reward:g} '
                '(raise it for an env of larger rewards)'
            )
        return ''


class BatchError(ValueError):
    """A TransitionBatch message whose sizes do not fit together."""


def batch_fields(batch: TransitionBatch, action_low, action_high) -> dict:
    """The fields of eqhrl_interfaces/msg/TransitionBatch for ``batch`` (episodes as dicts of
    EpisodeStats' fields); the signature is left out."""
    return {
        'actor': batch.actor,
        'sequence': int(batch.sequence),
        'actor_run': batch.run,
        'oldest_kept': int(batch.sequence if batch.oldest_kept is None else batch.oldest_kept),
        'observation_size': int(batch.observations.shape[1]),
        'action_low': np.asarray(action_low, dtype=np.float32).ravel(),
        'action_high': np.asarray(action_high, dtype=np.float32).ravel(),
        'observations': np.asarray(batch.observations, dtype=np.float32).ravel(),
        'actions': np.asarray(batch.actions, dtype=np.float32).ravel(),
        'rewards': np.asarray(batch.rewards, dtype=np.float32).ravel(),
        'next_observations': np.asarray(batch.next_observations, dtype=np.float32).ravel(),
        'terminated': [bool(v) for v in batch.terminated],
        'advised': [bool(v) for v in batch.advised],
        'sources': np.asarray(batch.sources, dtype=np.uint8).tolist(),
        'episodes': [dataclasses.asdict(s) for s in batch.episodes],
        **frame_fields(batch.frames),  # frames as PNG bytes: the node makes CompressedImage of them
    }


def batch_from_fields(msg) -> tuple[TransitionBatch, np.ndarray, np.ndarray]:
    """(the batch, action_low, action_high) from a TransitionBatch message, or anything with its
    fields as attributes (a message read back from a record). Sizes that do not add up raise
    BatchError; values are checked where they are stored (Trainer.receive, EQSACLearner.store)."""
    obs_dim = int(msg.observation_size)
    action_dim = len(msg.action_low)
    n = len(msg.rewards)
    if obs_dim < 1 or action_dim < 1 or len(msg.action_high) != action_dim:
        raise BatchError(
            f'observation_size {obs_dim}, action_low {len(msg.action_low)} and action_high '
            f'{len(msg.action_high)} values do not describe spaces'
        )
    sizes = {
        'observations': (len(msg.observations), n * obs_dim),
        'next_observations': (len(msg.next_observations), n * obs_dim),
        'actions': (len(msg.actions), n * action_dim),
        'terminated': (len(msg.terminated), n),
        'advised': (len(msg.advised), n),
    }
    for name, (got, expected) in sizes.items():
        if got != expected:
            raise BatchError(f'{name} has {got} values, {n} transitions need {expected}')
    # A record written before sources existed has none: read as not said.
    sources = np.asarray(list(getattr(msg, 'sources', ())), dtype=np.uint8)
    if len(sources) not in (0, n):
        raise BatchError(f'sources has {len(sources)} values, {n} transitions need {n} (or none)')
    if len(sources) and int(sources.max()) >= len(ACTION_SOURCES):
        raise BatchError(f'sources holds {int(sources.max())}, not an index into {ACTION_SOURCES}')
    stats = [f.name for f in dataclasses.fields(EpisodeSummary)]
    batch = TransitionBatch(
        actor=msg.actor,
        sequence=int(msg.sequence),
        observations=np.asarray(msg.observations, dtype=np.float32).reshape(n, obs_dim),
        actions=np.asarray(msg.actions, dtype=np.float32).reshape(n, action_dim),
        rewards=np.asarray(msg.rewards, dtype=np.float32),
        next_observations=np.asarray(msg.next_observations, dtype=np.float32).reshape(n, obs_dim),
        terminated=np.asarray(msg.terminated, dtype=bool),
        advised=np.asarray(msg.advised, dtype=bool),
        episodes=[EpisodeSummary(**{name: getattr(e, name) for name in stats}) for e in msg.episodes],
        run=msg.actor_run,
        oldest_kept=int(msg.oldest_kept),
        sources=sources,
        frames=frames_from(msg, n, BatchError),
    )
    low, high = (np.asarray(v, dtype=np.float32) for v in (msg.action_low, msg.action_high))
    return batch, low, high


class Outbox:
    """What an actor has to send: the batch being filled, sealed batches not sent yet, and sent
    batches not yet held by the trainer's checkpoint (``unacked``), with the ones to send again.

    A batch is sealed when it holds ``batch_transitions``, when an episode ends (so that the
    episode's statistics travel with its last transitions), or when the node's flush timer
    says so. At most ``limit`` transitions are kept; past it the oldest batch is dropped.
    """

    def __init__(self, actor: str, obs_dim: int, action_dim: int, batch_transitions: int, limit: int, run: str = ''):
        if batch_transitions < 1 or limit < batch_transitions:
            raise ValueError(f'need 1 <= batch_transitions ({batch_transitions}) <= limit ({limit})')
        self.actor, self.run = actor, run
        self.obs_dim, self.action_dim = obs_dim, action_dim
        self.batch_transitions, self.limit = batch_transitions, limit
        self.sealed: deque[TransitionBatch] = deque()  # to send, oldest first
        self.unacked: deque[TransitionBatch] = deque()  # sent, not in a trainer's checkpoint yet
        self._sent_at: dict[int, float] = {}  # sequence -> time.monotonic() it last went out
        self._again: deque[int] = deque()  # sequences to send again, in the order asked
        self.next_sequence = 0
        self.received_through = -1  # the trainer has stored every batch up to this one
        self.highest_received = -1  # the highest batch the trainer has stored or holds
        self.dropped_batches = 0  # dropped at the bound before the trainer had them: lost
        self.dropped_transitions = 0
        self.dropped_episodes = 0
        self.released_unsaved = 0  # dropped at the bound after the trainer stored them (not yet saved)
        self.resent_batches = 0
        self._open()

    def _open(self) -> None:
        self._rows: list = []
        self._episodes: list = []
        self._since: float | None = None  # time.monotonic() of the open batch's first transition

    @property
    def waiting(self) -> int:
        """Transitions kept: not sent, or sent and not yet in a trainer's checkpoint."""
        return sum(len(b) for b in self.unacked) + sum(len(b) for b in self.sealed) + len(self._rows)

    @property
    def unsent(self) -> int:
        """Transitions the trainer has not stored yet, as far as this actor knows."""
        kept = (*self.unacked, *self.sealed)
        return sum(len(b) for b in kept if b.sequence > self.received_through) + len(self._rows)

    @property
    def oldest_kept(self) -> int:
        kept = self.unacked or self.sealed
        return kept[0].sequence if kept else self.next_sequence

    @property
    def pending(self) -> bool:
        """Something to send now: a sealed batch, or one to send again."""
        return bool(self.sealed or self._again)

    def add(
        self,
        obs,
        normalized_action,
        reward: float,
        next_obs,
        terminated: bool,
        advised: bool,
        source: str = 'learner',
        frames: tuple | None = None,
    ) -> None:
        """One transition; ``source``: who chose its action (one of ACTION_SOURCES). A camera
        actor's ``frames``: (the stack acted on [k, H, W, C], the frame that followed [H, W, C]);
        the sealed batch holds each frame once (BatchFrames)."""
        if self._since is None:
            self._since = time.monotonic()
        source_index = ACTION_SOURCES.index(source)
        self._rows.append((obs, normalized_action, reward, next_obs, terminated, advised, source_index, frames))
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
            run=self.run,
            sources=np.asarray([r[6] for r in rows], dtype=np.uint8),
            frames=BatchFrames.of(*zip(*(r[7] for r in rows))) if rows and rows[0][7] is not None else None,
        )
        self.next_sequence += 1
        self.sealed.append(batch)
        self._open()
        while self.waiting > self.limit and len(self.unacked) + len(self.sealed) > 1:
            dropped = (self.unacked or self.sealed).popleft()
            self._sent_at.pop(dropped.sequence, None)
            if dropped.sequence <= self.received_through:
                self.released_unsaved += 1  # the trainer has it; only a crash before its next save loses it
                continue
            self.dropped_batches += 1
            self.dropped_transitions += len(dropped)
            self.dropped_episodes += len(dropped.episodes)

    def pop_oldest(self, now: float | None = None) -> TransitionBatch | None:
        """The next batch to send now (None when there is none): one the trainer lacks first, then
        the oldest sealed one. Kept until a checkpoint holds it."""
        now = time.monotonic() if now is None else now
        while self._again:
            batch = self._find(self._again.popleft())
            if batch is not None:  # else let go meanwhile (saved, or dropped at the bound)
                self._sent_at[batch.sequence] = now
                self.resent_batches += 1
                return batch
        if not self.sealed:
            return None
        batch = self.sealed.popleft()
        batch.oldest_kept = self.oldest_kept if self.unacked else batch.sequence
        self.unacked.append(batch)
        self._sent_at[batch.sequence] = now
        return batch

    def _find(self, sequence: int) -> TransitionBatch | None:
        if not self.unacked or not self.unacked[0].sequence <= sequence <= self.unacked[-1].sequence:
            return None
        batch = self.unacked[sequence - self.unacked[0].sequence]  # numbered without holes
        return batch if batch.sequence == sequence else None

    def acknowledge(
        self,
        received_through: int,
        saved_through: int,
        missing=(),
        highest_received: int | None = None,
        now: float | None = None,
        resend: bool = True,
    ) -> int:
        """A trainer's acknowledgement: batches its checkpoint holds are let go; the ones it names
        ``missing``, and the sent ones above ``highest_received`` (all it has or holds) that no
        acknowledgement covered within ACK_WAIT_S, go out again, each at most once per
        RESEND_AFTER_S (none with ``resend`` false). Returns how many are queued to go again."""
        now = time.monotonic() if now is None else now
        self.received_through = received_through
        self.highest_received = (
            received_through if highest_received is None else max(received_through, highest_received)
        )
        while self.unacked and self.unacked[0].sequence <= saved_through:
            self._sent_at.pop(self.unacked.popleft().sequence, None)
        if not resend:
            return 0
        queued = set(self._again)
        due = [s for s in missing if s > received_through and now - self._sent_at.get(s, now) >= RESEND_AFTER_S]
        for batch in reversed(self.unacked):  # newest first: only those above highest_received
            if batch.sequence <= self.highest_received:
                break
            if now - self._sent_at.get(batch.sequence, now) >= ACK_WAIT_S:
                due.append(batch.sequence)
        return self._queue_again(due, queued)

    def probe(self, now: float | None = None) -> int:
        """No word from the trainer for a while: send again the oldest batch it has not stored (its
        acknowledgement then says what else it lacks). Returns 1 if one is queued."""
        now = time.monotonic() if now is None else now
        for batch in self.unacked:
            if batch.sequence > self.received_through:
                if now - self._sent_at.get(batch.sequence, now) < ACK_WAIT_S:
                    return 0
                return self._queue_again([batch.sequence], set(self._again))
        return 0

    def _queue_again(self, sequences, queued: set) -> int:
        count = 0
        for sequence in sorted(set(sequences) - queued):
            if self._find(sequence) is not None:
                self._again.append(sequence)
                count += 1
        return count

    def new_trainer(self) -> None:
        """Another trainer (a restart): it may lack anything its checkpoint does not hold, which is
        all this actor keeps. Its first acknowledgement says what it has."""
        self.received_through = self.highest_received = self.oldest_kept - 1


@dataclass
class ActorSequence:
    run: str = ''  # the actor run whose batches these are
    expected: int = 0  # the next sequence number due (everything before it is stored)
    saved_through: int = -1  # the last sequence the trainer's latest checkpoint holds
    batches: int = 0
    run_batches: int = 0  # of this run
    lost: int = 0  # batches the actor no longer held when the trainer asked for them
    restarts: int = 0
    duplicates: int = 0  # batches received again (resent) and already stored
    out_of_order: int = 0  # batches received past a missing one: held until it comes
    last_heard: float = 0.0  # time.monotonic()

    @property
    def received_through(self) -> int:
        return self.expected - 1


# What a batch is, for the trainer: stored, or not ('duplicate'; 'ahead': past a missing one, held).
STORED = ('first', 'next', 'gap', 'restart')


class SequenceTracker:
    """The trainer's view of each actor's stream: in order, each batch once, what was lost."""

    def __init__(self):
        self.actors: dict[str, ActorSequence] = {}

    def receive(self, actor: str, sequence: int, run: str = '', oldest_kept: int | None = None) -> str:
        """What a batch is: 'first' (an actor not heard before), 'restart' (a new run of a known
        actor), 'next' (the one due), 'gap' (due after batches the actor no longer held: lost),
        'duplicate' (stored already: drop it) or 'ahead' (past a missing one: not stored yet; the
        trainer holds it and asks for what is missing). A run's first batch is due at ``oldest_kept``."""
        oldest = sequence if oldest_kept is None else min(int(oldest_kept), sequence)
        state = self.actors.get(actor)
        if state is None:
            state = self.actors[actor] = ActorSequence(run=run, expected=oldest)
        elif state.run != run:  # the actor started again: its counts go on, its stream starts anew
            state.run, state.expected, state.saved_through, state.run_batches = run, oldest, -1, 0
            state.restarts += 1
        state.last_heard = time.monotonic()
        if sequence < state.expected:
            state.duplicates += 1
            return 'duplicate'
        gap = False
        if sequence > state.expected and oldest > state.expected:
            state.lost += oldest - state.expected  # the actor let them go (its bound) before we had them
            state.expected, gap = oldest, True
        if sequence > state.expected:
            state.out_of_order += 1
            return 'ahead'
        state.expected = sequence + 1
        state.batches += 1
        state.run_batches += 1
        if state.run_batches == 1:  # the run's first batch stored
            return 'restart' if state.restarts else 'first'
        return 'gap' if gap else 'next'

    def saved(self, saved: dict) -> None:
        """A checkpoint now holds what ``saved`` (its state_dict()) says."""
        for name, value in saved.items():
            state = self.actors.get(name)
            if state is not None and state.run == value['run']:
                state.saved_through = max(state.saved_through, int(value['through']))

    def state_dict(self) -> dict:
        """Each actor's run and the last batch stored: plain values, for a checkpoint."""
        return {name: {'run': s.run, 'through': s.received_through} for name, s in self.actors.items()}

    def load_state_dict(self, state: dict) -> None:
        """As a checkpoint left it: its batches are stored (and saved), the next ones are due."""
        self.actors = {}
        for name, value in state.items():
            through = int(value['through'])
            self.actors[str(name)] = ActorSequence(run=str(value['run']), expected=through + 1, saved_through=through)

    @property
    def lost(self) -> int:
        return sum(s.lost for s in self.actors.values())
