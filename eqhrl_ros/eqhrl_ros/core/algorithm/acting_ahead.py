"""Acting ahead: the compiled update also computes the next step's acting tensors.

After an env step, Algorithm 1 updates the networks and then proposes a_{t+1} for s_{t+1},
which the update already knows (it is the transition's s'). So, in the modes whose gates read
D(s) or E(s), the compiled program (update.update_then_act) ends with pi(.|s_{t+1}) from the
weights it has just stepped: the action a_{t+1} with the 'act' stream's next noise, D(s) (Eq. 8)
and the exact E(s) (Eq. 9) as the gates read them. propose() takes them instead of running the
actor and the critics again on one observation, eagerly and cold after the update.

What propose() takes is what it would have computed, to float rounding:
- the same observation (compared value by value; after an episode's end the reset observation
  is another one, and propose() computes as before);
- the same weights: nothing has changed them since (each weight's in-place version counter,
  and the networks' identity: a loaded checkpoint or weights from a trainer make it stale);
- the same noise: the 'act' stream's next draw, drawn ahead (streams.draw_ahead), which every
  draw from that stream takes first, whether the result is used or not. So the stream gives the
  same numbers in the same order either way, and a checkpoint saves it as before the draw.
"""

from __future__ import annotations

from typing import Callable, Optional

import torch

from .streams import RandomStreams

# Only where the gates read D(s) or E(s). Measured in the loop (benchmarks/acting_ahead.py,
# docs/performance.md "Acting ahead"): EQSAC's step 1.01-1.06x as fast, its propose 0.14-0.17 ms
# against 0.49-0.62; SAC's step 0.99-1.03x, the program's part costing about what its propose
# (the actor alone on one observation) saved.


class ActingAhead:
    """What the last compiled update computed for the observation it expected next.

    ``discrepancy``, ``entropy``: whether the program computes D(s) and the exact E(s) (the
    gates read them); a Monte Carlo E(s) is computed by propose() from the mean and log std.
    With neither, the program does not act ahead (``enabled``; the comment above)."""

    def __init__(self, streams: RandomStreams, action_dim: int, discrepancy: bool = False, entropy: bool = False):
        self.streams = streams
        self.action_dim = action_dim
        self.flags = (bool(discrepancy), bool(entropy))
        self.enabled = any(self.flags)
        self._kept: Optional[tuple] = None  # (observation, noise, weights' token, what was computed)

    def inputs(self, obs_t: Optional[torch.Tensor], obs_dim: int) -> Optional[tuple]:
        """update_then_act's ``ahead`` for ``obs_t`` ([1, obs_dim]: the observation expected
        next; None: no observation comes next, and the program's acting is for a made-up one,
        with no draw). None where the program does not act ahead."""
        if not self.enabled:
            return None
        if obs_t is None:
            zeros = [torch.zeros(1, n, device=self.streams.device) for n in (obs_dim, self.action_dim)]
            return (*zeros, *self.flags)
        return (obs_t, self.streams.draw_ahead((1, self.action_dim), 'act'), *self.flags)

    def keep(self, ahead: Optional[tuple], acted: Optional[dict], token: tuple) -> None:
        """What the program computed for ``ahead`` (inputs()), with the weights' ``token`` after it."""
        if ahead is not None and acted is not None and self.streams.drawn_ahead('act') is ahead[1]:
            # A copy: the observation may share memory with the caller's array, changed in place later.
            self._kept = (ahead[0].clone(), ahead[1], token, acted)

    def forget(self) -> None:
        self._kept = None

    def take(self, obs_t: torch.Tensor, token: Callable[[], tuple]) -> Optional[dict]:
        """What was computed for ``obs_t``, where it still holds (module docstring; ``token()``:
        the weights' token now), its noise then taken from the 'act' stream; else None. Either
        way, it is forgotten."""
        kept, self._kept = self._kept, None
        if kept is None:
            return None
        obs, noise, kept_token, acted = kept
        if (
            kept_token != token()
            or self.streams.drawn_ahead('act') is not noise
            or obs.shape != obs_t.shape
            or not torch.equal(obs, obs_t)
        ):
            return None
        self.streams.noise(noise.shape, 'act')  # the draw it used, taken: the stream moves past it
        return acted


def weights_token(networks: tuple, parameters: list) -> tuple:
    """What changes when the weights do: the networks' identity, and each weight's version
    counter (every in-place change of a tensor, an Adam step or a load_state_dict, moves it)."""
    return (*map(id, networks), *(p._version for p in parameters))
