"""One episode's statistics: what the learner node publishes and what episodes.csv holds.

No torch here, so that light readers (a teleop, a report) can name the fields.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class EpisodeSummary:
    """Per-episode statistics (what the learner node publishes and writes to CSV)."""

    episode: int
    episode_return: float
    length: int
    advice_asked: int
    advice_given: int
    advice_human: int
    advice_declined: int
    advice_failed: int
    success: bool
    total_steps: int
    alpha: float
    # The learner did not see the whole episode (an observation was lost, or it joined
    # mid-episode): return and length cover only what it saw. Never a normal episode.
    interrupted: bool = False
    # Seconds of a person's time spent on this episode's advice requests (reaction times of
    # answers and skips, whole answer windows let pass), and over the whole run so far.
    human_time_s: float = 0.0
    human_time_total_s: float = 0.0
    # The person took over unasked: stretches of steps, steps and seconds (not requests).
    takeovers: int = 0
    takeover_steps: int = 0
    takeover_s: float = 0.0

    CSV_FIELDS = (
        'episode',
        'return',
        'length',
        'advice_asked',
        'advice_given',
        'advice_human',
        'advice_declined',
        'advice_failed',
        'success',
        'total_steps',
        'alpha',
        'interrupted',
        'human_time_s',
        'human_time_total_s',
        'takeovers',
        'takeover_steps',
        'takeover_s',
    )

    def csv_row(self) -> list:
        return [
            self.episode,
            f'{self.episode_return:.4f}',
            self.length,
            self.advice_asked,
            self.advice_given,
            self.advice_human,
            self.advice_declined,
            self.advice_failed,
            int(self.success),
            self.total_steps,
            f'{self.alpha:.6f}',
            int(self.interrupted),
            f'{self.human_time_s:.3f}',
            f'{self.human_time_total_s:.3f}',
            self.takeovers,
            self.takeover_steps,
            f'{self.takeover_s:.3f}',
        ]
