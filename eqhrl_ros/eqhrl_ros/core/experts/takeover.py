"""The person's takeover (mixed initiative, as HG-DAgger's expert takes the wheel): when the
person's command replaces the learner's action, and for how long.

With the deadman held and a fresh command, the person takes over with the take-over button,
or by steering away from the learner's action by more than ``threshold`` ([-1, 1] units; 0
turns steering-away off); then keeps control for as long as the deadman stays held. Released
(or the command gone stale: the page closed, the link cut), control is the learner's again at
the next step. The acting node feeds it the person's commands and asks it at every step.
(A simulated person's takeover, by HG-DAgger's rule, is simulated_human.TakeoverRule.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..envs.spec import ActionScaler

# A person's command older than this is not taken over with (the page closed, the link cut).
TAKEOVER_STALE_S = 0.5


@dataclass(frozen=True)
class PersonCommand:
    """The person's latest command as the acting node heard it."""

    action: np.ndarray  # env units
    deadman: bool
    take_over: bool  # the take-over button is held
    at: float  # time.monotonic() when it arrived
    # When the deadman was last pressed (its rising edge; -inf: held since before we heard it):
    # a request for the wheel is taken only by a press made after it appeared (wheel.py).
    pressed_at: float = -math.inf


def heard(previous: Optional[PersonCommand], action, deadman: bool, take_over: bool, at: float) -> PersonCommand:
    """The command just heard, after ``previous`` (None: the first): its deadman's press time is
    ``at`` when the deadman goes from released (or unheard) to held, else the previous one's."""
    if not deadman:
        pressed_at = -math.inf
    elif previous is not None and previous.deadman:
        pressed_at = previous.pressed_at
    else:
        pressed_at = at
    return PersonCommand(action, deadman, take_over, at, pressed_at)


@dataclass(frozen=True)
class TakenStep:
    """A step the person drives: their action, whether a stretch starts, their seconds on it."""

    action: np.ndarray
    starts: bool
    seconds: float


class DeadmanTakeover:
    """Decides, step by step, whether the person drives (module docstring)."""

    def __init__(self, scaler: ActionScaler, threshold: float, stale_s: float = TAKEOVER_STALE_S):
        self.scaler = scaler
        self.threshold = float(threshold)
        self.stale_s = stale_s
        self.since: Optional[float] = None  # time.monotonic() of the last step taken over

    @property
    def taking_over(self) -> bool:
        return self.since is not None

    def _apart(self, a, b) -> float:
        """How far two env-unit actions are apart, in [-1, 1] units (the largest dimension)."""
        normalized = [np.clip(self.scaler.to_normalized(x), -1.0, 1.0) for x in (a, b)]
        return float(np.abs(normalized[0] - normalized[1]).max())

    def person_drives(self, person: Optional[PersonCommand], proposed, now: float) -> Optional[TakenStep]:
        """The step the person takes over now (their action and time), or None: the learner drives."""
        if person is None or len(person.action) != self.scaler.dim:
            return None
        if not person.deadman or now - person.at > self.stale_s:
            return None
        if self.since is not None:  # a stretch goes on for as long as the deadman is held
            return TakenStep(person.action, False, min(now - self.since, self.stale_s))
        if person.take_over or (self.threshold > 0 and self._apart(person.action, proposed) > self.threshold):
            return TakenStep(person.action, True, 0.0)
        return None

    def taken(self, now: float, accepted: bool) -> None:
        """The step person_drives() offered was taken (``accepted``) or refused (an action out of bounds)."""
        self.since = now if accepted else None

    def hand_back(self) -> bool:
        """The learner drives this step; True when that ends a stretch of the person's."""
        was = self.taking_over
        self.since = None
        return was
