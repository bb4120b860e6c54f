"""A gymnasium env seen through a camera (issue 49, item 1, in process): the rendering resized,
grey where asked, stacked with an episode's first frame repeated, and read by a camera learner."""

import numpy as np
import pytest

from eqhrl_ros.core.algorithm.config import LearnerConfig
from eqhrl_ros.core.algorithm.learner import EQSACLearner
from eqhrl_ros.core.envs.camera_envs import camera_env, resized
from eqhrl_ros.core.envs.spec import CameraSpec


def test_the_observation_is_the_state_and_the_last_frames_of_the_rendering():
    camera = CameraSpec(32, 40, 3, 3)
    env = camera_env('Pendulum-v1', camera, max_episode_steps=5)
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    assert obs['state'].shape == (3,) and obs['pixels'].shape == (3, 32, 40, 3) and obs['pixels'].dtype == np.uint8
    assert all(np.array_equal(obs['pixels'][0], frame) for frame in obs['pixels'])  # the reset frame, repeated
    assert np.array_equal(resized(env.render(), camera), obs['pixels'][-1])  # the newest is what the env shows
    frames = [obs['pixels'][-1]]
    for _ in range(5):
        obs, _, _, truncated, _ = env.step(np.array([2.0], np.float32))
        frames.append(obs['pixels'][-1])
        assert np.array_equal(obs['pixels'], np.stack([frames[max(len(frames) - 3 + i, 0)] for i in range(3)]))
    assert truncated and not np.array_equal(frames[0], frames[-1])  # the pendulum moved, and the camera saw it
    obs, _ = env.reset(seed=1)
    assert all(np.array_equal(obs['pixels'][0], frame) for frame in obs['pixels'])  # a new episode starts over
    env.close()


def test_a_grey_camera_weighs_the_channels_as_gymnasium_does():
    frame = np.zeros((8, 8, 3), np.uint8)
    frame[..., 0], frame[..., 1], frame[..., 2] = 100, 200, 50
    grey = resized(frame, CameraSpec(4, 4, channels=1, stack=1))
    assert grey.shape == (4, 4, 1) and (grey == round(0.299 * 100 + 0.587 * 200 + 0.114 * 50)).all()
    assert (resized(frame, CameraSpec(4, 4, 3, 1)) == frame[:4, :4]).all()  # area resizing of a flat colour


@pytest.mark.parametrize('env_id', ['Pendulum-v1', 'LunarLanderContinuous-v3'])
def test_a_camera_learner_reads_what_the_env_shows(env_id):
    camera = CameraSpec(24, 24, 1, 2)
    env = camera_env(env_id, camera, max_episode_steps=6)
    low, high = env.action_space.low, env.action_space.high
    config = LearnerConfig(mode='eqsac', hidden=(16, 16), batch_size=4, learning_starts=4, replay_capacity=100)
    learner = EQSACLearner(env.observation_space['state'].shape[0], low, high, config, camera=camera)
    obs, _ = env.reset(seed=0)
    for _ in range(6):
        proposal = learner.propose(obs)
        next_obs, reward, terminated, truncated, _ = env.step(proposal.action)
        summary = learner.step(obs, proposal.action, reward, next_obs, terminated, truncated)
        obs = next_obs
        if summary is not None:
            break
    assert summary is not None and len(learner.replay) == summary.length and learner.updates > 0
    env.close()
