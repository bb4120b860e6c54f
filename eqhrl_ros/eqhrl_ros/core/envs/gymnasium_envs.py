"""gymnasium envs: construction, their EnvSpec and their built-in success rules (the action
scaling lives in env_spec.py, without gymnasium)."""

from __future__ import annotations

import os
from typing import cast

import gymnasium as gym
import numpy as np

from . import spec as env_spec
from .spec import EnvSpec, SuccessCriterion, builtin_success

# What each action value does, for a person steering (gymnasium's own documentation of the envs).
ACTION_LABELS = {
    'Pendulum-v1': ('torque (+ increases the angle θ)',),
    'LunarLanderContinuous-v3': ('main engine (fires above 0)', 'side engines (left below -0.5, right above +0.5)'),
}

# Table 2 and Table 3 of the paper.
PAPER_MAX_EPISODE_STEPS = {'Pendulum-v1': 100, 'LunarLanderContinuous-v3': 600}


def make_env(env_id: str, max_episode_steps: int | None = None, render_mode: str | None = None) -> gym.Env:
    """gymnasium.make with the episode length of the paper unless one is given.

    LunarLanderContinuous-v3 is an alias of LunarLander-v3 with continuous=True.
    """
    steps = max_episode_steps or PAPER_MAX_EPISODE_STEPS.get(env_id)
    if render_mode == 'rgb_array':
        # Frames drawn off screen need no window: SDL's dummy video driver draws the same frames, and
        # SDL's default one printed "error: XDG_RUNTIME_DIR is invalid" in every container
        # (pygame.init() of the box2d envs). A driver the user chose is kept.
        os.environ.setdefault('SDL_VIDEODRIVER', 'dummy')
    env = gym.make(env_id, max_episode_steps=steps, render_mode=render_mode)
    if not isinstance(env.action_space, gym.spaces.Box):
        env.close()
        raise ValueError(
            f'{env_id} has a {type(env.action_space).__name__} action space; EQ-HRL needs a continuous (Box) one'
        )
    return env


def gym_spec(env_id: str, max_episode_steps: int | None = None, env: gym.Env | None = None, **pace) -> EnvSpec:
    """The EnvSpec of a gymnasium id (no episode is run): sizes, bounds, episode length and
    the built-in success rule. ``env``: an env already made for the id; ``pace``: realtime, rate_hz."""
    made = env is None
    the_env = make_env(env_id, max_episode_steps) if env is None else env
    try:
        rule, threshold = builtin_success(env_id)
        limit = the_env.spec.max_episode_steps if the_env.spec is not None else None
        actions = cast(gym.spaces.Box, the_env.action_space)  # make_env refuses any other kind
        return EnvSpec(
            env_id,
            int(np.prod(the_env.observation_space.shape or ())),
            actions.low,
            actions.high,
            action_labels=ACTION_LABELS.get(env_id, ()),
            max_episode_steps=int(max_episode_steps or limit or 0),
            success_rule=rule,
            success_threshold=threshold,
            source=f'env_id {env_id}',
            **pace,
        )
    finally:
        if made:
            the_env.close()


def success_criterion(env_id: str) -> SuccessCriterion:
    """The built-in success rule of a gymnasium env (env_spec.builtin_success)."""
    return env_spec.success_criterion(*builtin_success(env_id))
