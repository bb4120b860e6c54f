"""A simulated person: a controller or policy answering with a person's limits.

A real person takes time to react, steers imprecisely, skips a request now and then and
misses others entirely. ``SimulatedHuman`` puts those limits around any expert, so that the
whole human path can be tested headless and experiments can ask what the method costs a
person. No ROS and no sleeping here: ``plan`` says what the person will do and when; the
in-process loop counts the delay as time spent, the ROS nodes wait it out on the clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..algorithm.config import check_fields, hyper
from ..data.advice import SKIPPED, Advice, AdviceRequest
from .takeover import PersonCommand

PLAN_KINDS = ('answer', 'skip', 'miss')


@dataclass
class HumanLimits:
    """How the simulated person behaves (each field is also an `expert` node parameter)."""

    reaction_median_s: float = hyper(
        0.8, "Median reaction time, seconds (log-normal; a person's choice reaction is 0.5-1.5 s)", range=(0.0, 600.0)
    )
    reaction_sigma: float = hyper(0.35, 'Spread of the reaction time: sigma of its logarithm', range=(0.0, 5.0))
    action_noise: float = hyper(
        0.1, 'Steering noise: standard deviation as a fraction of each action half-range', range=(0.0, 10.0)
    )
    skip_probability: float = hyper(0.05, 'Chance that the person looks and declines (skip)', range=(0.0, 1.0))
    miss_probability: float = hyper(0.1, 'Chance that the person does not notice the request', range=(0.0, 1.0))
    answer_window_s: float = hyper(
        3.0, 'Seconds the person is given; a later reaction is a missed request (timeout)', range=(0.01, 600.0)
    )
    stretch_s: float = hyper(
        2.0,
        'Asked for the wheel (advice_protocol wheel): seconds the person drives once they take it, '
        'before they release the deadman (the learner may take it back sooner: wheel_agree_steps, wheel_max_s)',
        range=(0.0, 3600.0),
    )

    def __post_init__(self):
        check_fields(self)
        if self.skip_probability + self.miss_probability > 1.0:
            raise ValueError(
                f'skip_probability + miss_probability must be at most 1, got '
                f'{self.skip_probability} + {self.miss_probability}'
            )


def expected_seconds_per_request(limits: Optional[HumanLimits] = None) -> float:
    """The seconds a simulated person spends on one request, on average: E[min(T, window)] for
    the log-normal reaction time T (a miss costs the whole window; a skip, its reaction time).
    A closed form, so that a report can put a person's seconds beside request counts."""
    limits = limits or HumanLimits()
    window, median, sigma = limits.answer_window_s, limits.reaction_median_s, limits.reaction_sigma
    if median <= 0.0:
        reacted = 0.0
    elif sigma == 0.0:
        reacted = min(median, window)
    else:
        phi = lambda z: 0.5 * (1.0 + math.erf(z / math.sqrt(2.0)))  # noqa: E731 (the normal CDF)
        z = (math.log(window) - math.log(median)) / sigma
        reacted = median * math.exp(sigma**2 / 2) * phi(z - sigma) + window * (1.0 - phi(z))
    return limits.miss_probability * window + (1.0 - limits.miss_probability) * reacted


@dataclass(frozen=True)
class TakeoverRule:
    """When a simulated person takes over unasked (mixed initiative), by the HG-DAgger rule: once the
    learner's action departs from their own by more than ``delta`` ([-1, 1] units, any dimension)
    for as long as their reaction time, they steer until it is back within ``delta / 2``."""

    delta: float
    step_s: float = 0.05  # seconds per env step: a reaction time in steps, a step's share of their time

    def __post_init__(self):
        if not (0.0 < self.delta <= 2.0 and math.isfinite(self.delta)):
            raise ValueError(f'TakeoverRule.delta must be in (0, 2], got {self.delta!r}')
        if not (0.0 < self.step_s <= 60.0 and math.isfinite(self.step_s)):
            raise ValueError(f'TakeoverRule.step_s must be in (0, 60] seconds, got {self.step_s!r}')


@dataclass(frozen=True)
class HumanPlan:
    """What the simulated person will do about one request, and after how many seconds."""

    kind: str  # one of PLAN_KINDS; 'miss': never acts, the answer window passes
    delay_s: float  # reaction time (inf for a miss)
    action: Optional[np.ndarray] = None  # for 'answer': the noisy action, inside the bounds


class SimulatedHuman:
    """An Expert (core interface) that answers as ``expert`` would, with a person's limits.

    Calling it answers at once with the time the person would have taken
    (``Advice.response_time_s``); a reaction later than the answer window is a timeout.
    """

    human = True

    def __init__(
        self,
        expert,
        limits: Optional[HumanLimits] = None,
        seed: int = 0,
        name: str = '',
        takeover: Optional[TakeoverRule] = None,
        step_s: float = 0.05,
    ):
        self.expert = expert
        self.step_s = takeover.step_s if takeover is not None else step_s  # simulated seconds per env step
        self._wheel: Optional[tuple[float, float]] = None  # (press, release) of the wheel asked for
        self.limits = limits or HumanLimits()
        self.rng = np.random.default_rng(seed)
        self.takeover = takeover
        self._taking_over = False
        self._reacting_steps: Optional[int] = None  # steps left before they react to a departure
        self.name = name or f'simulated_human({getattr(expert, "name", type(expert).__name__)})'
        # The spaces it answers for are its expert's (checked against the env's).
        self.observation_size = getattr(expert, 'observation_size', None)
        self.action_size = getattr(expert, 'action_size', None)

    def _reaction_s(self) -> float:
        """One reaction time, seconds: log-normal around reaction_median_s."""
        limits = self.limits
        return float(limits.reaction_median_s * math.exp(limits.reaction_sigma * self.rng.standard_normal()))

    def plan(self, request: AdviceRequest) -> HumanPlan:
        """Draw what the person does about ``request``: one uniform draw picks miss, skip or
        answer; a log-normal draw gives the reaction time; Gaussian noise perturbs the action."""
        limits = self.limits
        draw = self.rng.random()
        delay = self._reaction_s()
        if draw < limits.miss_probability:
            return HumanPlan('miss', math.inf)
        if draw < limits.miss_probability + limits.skip_probability:
            return HumanPlan('skip', delay)
        advice = self.expert(request)
        if not advice.advised:
            return HumanPlan('skip', delay)  # the person's model has no answer either
        low = np.asarray(request.action_low, dtype=np.float32)
        high = np.asarray(request.action_high, dtype=np.float32)
        noise = self.rng.standard_normal(low.shape[0]) * limits.action_noise * (high - low) / 2.0
        action = np.clip(np.asarray(advice.action, dtype=np.float32) + noise.astype(np.float32), low, high)
        return HumanPlan('answer', delay, action)

    def outcome(self, plan: HumanPlan, window_s: Optional[float] = None) -> Advice:
        """What ``plan`` comes to when the person is given ``window_s`` (default: answer_window_s)."""
        window = self.limits.answer_window_s if window_s is None else window_s
        if plan.kind == 'miss' or plan.delay_s > window:
            return Advice.no_answer(window, self.name)
        if plan.kind == 'skip':
            return Advice.decline(SKIPPED, self.name, human=True, response_time_s=plan.delay_s)
        return Advice(plan.action, expert_name=self.name, human=True, response_time_s=plan.delay_s)

    def __call__(self, request: AdviceRequest) -> Advice:
        return self.outcome(self.plan(request))

    def alerted(self, now: float) -> None:
        """Asked at ``now`` to take the wheel (core/experts/wheel.py): one uniform draw picks
        whether the person lets it pass (a miss or a skip: they never press), else they press the
        deadman after a reaction time and release it stretch_s later."""
        limits = self.limits
        if self.rng.random() < limits.miss_probability + limits.skip_probability:
            self._wheel = None
            return
        press = now + self._reaction_s()
        self._wheel = (press, press + limits.stretch_s)

    def wheel_command(self, request: AdviceRequest, now: float) -> Optional[PersonCommand]:
        """The person's command at ``now`` for the state in ``request``: their model's action with
        their steering noise, the deadman held between their press and their release; None while
        they do not hold it."""
        if self._wheel is None or not self._wheel[0] <= now < self._wheel[1]:
            return None
        advice = self.expert(request)
        if not advice.advised:
            return None
        low = np.asarray(request.action_low, dtype=np.float32)
        high = np.asarray(request.action_high, dtype=np.float32)
        noise = self.rng.standard_normal(low.shape[0]) * self.limits.action_noise * (high - low) / 2.0
        action = np.clip(np.asarray(advice.action, dtype=np.float32) + noise.astype(np.float32), low, high)
        return PersonCommand(action, True, False, now, pressed_at=self._wheel[0])

    def intervene(self, request: AdviceRequest, new_episode: bool = False):
        """Mixed initiative (with a TakeoverRule; None otherwise): ``(action, seconds, starts)`` when
        the person takes this step over, else None. ``request`` carries the state and the learner's
        own action (proposed_action). The person's own action is their model's, with their steering
        noise; a step taken over costs them ``step_s`` seconds. Their reaction time is drawn once per
        departure, in steps; a departure that ends before they react is let pass."""
        rule = self.takeover
        if rule is None:
            return None
        if new_episode:
            self._taking_over, self._reacting_steps = False, None
        advice = self.expert(request)
        if not advice.advised:
            self._taking_over, self._reacting_steps = False, None
            return None
        low = np.asarray(request.action_low, dtype=np.float32)
        high = np.asarray(request.action_high, dtype=np.float32)
        half = (high - low) / 2.0
        own = np.asarray(advice.action, dtype=np.float32)
        apart = float(np.max(np.abs(own - np.asarray(request.proposed_action, dtype=np.float32)) / half))
        starts = False
        if self._taking_over:
            if apart <= rule.delta / 2.0:  # back where the learner can be trusted: hand back
                self._taking_over = False
                return None
        elif apart > rule.delta:
            if self._reacting_steps is None:
                reaction = self.limits.reaction_median_s * math.exp(
                    self.limits.reaction_sigma * self.rng.standard_normal()
                )
                self._reacting_steps = max(1, math.ceil(reaction / rule.step_s))
            self._reacting_steps -= 1
            if self._reacting_steps > 0:
                return None
            self._taking_over, self._reacting_steps, starts = True, None, True
        else:
            self._reacting_steps = None
            return None
        noise = self.rng.standard_normal(low.shape[0]) * self.limits.action_noise * half
        action = np.clip(own + noise.astype(np.float32), low, high)
        return action, rule.step_s, starts
