"""An env as the learner sees it (core/envs): a gymnasium id's spec, and actions between env
units and the learner's [-1, 1]."""

import numpy as np
import pytest

from eqhrl_ros.core.envs.gymnasium_envs import gym_spec
from eqhrl_ros.core.envs.spec import ActionScaler


def test_a_gymnasium_ids_spec_has_its_sizes_bounds_and_episode_length():
    spec = gym_spec('Pendulum-v1', 100)
    assert spec.observation_size == 3 and spec.action_size == 1 and spec.max_episode_steps == 100
    assert spec.action_low.tolist() == [-2.0] and spec.action_high.tolist() == [2.0]
    lander = gym_spec('LunarLanderContinuous-v3', 600)
    assert lander.observation_size == 8 and lander.action_size == 2


def test_actions_go_to_minus_one_one_and_back():
    scaler = ActionScaler([-2.0, 0.0], [2.0, 10.0])
    env = np.array([1.0, 7.5], np.float32)
    normalized = scaler.to_normalized(env)
    assert normalized == pytest.approx([0.5, 0.5])
    assert scaler.to_env(normalized) == pytest.approx(env)
    assert scaler.to_env(np.array([-1.0, 1.0])) == pytest.approx([-2.0, 10.0])
