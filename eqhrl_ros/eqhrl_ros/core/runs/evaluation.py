"""Advice-free evaluation: the deterministic policy alone, from a fixed set of start states.

A training episode inside the advising budget mixes the learner's actions with the expert's,
so its return is not the learner's. Every K episodes, the runner plays the policy's mean
action (tanh of the Gaussian mean: no noise, no gates, no expert, no storing, no update) from
the same start states, on an env of its own. It draws nothing from the learner's random
streams, so training goes exactly as it would without it (tests/core/runs/test_evaluation.py).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Sequence

# Start states are the env's resets with these seeds: far from the training seeds (0, 1, ...).
EVAL_SEED_BASE = 1_000_000
EVAL_FIELDS = ('episode', 'start', 'return', 'length', 'success')


def eval_seeds(count: int) -> list[int]:
    """The seeds of ``count`` fixed start states, the same for every run and algorithm."""
    return [EVAL_SEED_BASE + i for i in range(count)]


@dataclass(frozen=True)
class EvalEpisode:
    after_episode: int  # training episodes finished before this evaluation
    start: int  # the reset seed of its start state
    episode_return: float
    length: int
    success: bool

    def csv_row(self) -> list:
        return [self.after_episode, self.start, f'{self.episode_return:.4f}', self.length, int(self.success)]


def evaluate(env, learner, starts: Sequence[int]) -> list[EvalEpisode]:
    """One episode of the deterministic policy from each start seed; the env must end episodes."""
    criterion = copy.deepcopy(learner.success)  # the training episode's criterion is left alone
    results = []
    for start in starts:
        obs, _ = env.reset(seed=start)
        criterion.reset()
        total, length = 0.0, 0
        while True:
            obs, reward, terminated, truncated, info = env.step(learner.act(obs, deterministic=True))
            total += float(reward)
            length += 1
            criterion.update(obs, float(reward))
            if terminated or truncated:
                break
        results.append(EvalEpisode(learner.episode, start, total, length, criterion.success(total)))
    return results
