"""Asking for the wheel: in real time, a request asks the person to drive now (this package's
protocol, beyond the paper; the paper's one-action answer stays the protocol of a lock-step env).

The paper asks for one action for one state while the simulator waits. A real robot does not
wait: by the time a person has read a request and reacted (0.6-1.5 s), its state is gone, and
an action for it applied once is worth little. So in a real-time env, when the gates fire, the
learner alerts the person and keeps driving with its own policy; the person takes the wheel by
pressing the deadman (a press made after the alert: one held from before does not count), and
from then on every step applies their current command to the current state, labelled as asked.
Control returns to the learner by the hand-back rule (``WheelRules``):

- ``released``: the deadman is released (or the command goes stale: the page closed, the link cut);
- ``agreed``: the person's and the policy's actions agree within ``agree`` ([-1, 1] units, every
  dimension) for ``agree_steps`` steps in a row, as ThriftyDAgger hands back (0: off);
- ``longest``: the stretch has lasted ``max_s`` seconds (0: no limit);
- ``budget``: the person's budget in seconds (advising_budget_s) is spent.

A request the person does not take within ``take_s`` seconds ends as a ``timeout``. The person's
seconds run from the alert to the hand-back, reaction included, and are counted step by step
(``WheelTurn.seconds``); the request ends at the last step before the one that would pass the
budget, so the budget is not overspent (by a step's jitter at most). A STOP pauses
the request and its clock (``pause``, ``resume``). No ROS and no clock here: the caller passes
``now`` (time.monotonic() in the nodes, simulated time in-process).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..envs.spec import ActionScaler
from .takeover import TAKEOVER_STALE_S, PersonCommand

# How a request for the wheel can end: taken and handed back one of these ways, or never taken.
HAND_BACKS = ('released', 'agreed', 'longest', 'budget', 'episode_ended')
UNTAKEN = ('timeout', 'budget', 'episode_ended')
# A press sooner than this after the alert cannot be a reaction to it (a person's simple
# reaction takes 0.15-0.3 s): it was made for something else (the press before, a key repeat).
MIN_REACTION_S = 0.1


@dataclass(frozen=True)
class WheelRules:
    """How long the person has to take the wheel, and how it is handed back (module docstring)."""

    take_s: float = 4.0
    max_s: float = 10.0
    agree: float = 0.1
    agree_steps: int = 10

    def __post_init__(self):
        for name in ('take_s', 'max_s', 'agree'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f'WheelRules.{name} must be a finite number >= 0, got {value!r}')
        if self.take_s <= 0:
            raise ValueError(f'WheelRules.take_s must be > 0 seconds, got {self.take_s!r}')
        if self.agree_steps < 0:
            raise ValueError(f'WheelRules.agree_steps must be >= 0, got {self.agree_steps!r}')


@dataclass(frozen=True)
class WheelTurn:
    """What the open request says about this step."""

    action: Optional[np.ndarray]  # the person's action (env units), or None: the learner drives
    starts: bool  # the person takes the wheel at this step
    seconds: float  # the person's seconds since the last step, to count now
    ended: str = ''  # the request ended at this step: a HAND_BACKS or UNTAKEN kind ('' : goes on)
    taken: bool = False  # the person had the wheel (for an ended request: it was taken)


class AskedWheel:
    """One open request for the wheel, step by step."""

    def __init__(self, alerted_at: float, rules: WheelRules, scaler: ActionScaler, stale_s: float = TAKEOVER_STALE_S):
        self.rules = rules
        self.scaler = scaler
        self.stale_s = stale_s
        self.alerted_at = alerted_at
        self.counted_to = alerted_at  # the person's seconds are counted up to here
        self.taken_at: Optional[float] = None
        self.paused_at: Optional[float] = None
        self.steps = 0  # steps the person drove
        self.interval = 0.0  # seconds between the last two steps: what the next one will likely cost
        self.agreeing = 0  # steps in a row the person's and the policy's actions agreed

    @property
    def taken(self) -> bool:
        return self.taken_at is not None

    def seconds_left(self, now: float) -> float:
        """Of the time to take the wheel (0 once taken)."""
        if self.taken:
            return 0.0
        at = self.paused_at if self.paused_at is not None else now
        return max(0.0, self.alerted_at + self.rules.take_s - at)

    def pause(self, now: float) -> None:
        """A STOP: the request and its clock hold (the env takes no step)."""
        if self.paused_at is None:
            self.paused_at = now

    def resume(self, now: float) -> None:
        """The STOP is released: the clock goes on where it was; the stop is nobody's time here."""
        if self.paused_at is None:
            return
        held = max(0.0, now - self.paused_at)
        self.alerted_at += held
        self.counted_to += held
        if self.taken_at is not None:
            self.taken_at += held
        self.paused_at = None

    def _count(self, now: float) -> float:
        seconds = max(0.0, now - self.counted_to)
        self.counted_to = max(self.counted_to, now)
        return seconds

    def _holding(self, person: Optional[PersonCommand], now: float) -> Optional[PersonCommand]:
        """``person`` while they hold the deadman with a fresh command of the right size, else None."""
        holds = (
            person is not None
            and person.deadman
            and now - person.at <= self.stale_s
            and len(person.action) == self.scaler.dim
        )
        return person if holds else None

    def step(self, person: Optional[PersonCommand], proposed, now: float, budget_left_s: float = math.inf) -> WheelTurn:
        """This step's turn: the person's command when they hold the wheel, else None (the
        learner drives, with its own policy, never a stale held action). ``budget_left_s`` is
        what is left of the person's budget before this step's seconds."""
        if self.paused_at is not None:  # a step still on its way when STOP came: nothing moves on
            driving = self._holding(person, now) if self.taken else None
            return WheelTurn(driving.action if driving else None, False, 0.0, taken=self.taken)
        seconds = self._count(now)
        # Ended at this step if the next one would pass the budget: it is never overspent.
        out_of_budget = seconds + max(self.interval, seconds) > budget_left_s
        self.interval = seconds
        held = self._holding(person, now)
        if self.taken_at is None:
            pressed_after = held is not None and held.pressed_at >= self.alerted_at + MIN_REACTION_S
            if held is not None and pressed_after and not out_of_budget:
                self.taken_at, self.steps, self.agreeing = now, 1, 0
                return WheelTurn(held.action, True, seconds, taken=True)
            if out_of_budget:
                return WheelTurn(None, False, seconds, 'budget')
            if now - self.alerted_at >= self.rules.take_s:
                return WheelTurn(None, False, seconds, 'timeout')
            return WheelTurn(None, False, seconds)
        if held is None:
            return WheelTurn(None, False, seconds, 'released', taken=True)
        if out_of_budget:
            return WheelTurn(None, False, seconds, 'budget', taken=True)
        if self.rules.max_s > 0 and now - self.taken_at >= self.rules.max_s:
            return WheelTurn(None, False, seconds, 'longest', taken=True)
        if self.rules.agree_steps > 0:
            apart = np.abs(
                np.clip(self.scaler.to_normalized(held.action), -1, 1)
                - np.clip(self.scaler.to_normalized(proposed), -1, 1)
            )
            self.agreeing = self.agreeing + 1 if float(apart.max()) <= self.rules.agree else 0
            if self.agreeing >= self.rules.agree_steps:
                return WheelTurn(None, False, seconds, 'agreed', taken=True)
        self.steps += 1
        return WheelTurn(held.action, False, seconds, taken=True)

    def end_episode(self, now: float) -> WheelTurn:
        """The episode ended with the request open: its last seconds, and how it ended."""
        return WheelTurn(None, False, self._count(now), 'episode_ended', taken=self.taken)
