"""Environment helpers: construction, action scaling and the per-env definition of success."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np

# Table 2 and Table 3 of the paper.
PAPER_MAX_EPISODE_STEPS = {'Pendulum-v1': 100, 'LunarLanderContinuous-v3': 600}


def make_env(env_id: str, max_episode_steps: int | None = None, render_mode: str | None = None) -> gym.Env:
    """gymnasium.make with the episode length of the paper unless one is given.

    LunarLanderContinuous-v3 is an alias of LunarLander-v3 with continuous=True.
    """
    steps = max_episode_steps or PAPER_MAX_EPISODE_STEPS.get(env_id)
    env = gym.make(env_id, max_episode_steps=steps, render_mode=render_mode)
    if not isinstance(env.action_space, gym.spaces.Box):
        env.close()
        raise ValueError(
            f'{env_id} has a {type(env.action_space).__name__} action space; EQ-HRL needs a continuous (Box) one'
        )
    return env


def env_spaces(env_id: str) -> tuple[int, np.ndarray, np.ndarray]:
    """Observation size and action bounds of an env id, from its spec (no episode is run)."""
    env = gym.make(env_id)
    try:
        return (
            int(np.prod(env.observation_space.shape)),
            env.action_space.low.astype(np.float32),
            env.action_space.high.astype(np.float32),
        )
    finally:
        env.close()


class ActionScaler:
    """Affine map between the policy's box [-1, 1]^m and the env's [low, high]."""

    def __init__(self, low, high):
        self.low = np.asarray(low, dtype=np.float32).reshape(-1)
        self.high = np.asarray(high, dtype=np.float32).reshape(-1)
        if self.low.shape != self.high.shape:
            raise ValueError('action low and high differ in size')
        if not (np.isfinite(self.low).all() and np.isfinite(self.high).all()):
            raise ValueError('EQ-HRL needs finite action bounds')
        if (self.high <= self.low).any():
            raise ValueError('action high must exceed low in every dimension')
        self.scale = (self.high - self.low) / 2.0
        self.center = (self.high + self.low) / 2.0

    @property
    def dim(self) -> int:
        return self.low.shape[0]

    def to_env(self, normalized: np.ndarray) -> np.ndarray:
        return (self.center + self.scale * np.asarray(normalized, dtype=np.float32)).astype(np.float32)

    def to_normalized(self, action: np.ndarray) -> np.ndarray:
        return ((np.asarray(action, dtype=np.float32) - self.center) / self.scale).astype(np.float32)


class SuccessCriterion:
    """Per-episode success, fed every step. Subclasses define it per env."""

    def reset(self) -> None:
        pass

    def update(self, obs: np.ndarray, reward: float) -> None:
        pass

    def success(self, episode_return: float) -> bool:
        return False


class ReturnAtLeast(SuccessCriterion):
    """Success when the episode's return reaches a threshold (LunarLander: 200, the env's solved line)."""

    def __init__(self, threshold: float):
        self.threshold = threshold

    def success(self, episode_return: float) -> bool:
        return episode_return >= self.threshold


class PendulumUpright(SuccessCriterion):
    """Success when the pendulum ends the episode balanced: its last ``hold_steps``
    observations all have cos(theta) >= cos(max_angle) (theta = 0 is upright)."""

    def __init__(self, max_angle_deg: float = 18.0, hold_steps: int = 10):
        self.min_cos = math.cos(math.radians(max_angle_deg))
        self.hold_steps = hold_steps
        self.reset()

    def reset(self) -> None:
        self._upright_run = 0

    def update(self, obs: np.ndarray, reward: float) -> None:
        self._upright_run = self._upright_run + 1 if obs[0] >= self.min_cos else 0

    def success(self, episode_return: float) -> bool:
        return self._upright_run >= self.hold_steps


def success_criterion(env_id: str) -> SuccessCriterion:
    if env_id.startswith('Pendulum'):
        return PendulumUpright()
    if env_id.startswith('LunarLander'):
        return ReturnAtLeast(200.0)
    return SuccessCriterion()
