"""The learner's random streams: one per purpose, so that e.g. estimating E(s) never shifts the
noise of the policy's own actions, and every path of the update draws the same numbers."""

from __future__ import annotations

import torch

# Every stream a learner draws from, in the order they are seeded (seed + i).
STREAMS = ('act', 'update', 'replay', 'entropy', 'warmup', 'request')


class RandomStreams:
    """CPU generators on every device (noise()): the same random numbers on a GPU as on the CPU."""

    def __init__(self, seed: int, device: torch.device):
        self.device = device
        self.generators = {name: torch.Generator().manual_seed(seed + i) for i, name in enumerate(STREAMS)}

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
