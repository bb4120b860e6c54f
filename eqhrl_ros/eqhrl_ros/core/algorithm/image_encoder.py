"""The image encoder and its augmentation (issue 49, item 2).

The shape DrQ-v2 and SAC-AE use for learning from pixels with an actor-critic:
- ``ImageEncoder``: a stack of k frames, uint8 [B, k*C, H, W], scaled to [-0.5, 0.5], then four
  3x3 convolutions of 32 filters (the first with stride 2), each followed by a ReLU, flattened.
  The critics' loss trains it; the actor reads its output detached, so that the actor's loss
  never moves it (DrQ-v2, Section 3.1; SAC-AE, Section 5).
- ``random_shift``: each image of a batch padded by ``pad`` pixels (edge pixels repeated) and
  cropped back at a random integer offset in [0, 2 pad] on each axis, its own per image
  (DrQ-v2's augmentation, pad 4 at 84x84). It is applied to the batches an update samples,
  never to the observation the learner acts on.

- ``ObservationEncoder``: what the actor and the critics read from an observation with a camera:
  its state vector, then the ImageEncoder's features of its frame stack through SAC-AE's head
  (a linear layer to 50, LayerNorm, tanh). The learner's replay and
  update carry such an observation flat (observations.CameraObservation): the state, then the
  stack's values channel-first, as floats in [0, 255].

The gates read the encoded state as they read a vector today: D(s) from the twin critics on
it, E(s) from the actor's output on it.
"""

from __future__ import annotations

import torch
from torch import nn

from ..envs.spec import CameraSpec

FILTERS = 32
LAYERS = 4
CPU_CHUNK = 64  # images through the convolutions at a time on the CPU (ImageEncoder.scaled)
FEATURES = 50  # what the encoder gives the networks beside the state (SAC-AE's and DrQ's 50)


def conv_output_size(size: int) -> int:
    """Height (or width) after the encoder's convolutions: 3x3, no padding, stride 2 then 1."""
    size = (size - 3) // 2 + 1
    return size - 2 * (LAYERS - 1)


MIN_SIZE = 2 * (2 * (LAYERS - 1) + 1) + 1  # the smallest height and width the convolutions leave 1 pixel of


class ImageEncoder(nn.Module):
    """uint8 [B, k*C, H, W] frame stacks to float [B, dim] features."""

    def __init__(self, stacked_channels: int, height: int, width: int):
        super().__init__()
        self.dim = self.output_dim(stacked_channels, height, width)
        self.input_shape = (int(stacked_channels), int(height), int(width))
        layers: list[nn.Module] = [nn.Conv2d(stacked_channels, FILTERS, 3, stride=2), nn.ReLU()]
        for _ in range(LAYERS - 1):
            layers += [nn.Conv2d(FILTERS, FILTERS, 3, stride=1), nn.ReLU()]
        self.convs = nn.Sequential(*layers)

    @staticmethod
    def output_dim(stacked_channels: int, height: int, width: int) -> int:
        """The features' size for such frames, or a ValueError when they are too small."""
        if min(conv_output_size(height), conv_output_size(width)) < 1:
            raise ValueError(
                f'frames of {height}x{width} are too small for the encoder (at least {MIN_SIZE}x{MIN_SIZE})'
            )
        return FILTERS * conv_output_size(height) * conv_output_size(width)

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        if frames.dtype != torch.uint8 or tuple(frames.shape[1:]) != self.input_shape:
            raise ValueError(
                f'the encoder reads uint8 [B, {", ".join(map(str, self.input_shape))}], '
                f'got {frames.dtype} {list(frames.shape)}'
            )
        return self.scaled(frames.float() / 255.0 - 0.5)

    def scaled(self, x: torch.Tensor) -> torch.Tensor:
        """Features of float frames already scaled to [-0.5, 0.5]. On the CPU, CPU_CHUNK images
        at a time: the same numbers per image, and at 84x84 stacked by 3 the convolutions of
        256 frames at once, forward and backward, took 1.31 s against 0.57 s by 64s or 128s
        (2 cores; benchmarks/bench_pixels.py), their activations no longer fitting the caches."""
        if x.device.type != 'cpu' or x.shape[0] <= CPU_CHUNK:
            return self.convs(x).flatten(1)
        return torch.cat([self.convs(chunk).flatten(1) for chunk in x.split(CPU_CHUNK)])


class ObservationEncoder(nn.Module):
    """A flat observation [B, state_dim + stack values] (CameraObservation's layout) to the
    features the networks read: [B, state_dim + FEATURES], the state first, unchanged, then the
    ImageEncoder's output projected to FEATURES values, layer-normalised and squashed by tanh
    (SAC-AE's head, Section 5: without it the critics' first layer would read 39,200 values
    at 84x84, ten million weights each)."""

    def __init__(self, state_dim: int, camera: CameraSpec):
        super().__init__()
        self.state_dim, self.camera = int(state_dim), camera
        self.stacked_shape = (camera.stack * camera.channels, camera.height, camera.width)
        self.image = ImageEncoder(*self.stacked_shape)
        self.head = nn.Sequential(nn.Linear(self.image.dim, FEATURES), nn.LayerNorm(FEATURES), nn.Tanh())
        self.dim = self.state_dim + FEATURES

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        state, frames = obs[:, : self.state_dim], obs[:, self.state_dim :]
        features = self.head(self.image.scaled(frames.reshape(-1, *self.stacked_shape) / 255.0 - 0.5))
        return torch.cat([state, features], dim=1)


def random_shift(frames: torch.Tensor, pad: int, generator: torch.Generator) -> torch.Tensor:
    """Each [C, H, W] image of ``frames`` [B, C, H, W] shifted by its own random integer offset
    of at most ``pad`` pixels per axis, the edge pixels repeated into the gap. Any dtype."""
    if pad == 0:
        return frames
    batch, _, height, width = frames.shape
    padded = nn.functional.pad(frames.float(), (pad, pad, pad, pad), mode='replicate').to(frames.dtype)
    dy = torch.randint(0, 2 * pad + 1, (batch, 1), generator=generator)
    dx = torch.randint(0, 2 * pad + 1, (batch, 1), generator=generator)
    rows = (torch.arange(height).unsqueeze(0) + dy)[:, :, None]  # [B, H, 1]
    cols = (torch.arange(width).unsqueeze(0) + dx)[:, None, :]  # [B, 1, W]
    shifted = padded[torch.arange(batch)[:, None, None], :, rows, cols]  # [B, H, W, C]
    return shifted.permute(0, 3, 1, 2).contiguous()
