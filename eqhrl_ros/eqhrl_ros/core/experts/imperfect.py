"""Experts worse than the controller they wrap, for asking what a person's imperfection costs.

A noisy hand and missed requests are SimulatedHuman's (core/experts/simulated_human.py). These add
the two limits it cannot express, as wrappers around any expert:
- ``DelayedExpert``: the answer is for the state some steps ago (a person reacts to what
  they saw, and the robot has moved on since).
- ``WeakExpert``: a timid controller, its action scaled by a gain below 1.
Both are Experts (core interface) and keep the wrapped expert's spaces.
"""

from __future__ import annotations

import dataclasses
from collections import deque

import numpy as np

from ..data.advice import Advice, AdviceRequest


class DelayedExpert:
    """Answers a request with the wrapped expert's answer for the observation ``delay_steps``
    steps before it, in the same episode (early in an episode: the episode's first one).

    The training loop shows it every observation (``observe``); train() does this for any
    expert with an ``observe`` method.
    """

    def __init__(self, expert, delay_steps: int):
        if delay_steps < 0:
            raise ValueError(f'delay_steps must be >= 0, got {delay_steps}')
        self.expert = expert
        self.delay_steps = int(delay_steps)
        self._seen: deque = deque(maxlen=self.delay_steps + 1)
        self.name = f'delayed({getattr(expert, "name", type(expert).__name__)}, {self.delay_steps} steps)'
        self.human = getattr(expert, 'human', False)
        self.observation_size = getattr(expert, 'observation_size', None)
        self.action_size = getattr(expert, 'action_size', None)

    def observe(self, obs, new_episode: bool = False) -> None:
        if new_episode:
            self._seen.clear()
        self._seen.append(np.asarray(obs, dtype=np.float32).copy())

    def __call__(self, request: AdviceRequest) -> Advice:
        earlier = self._seen[0] if self._seen else request.observation
        return self.expert(dataclasses.replace(request, observation=earlier))


class WeakExpert:
    """The wrapped expert's action times ``gain`` (0 < gain <= 1): right in direction, timid in size."""

    def __init__(self, expert, gain: float):
        if not 0.0 < gain <= 1.0:
            raise ValueError(f'gain must be in (0, 1], got {gain}')
        self.expert = expert
        self.gain = float(gain)
        self.name = f'weak({getattr(expert, "name", type(expert).__name__)}, gain {self.gain:g})'
        self.human = getattr(expert, 'human', False)
        self.observation_size = getattr(expert, 'observation_size', None)
        self.action_size = getattr(expert, 'action_size', None)

    def __call__(self, request: AdviceRequest) -> Advice:
        advice = self.expert(request)
        if not advice.advised:
            return advice
        return dataclasses.replace(advice, action=np.asarray(advice.action, dtype=np.float32) * self.gain)
