"""Is advice open now? The one place that says: Eq. 7's budget in episodes, the person's budget
in seconds, and the mode.

The learner asks its gates only while the window is open; the acting node's /diagnostics, the
in-process takeover and the person's page (through the console node, which computes it with
``advice_window`` from the learner's parameters and episode statistics) all read it from here.
The budgets themselves live in one place, the LearnerConfig: ``AdviceBudget`` is a view of it,
and changing a budget while learning (``ros2 param set``, the page) goes through it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from . import equations as eq
from .config import LearnerConfig, asks_for_advice, check_value


@dataclass(frozen=True)
class AdviceWindow:
    """Whether a request may be made now, and what is left of the budgets."""

    open: bool
    episodes_left: int  # of Eq. 7's budget
    seconds_left: float  # of the person's budget; inf when advising_budget_s is 0
    why_closed: str = ''  # '' while open

    def to_dict(self) -> dict:
        """For a web page: JSON has no inf (null: no budget in seconds)."""
        return {
            'open': self.open,
            'episodes_left': self.episodes_left,
            'seconds_left': self.seconds_left if math.isfinite(self.seconds_left) else None,
            'why_closed': self.why_closed,
        }


def advice_window(mode: str, advising_budget: int, advising_budget_s: float, episode: int, seconds_used: float):
    """The window at episode index ``episode`` with ``seconds_used`` of the person's time spent."""
    episodes_left = max(0, int(advising_budget) - int(episode))
    seconds_left = max(0.0, advising_budget_s - seconds_used) if advising_budget_s > 0 else math.inf
    if not asks_for_advice(mode):
        return AdviceWindow(False, episodes_left, seconds_left, f'mode {mode} does not ask')
    if not eq.early_advising(episode, advising_budget):
        why = f'the advising budget is used up ({advising_budget} episodes of advice)'
        return AdviceWindow(False, episodes_left, seconds_left, why)
    if seconds_left <= 0.0:
        why = f"the advising budget is used up (the person's {advising_budget_s:g} s)"
        return AdviceWindow(False, episodes_left, seconds_left, why)
    return AdviceWindow(True, episodes_left, seconds_left)


class AdviceBudget:
    """The budgets of one learner, read from and set on its LearnerConfig (their one store)."""

    def __init__(self, config: LearnerConfig):
        self.config = config

    @property
    def episodes(self) -> int:
        return self.config.advising_budget

    @property
    def seconds(self) -> float:
        return self.config.advising_budget_s

    def set_episodes(self, episodes: int) -> None:
        self.config.advising_budget = check_value('advising_budget', episodes)

    def set_seconds(self, seconds: float) -> None:
        self.config.advising_budget_s = check_value('advising_budget_s', seconds)

    def within_episodes(self, episode: int) -> bool:
        """Eq. 7 and a mode that asks: the gates' own condition."""
        return asks_for_advice(self.config.mode) and eq.early_advising(episode, self.config.advising_budget)

    def window(self, episode: int, seconds_used: float) -> AdviceWindow:
        return advice_window(self.config.mode, self.episodes, self.seconds, episode, seconds_used)
