"""One episode's statistics: what the learner node publishes and what episodes.csv holds.

No torch here, so that light readers (a teleop, a report) can name the fields.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import ClassVar


def _column(fmt: str = '', name: str = ''):
    """A field's column in episodes.csv: its name there ('' for the field's own) and how a number
    is written ('' for an int; a bool is written 0 or 1)."""
    return {'csv': name, 'fmt': fmt}


@dataclass(frozen=True)
class EpisodeSummary:
    """Per-episode statistics. Every field is a column of episodes.csv, in this order, and a field
    of eqhrl_interfaces/msg/EpisodeStats.msg (tests/test_one_home.py holds the three together)."""

    CSV_FIELDS: ClassVar[tuple[str, ...]]  # the columns of episodes.csv (set below the class)

    episode: int
    episode_return: float = field(metadata=_column('.4f', name='return'))
    length: int
    advice_asked: int
    advice_given: int
    advice_human: int
    advice_declined: int
    advice_failed: int
    success: bool
    total_steps: int
    alpha: float = field(metadata=_column('.6f'))
    # The learner did not see the whole episode (an observation was lost, or it joined
    # mid-episode): return and length cover only what it saw. Never a normal episode.
    interrupted: bool = False
    # Seconds of a person's time spent on this episode's advice requests (from the alert to the
    # answer or the hand-back, reaction included; skips, whole windows let pass), and the person's
    # seconds over the whole run so far: requests and unasked takeovers (takeover_s), the sum that
    # advising_budget_s is spent against.
    human_time_s: float = field(default=0.0, metadata=_column('.3f'))
    human_time_total_s: float = field(default=0.0, metadata=_column('.3f'))
    # The person took over unasked: stretches of steps, steps and seconds (not requests).
    takeovers: int = 0
    takeover_steps: int = 0
    takeover_s: float = field(default=0.0, metadata=_column('.3f'))
    # The person's STOP held this episode: how many times, and for how many seconds (the env took
    # no step meanwhile; the episode went on from the same state once released).
    stops: int = 0
    stopped_s: float = field(default=0.0, metadata=_column('.3f'))
    # Steps the person drove because the learner asked them to take the wheel (the wheel protocol;
    # distinct from takeover_steps, taken unasked). The requests themselves are counted above.
    asked_steps: int = 0

    def csv_row(self) -> list:
        """This episode as a row of episodes.csv (CSV_FIELDS)."""
        row = []
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            fmt = f.metadata.get('fmt', '')
            row.append(int(value) if isinstance(value, bool) else format(value, fmt) if fmt else value)
        return row


# The columns of episodes.csv: the fields' names, but 'return' for episode_return.
EpisodeSummary.CSV_FIELDS = tuple(f.metadata.get('csv') or f.name for f in dataclasses.fields(EpisodeSummary))
