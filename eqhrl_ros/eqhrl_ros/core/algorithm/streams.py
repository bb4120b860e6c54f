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
    """CPU generators on every device (noise()): the same random numbers on a GPU as on the CPU.

    A stream's next draw can be made early (draw_ahead: the compiled update acts ahead with it,
    acting_ahead.py): noise() then returns it, and state_dict() saves the stream as it was before
    it, so that drawing ahead never changes a stream's numbers, in a run or across a resume."""

    def __init__(self, seed: int, device: torch.device):
        self.device = device
        seeds = stream_seeds(seed)
        self.generators = {name: torch.Generator().manual_seed(seeds[name]) for name in STREAMS}
        self.ahead: dict = {}  # stream -> (its generator's state before the draw, the draw)

    def __getitem__(self, name: str) -> torch.Generator:
        self._undo_ahead(name)  # the generator itself: as if nothing was drawn ahead
        return self.generators[name]

    def __iter__(self):
        return iter(self.generators)

    def items(self):
        for name in list(self.ahead):
            self._undo_ahead(name)
        return self.generators.items()

    def noise(self, shape, stream: str, uniform: bool = False) -> torch.Tensor:
        """Standard normal (or uniform [0, 1)) noise from ``stream``, on the learner's device:
        the draw made ahead, where it is the one asked for."""
        held = self.ahead.get(stream)
        if held is not None and not uniform and tuple(held[1].shape) == tuple(shape):
            del self.ahead[stream]
            return held[1]
        self._undo_ahead(stream)  # another draw was asked for: as if none was made ahead
        draw = torch.rand if uniform else torch.randn
        return draw(shape, generator=self.generators[stream]).to(self.device)

    def draw_ahead(self, shape, stream: str) -> torch.Tensor:
        """The standard normal noise that the next noise(shape, stream) will return, drawn now
        (the same tensor until then)."""
        held = self.ahead.get(stream)
        if held is not None and tuple(held[1].shape) == tuple(shape):
            return held[1]
        self._undo_ahead(stream)
        before = self.generators[stream].get_state()
        drawn = torch.randn(shape, generator=self.generators[stream]).to(self.device)
        self.ahead[stream] = (before, drawn)
        return drawn

    def drawn_ahead(self, stream: str):
        """The draw made ahead on ``stream`` and not yet taken (None when there is none)."""
        held = self.ahead.get(stream)
        return None if held is None else held[1]

    def _undo_ahead(self, stream: str) -> None:
        held = self.ahead.pop(stream, None)
        if held is not None:
            self.generators[stream].set_state(held[0])

    def uniform(self, stream: str) -> float:
        """One draw in [0, 1) from ``stream``, as a number (the random gates' draw)."""
        self._undo_ahead(stream)
        return float(torch.rand((), generator=self.generators[stream]))

    def state_dict(self) -> dict:
        """Each stream's state, a stream drawn ahead as it was before that draw."""
        return {
            name: self.ahead[name][0] if name in self.ahead else gen.get_state()
            for name, gen in self.generators.items()
        }

    def adopt(self, other: 'RandomStreams') -> None:
        """Take ``other``'s generators (a loaded checkpoint's), and forget any draw made ahead."""
        self.generators, self.ahead = other.generators, {}

    def loaded(self, state: dict) -> 'RandomStreams':
        """A copy with ``state``'s streams (a checkpoint from before a stream existed leaves that one as it is here)."""
        copy = RandomStreams.__new__(RandomStreams)
        copy.device = self.device
        copy.generators, copy.ahead = {}, {}
        own = self.state_dict()
        for name in self.generators:
            fresh = torch.Generator()
            fresh.set_state(state[name] if name in state else own[name])
            copy.generators[name] = fresh
        return copy
