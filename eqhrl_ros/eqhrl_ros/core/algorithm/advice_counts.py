"""What advice cost and brought, counted: per episode (AdviceCounts) and over the run (RunTally).

The lone learner closes its own episodes, the trainer closes its actors' episodes; both go
through RunTally.close, so an episode's row gets its run-wide index, steps and the person's
seconds so far the same way on both paths.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from ..data.advice import FAILURE_KINDS
from ..data.summary import EpisodeSummary

# EpisodeSummary's advice fields and the AdviceCounts they come from: one mapping, both ways.
SUMMARY_FIELDS = {
    'advice_asked': 'asked',
    'advice_given': 'given',
    'advice_human': 'human',
    'advice_declined': 'declined',
    'human_time_s': 'human_time_s',
    'takeovers': 'takeovers',
    'takeover_steps': 'takeover_steps',
    'takeover_s': 'takeover_s',
    'asked_steps': 'asked_steps',
}


@dataclass
class AdviceCounts:
    asked: int = 0
    given: int = 0
    human: int = 0  # of the given advice, how much came from a person
    declined: int = 0
    failed: dict = field(default_factory=lambda: {kind: 0 for kind in FAILURE_KINDS})
    # Seconds a person spent on requests: answering, skipping, or a whole answer window let pass.
    human_time_s: float = 0.0
    # Steps the person took over unasked (mixed initiative): stretches of them, steps, seconds.
    takeovers: int = 0
    takeover_steps: int = 0
    takeover_s: float = 0.0
    # Steps the person drove because they were asked to (the wheel protocol).
    asked_steps: int = 0

    @property
    def failed_total(self) -> int:
        return sum(self.failed.values())

    def summary_fields(self) -> dict:
        """These counts as an EpisodeSummary's advice fields (failures as their total)."""
        return {
            **{field: getattr(self, name) for field, name in SUMMARY_FIELDS.items()},
            'advice_failed': self.failed_total,
        }

    @classmethod
    def from_summary(cls, summary: EpisodeSummary) -> 'AdviceCounts':
        """The counts an EpisodeSummary's advice fields hold (failures by kind stay with who counted them)."""
        return cls(**{name: getattr(summary, field) for field, name in SUMMARY_FIELDS.items()})

    def add(self, other: 'AdviceCounts') -> None:
        self.asked += other.asked
        self.given += other.given
        self.human += other.human
        self.declined += other.declined
        self.human_time_s += other.human_time_s
        self.takeovers += other.takeovers
        self.takeover_steps += other.takeover_steps
        self.takeover_s += other.takeover_s
        self.asked_steps += other.asked_steps
        for kind, n in other.failed.items():
            self.failed[kind] += n

    def to_dict(self) -> dict:
        return {
            'asked': self.asked,
            'given': self.given,
            'human': self.human,
            'declined': self.declined,
            'failed': dict(self.failed),
            'human_time_s': self.human_time_s,
            'takeovers': self.takeovers,
            'takeover_steps': self.takeover_steps,
            'takeover_s': self.takeover_s,
            'asked_steps': self.asked_steps,
        }

    @staticmethod
    def from_dict(d: dict) -> 'AdviceCounts':
        failed = {kind: 0 for kind in FAILURE_KINDS}
        failed.update({k: int(v) for k, v in d['failed'].items() if k in failed})
        return AdviceCounts(
            int(d['asked']),
            int(d['given']),
            int(d.get('human', 0)),
            int(d['declined']),
            failed,
            float(d.get('human_time_s', 0.0)),  # checkpoints before people were timed have none
            int(d.get('takeovers', 0)),  # nor before takeovers were counted
            int(d.get('takeover_steps', 0)),
            float(d.get('takeover_s', 0.0)),
            int(d.get('asked_steps', 0)),  # nor before the wheel was asked for
        )


@dataclass
class RunTally:
    """The run's counters: the episode index (Eq. 7's "Iteration"), the env steps, and the
    advice counts of every finished episode."""

    episode: int = 0
    total_steps: int = 0
    advice_total: AdviceCounts = field(default_factory=AdviceCounts)

    def person_seconds(self, open_episode: AdviceCounts | None = None) -> float:
        """The person's seconds over the run (on requests and on unasked takeovers), the open
        episode's included."""
        spent = self.advice_total.human_time_s + self.advice_total.takeover_s
        return spent + (open_episode.human_time_s + open_episode.takeover_s if open_episode else 0.0)

    def close(self, summary: EpisodeSummary, counts: AdviceCounts) -> EpisodeSummary:
        """``summary`` as the run's next row: its index, the run's steps so far and the person's
        seconds so far; ``counts`` (its advice) join the run's total and the index moves on."""
        row = dataclasses.replace(
            summary,
            episode=self.episode,
            total_steps=self.total_steps,
            human_time_total_s=self.person_seconds(counts),
        )
        self.advice_total.add(counts)
        self.episode += 1
        return row
