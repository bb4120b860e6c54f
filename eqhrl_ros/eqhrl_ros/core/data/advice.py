"""What passes between the learner and an expert: the request, the answer, the expert's interface.

The learner core calls ``expert(request) -> Advice``. It never knows whether a
controller, a trained policy, a ROS service or a person answers.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np


@dataclass(frozen=True)
class AdviceRequest:
    """What the learner tells the expert when its gates fire (mirrors eqhrl_interfaces/srv/Advise)."""

    observation: np.ndarray
    proposed_action: np.ndarray  # env units
    action_low: np.ndarray
    action_high: np.ndarray
    discrepancy: float  # D(s), Eq. 8
    entropy: float  # E(s), Eq. 9 (NaN in qasac mode)
    episode: int
    step: int
    # A camera learner's frames the observation was paired with, uint8 [k, H, W, C] oldest first,
    # as the learner reads them (None without a camera): what a person is shown when asked.
    pixels: Optional[np.ndarray] = None


@dataclass(frozen=True)
class Advice:
    """The expert's answer: an action (env units), or None and a reason when it declines."""

    action: Optional[np.ndarray]
    reason: str = ''
    expert_name: str = ''
    human: bool = False  # a person answered (or skipped, or let the answer window pass)
    # Seconds from the request to this answer: a person's reaction time, the cost the
    # method exists to save (0 for a controller that answers at once).
    response_time_s: float = 0.0
    # A person's answer window passed with no answer: counted as a timeout, not a decline.
    timed_out: bool = False

    @property
    def advised(self) -> bool:
        return self.action is not None

    @staticmethod
    def decline(reason: str, expert_name: str = '', human: bool = False, response_time_s: float = 0.0) -> 'Advice':
        return Advice(None, reason, expert_name, human, response_time_s)

    @staticmethod
    def no_answer(window_s: float, expert_name: str = '') -> 'Advice':
        """A person did not answer within ``window_s``: the whole window was their time."""
        return Advice(None, f'no answer within {window_s:.1f} s', expert_name, True, window_s, timed_out=True)


Expert = Callable[[AdviceRequest], Advice]

# The reason a person's explicit "no advice" (skip) carries.
SKIPPED = 'skipped by the person'


# Who chose a stored step's action (TransitionBatch.sources holds the index): the learner's own
# policy, an expert's answer to a request, the person driving because they were asked to take the
# wheel, or the person taking over unasked.
ACTION_SOURCES = ('learner', 'answer', 'asked', 'takeover')
# A Resolution's outcome -> the source of the action it gives (any other outcome: the learner's).
OUTCOME_SOURCES = {'given': 'answer', 'asked': 'asked', 'taken over': 'takeover'}


# What check_advised_action refuses an answer's action for.
ACTION_FAULTS = ('wrong_size', 'non_finite', 'out_of_bounds')
# Kinds of failed advice, counted apart from advice given and advice declined.
FAILURE_KINDS = (
    'unavailable',
    'timeout',
    'error',
    *ACTION_FAULTS,
    'untrusted',
    'episode_ended',  # a real-time episode ended before the answer came: not the person's timeout
    'budget_spent',  # the person's seconds (advising_budget_s) ran out before they took the wheel
)


def check_advised_action(
    action, low: np.ndarray, high: np.ndarray, tolerance: float = 1e-4
) -> tuple[Optional[np.ndarray], str]:
    """Validate an advised action. Returns (action, '') or (None, failure kind)."""
    action = np.asarray(action, dtype=np.float32).reshape(-1)
    if action.shape[0] != low.shape[0]:
        return None, 'wrong_size'
    if not np.isfinite(action).all():
        return None, 'non_finite'
    if (action < low - tolerance).any() or (action > high + tolerance).any():
        return None, 'out_of_bounds'
    return np.clip(action, low, high), ''


def refused_action_words(action, low: np.ndarray, high: np.ndarray) -> str:
    """What is wrong with an advised action that check_advised_action refuses, in the words a
    person fixing their expert needs ('' for one it takes)."""
    action = np.asarray(action, dtype=np.float32).reshape(-1)
    kind = check_advised_action(action, low, high)[1]
    shown = np.array2string(action[:8], precision=4, separator=', ') + (' …' if action.shape[0] > 8 else '')
    if kind == 'wrong_size':
        return f'{action.shape[0]} values where the env takes {low.shape[0]}'
    if kind == 'non_finite':
        return f'{shown} is not finite'
    if kind == 'out_of_bounds':
        bounds = f'{np.array2string(low, separator=", ")} … {np.array2string(high, separator=", ")}'
        return f'{shown} is outside the bounds {bounds} (env units, as Advise.action_low/high give them)'
    return ''
