"""A gymnasium env seen through a camera: its own rendering as the camera, beside its state.

``camera_env(env_id, camera)`` wraps ``make_env`` with gymnasium's own wrappers, so that the
tests, studies and benchmarks of learning from pixels need no robot:

1. ``AddRenderObservation``: the observation becomes {'state': the env's vector, 'pixels': its
   rgb_array rendering};
2. ``TransformObservation``: the rendering resized to the camera's height x width (torch's area
   interpolation: gymnasium's ResizeObservation needs OpenCV, not a dependency here) and, for a
   one-channel camera, made grey (ITU-R 601 weights, as gymnasium's GrayscaleObservation);
3. ``FrameStackObservation``: the last ``stack`` observations, an episode's first repeated
   (padding 'reset'), then the state taken from the newest.

The observation is what EQSACLearner reads with that CameraSpec: {'state': float32 [n],
'pixels': uint8 [stack, height, width, channels]}.
"""

from __future__ import annotations

from typing import cast

import gymnasium as gym
import numpy as np
from gymnasium.wrappers import AddRenderObservation, FrameStackObservation, TransformObservation

from .gymnasium_envs import make_env
from .spec import CameraSpec

GREY_WEIGHTS = np.array([0.299, 0.587, 0.114], np.float32)  # ITU-R 601-2 luma


def resized(frame: np.ndarray, camera: CameraSpec) -> np.ndarray:
    """An (H, W, 3) uint8 rendering at the camera's height x width (area interpolation), grey
    when the camera has one channel: (height, width, channels) uint8."""
    import torch  # here: gym_env's camera imports this module, and needs torch only for a frame

    image = torch.from_numpy(np.ascontiguousarray(frame)).permute(2, 0, 1).unsqueeze(0).float()
    image = torch.nn.functional.interpolate(image, size=(camera.height, camera.width), mode='area')[0]
    pixels = image.permute(1, 2, 0).numpy()
    if camera.channels == 1:
        pixels = (pixels @ GREY_WEIGHTS)[..., None]
    return np.clip(np.rint(pixels), 0, 255).astype(np.uint8)


def camera_env(env_id: str, camera: CameraSpec, max_episode_steps: int | None = None) -> gym.Env:
    """``env_id`` (make_env's episode lengths) observed as {'state', 'pixels'}: see the module."""
    rendered = AddRenderObservation(
        make_env(env_id, max_episode_steps, render_mode='rgb_array'),
        render_only=False,
        render_key='pixels',
        obs_key='state',
    )
    state_space = cast(gym.spaces.Dict, rendered.observation_space)['state']
    frame_space = gym.spaces.Box(0, 255, (camera.height, camera.width, camera.channels), np.uint8)
    resized_env = TransformObservation(
        rendered,
        lambda obs: {'state': obs['state'], 'pixels': resized(obs['pixels'], camera)},
        gym.spaces.Dict({'state': state_space, 'pixels': frame_space}),
    )
    stacked = FrameStackObservation(resized_env, camera.stack, padding_type='reset')
    stack_space = gym.spaces.Box(0, 255, camera.stack_shape, np.uint8)
    return TransformObservation(
        stacked,
        lambda obs: {'state': np.asarray(obs['state'][-1], np.float32), 'pixels': np.asarray(obs['pixels'])},
        gym.spaces.Dict({'state': state_space, 'pixels': stack_space}),
    )
