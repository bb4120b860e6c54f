"""What the networks read: an observation from the env, checked and made a tensor.

The learner's networks never see raw input. An observation part offers:
- ``dim``: the size of the flat tensor ``tensor(obs)`` gives (what the replay and the update carry);
- ``tensor(obs)``: the observation checked, as a [1, dim] float32 tensor;
- ``features(obs_t)``: what the actor and the critics read from such tensors;
- ``features_dim``: its size; ``encoder``: the module with weights of its own in between (None);
- ``state(obs)``: the observation's vector part (for the success rule and an advice request).

``VectorObservation``: a flat vector; the networks read it as it is. ``CameraObservation``: a
state vector and a camera's stack of frames, ``{'state': vector, 'pixels': uint8 [k, H, W, C]}``
(the keys of gymnasium's AddRenderObservation; the stack as gymnasium's FrameStackObservation
gives it, oldest first); an ObservationEncoder (image_encoder.py), trained by the critics' loss,
makes its features."""

from __future__ import annotations

from typing import Mapping, Optional

import numpy as np
import torch

from ..envs.spec import CameraSpec
from .image_encoder import FEATURES, ImageEncoder, ObservationEncoder


def checked_vector(values, size: int, what: str = 'observation') -> np.ndarray:
    """``values`` as a flat float32 array of ``size`` finite values, or a ValueError."""
    array = np.asarray(values, dtype=np.float32).reshape(-1)
    if array.shape[0] != size:
        raise ValueError(f'{what} has {array.shape[0]} values, the learner expects {size}')
    if not np.isfinite(array).all():
        raise ValueError(f'{what} holds a non-finite value (NaN or inf)')
    return array


class VectorObservation:
    """A flat vector of ``dim`` finite floats."""

    encoder: Optional[ObservationEncoder] = None
    camera: Optional[CameraSpec] = None

    def make_encoder(self) -> None:
        return None

    def __init__(self, dim: int, device: torch.device):
        if dim < 1:
            raise ValueError(f'obs_dim must be >= 1, got {dim}')
        self.dim = self.features_dim = self.state_dim = int(dim)
        self.device = device

    def tensor(self, obs) -> torch.Tensor:
        """``obs`` as a [1, dim] float32 tensor on the learner's device, or a ValueError."""
        return torch.from_numpy(checked_vector(obs, self.dim)).unsqueeze(0).to(self.device)

    def features(self, obs_t: torch.Tensor) -> torch.Tensor:
        return obs_t

    def state(self, obs) -> np.ndarray:
        return np.asarray(obs, dtype=np.float32).reshape(-1)

    def pixels(self, obs) -> None:
        return None  # no camera


class CameraObservation:
    """A state vector of ``state_dim`` finite floats (0: pixels alone) and a camera's frame
    stack; the networks read the state and the encoder's features of the stack."""

    def __init__(self, state_dim: int, camera: CameraSpec, device: torch.device):
        if state_dim < 0:
            raise ValueError(f'the state beside a camera must have >= 0 values, got {state_dim}')
        self.state_dim, self.camera, self.device = int(state_dim), camera, device
        self.dim = self.state_dim + camera.stack_size
        ImageEncoder.output_dim(camera.stack * camera.channels, camera.height, camera.width)  # refuses a small frame
        self.features_dim = self.state_dim + FEATURES
        self.encoder: Optional[ObservationEncoder] = None  # made by make_encoder, with the networks

    def make_encoder(self) -> ObservationEncoder:
        """The encoder's first weights, from torch's global generator (the learner seeds it)."""
        self.encoder = ObservationEncoder(self.state_dim, self.camera).to(self.device)
        return self.encoder

    def parts(self, obs) -> tuple[np.ndarray, np.ndarray]:
        """(state float32 [state_dim], pixels uint8 [k, H, W, C]) of ``obs``, or a ValueError
        that says what was wrong."""
        if not isinstance(obs, Mapping) or 'pixels' not in obs:
            raise ValueError(
                "an observation with a camera is {'state': vector, 'pixels': uint8 [k, H, W, C]}, "
                f'got {type(obs).__name__}'
            )
        pixels = np.asarray(obs['pixels'])
        if pixels.dtype != np.uint8:
            raise ValueError(f'camera pixels must be uint8, got {pixels.dtype}')
        expected = self.camera.stack_shape
        if pixels.shape != expected and not (self.camera.stack == 1 and pixels.shape == expected[1:]):
            raise ValueError(f'camera pixels have shape {pixels.shape}, the learner reads {expected} (k, H, W, C)')
        state = checked_vector(obs.get('state', ()), self.state_dim, 'the state beside the camera')
        return state, pixels.reshape(expected)

    def flat(self, obs) -> np.ndarray:
        """The state, then the stack channel-first ([k*C, H, W] flattened), as float32."""
        state, pixels = self.parts(obs)
        return np.concatenate([state, pixels.transpose(0, 3, 1, 2).reshape(-1).astype(np.float32)])

    def tensor(self, obs) -> torch.Tensor:
        return torch.from_numpy(self.flat(obs)).unsqueeze(0).to(self.device)

    def features(self, obs_t: torch.Tensor) -> torch.Tensor:
        if self.encoder is None:
            raise RuntimeError('make_encoder() before features()')
        return self.encoder(obs_t)

    def state(self, obs) -> np.ndarray:
        return self.parts(obs)[0]

    def pixels(self, obs) -> np.ndarray:
        """A copy of the observation's frame stack, uint8 [k, H, W, C]."""
        return self.parts(obs)[1].copy()
