"""What the networks read: an observation from the env, checked and made a tensor.

The learner's networks never see raw input: ``VectorObservation`` checks a flat vector's size
and finiteness and gives the [1, obs_dim] tensor the actor and the critics read. It is the seam
for other kinds of observation: an image encoder (with weights of its own, trained by the
critics' loss) is one more part in front of the networks, offering the same two members
(``dim``, the size of what it gives the networks, and ``tensor``)."""

from __future__ import annotations

import numpy as np
import torch


class VectorObservation:
    """A flat vector of ``dim`` finite floats."""

    def __init__(self, dim: int, device: torch.device):
        if dim < 1:
            raise ValueError(f'obs_dim must be >= 1, got {dim}')
        self.dim = int(dim)
        self.device = device

    def tensor(self, obs) -> torch.Tensor:
        """``obs`` as a [1, dim] float32 tensor on the learner's device, or a ValueError."""
        array = np.asarray(obs, dtype=np.float32).reshape(-1)
        if array.shape[0] != self.dim:
            raise ValueError(f'observation has {array.shape[0]} values, the learner expects {self.dim}')
        if not np.isfinite(array).all():
            raise ValueError('observation holds a non-finite value (NaN or inf)')
        return torch.from_numpy(array).unsqueeze(0).to(self.device)
