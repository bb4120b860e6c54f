"""The learner's random streams: one per purpose, so that e.g. estimating E(s) never shifts the
noise of the policy's own actions, and every path of the update draws the same numbers."""

from __future__ import annotations

import numpy as np
import torch

# Every stream a learner draws from; 'networks' seeds the networks' first weights.
STREAMS = ('act', 'update', 'replay', 'entropy', 'warmup', 'request')


def stream_seeds(seed: int) -> dict:
    """A 64-bit seed per stream (and 'networks'), spawned from ``seed`` by numpy's SeedSequence:
    independent of each other and of every other seed's (seeding stream i with seed + i, as this
    package did until 2026-12, made seed k's update stream seed k+1's action stream)."""
    names = (*STREAMS, 'networks')
    children = np.random.SeedSequence(int(seed)).spawn(len(names))
    return {name: int(child.generate_state(1, np.uint64)[0]) for name, child in zip(names, children)}


class RandomStreams:
    """CPU generators on every device (noise()): the same random numbers on a GPU as on the CPU."""

    def __init__(self, seed: int, device: torch.device):
        self.device = device
        seeds = stream_seeds(seed)
        self.generators = {name: torch.Generator().manual_seed(seeds[name]) for name in STREAMS}

    def __getitem__(self, name: str) -> torch.Generator:
        return self.generators[name]

    def __iter__(self):
        return iter(self.generators)

    def items(self):
        return self.generators.items()

    def noise(self, shape, stream: str, uniform: bool = False) -> torch.Tensor:
        """Standard normal (or uniform [0, 1)) noise from ``stream``, on the learner's device."""
        draw = torch.rand if uniform else torch.randn
        return draw(shape, generator=self.generators[stream]).to(self.device)

    def uniform(self, stream: str) -> float:
        """One draw in [0, 1) from ``stream``, as a number (the random gates' draw)."""
        return float(torch.rand((), generator=self.generators[stream]))

    def state_dict(self) -> dict:
        return {name: gen.get_state() for name, gen in self.generators.items()}

    def loaded(self, state: dict) -> 'RandomStreams':
        """A copy with ``state``'s streams (a checkpoint from before a stream existed leaves that one as it is here)."""
        copy = RandomStreams.__new__(RandomStreams)
        copy.device = self.device
        copy.generators = {}
        for name, gen in self.generators.items():
            fresh = torch.Generator()
            fresh.set_state(state[name] if name in state else gen.get_state())
            copy.generators[name] = fresh
        return copy
