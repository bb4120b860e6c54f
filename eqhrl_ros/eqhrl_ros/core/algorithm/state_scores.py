"""Two scores of a state for gates beyond the paper (extensions, labelled so wherever they appear):

- ``novelty``: how far s lies from the states the learner has seen lately: the mean distance to
  its ``neighbours`` nearest among the last ``memory`` observations, each dimension standardised
  by its running mean and spread. In the spirit of ThriftyDAgger's novelty (ask where the learner
  is out of its depth); ThriftyDAgger measures it by an ensemble's disagreement, which is close to
  the paper's D(s) already, so this gate measures the state itself.
- ``advice_gain``: how much the expert's answers changed the action near s: the distance-weighted
  mean, over the ``neighbours`` nearest states that were answered, of |a_expert - a_policy| (in
  [-1, 1] units, the largest dimension). A gate of this package's own design, from the traces:
  ask where advice has made a difference, not where the critics merely disagree.

Both are small (a few thousand states, one torch.cdist a step) and not saved with a checkpoint:
after a resume they are rebuilt from the states that come.
"""

from __future__ import annotations

from typing import Optional

import torch


class RunningScale:
    """Per-dimension running mean and variance of every state seen (Welford), for standardising."""

    def __init__(self, dim: int, device):
        self.count = 0
        self.mean = torch.zeros(dim, device=device)
        self.m2 = torch.zeros(dim, device=device)

    def add(self, obs: torch.Tensor) -> None:
        self.count += 1
        delta = obs - self.mean
        self.mean += delta / self.count
        self.m2 += delta * (obs - self.mean)

    def standardised(self, obs: torch.Tensor) -> torch.Tensor:
        spread = (self.m2 / max(1, self.count - 1)).sqrt().clamp_min(1e-6)
        return (obs - self.mean) / spread


class StateNeighbours:
    """The last ``capacity`` states (raw) with a value each; their nearest to a state, standardised."""

    def __init__(self, dim: int, capacity: int, device):
        self.states = torch.zeros(capacity, dim, device=device)
        self.values = torch.zeros(capacity, device=device)
        self.capacity, self.size, self.next = capacity, 0, 0

    def __len__(self) -> int:
        return self.size

    def add(self, obs: torch.Tensor, value: float = 0.0) -> None:
        self.states[self.next] = obs
        self.values[self.next] = value
        self.next = (self.next + 1) % self.capacity
        self.size = min(self.size + 1, self.capacity)

    def nearest(self, obs: torch.Tensor, k: int, scale: RunningScale) -> tuple[torch.Tensor, torch.Tensor]:
        """(distances, values) of the ``k`` nearest stored states to ``obs``, standardised by ``scale``."""
        stored = scale.standardised(self.states[: self.size])
        distances = torch.cdist(scale.standardised(obs).unsqueeze(0), stored).squeeze(0)
        k = min(k, self.size)
        nearest = torch.topk(distances, k, largest=False)
        return nearest.values, self.values[: self.size][nearest.indices]


class StateScores:
    """The learner's memory of states for the ``novelty`` and ``advice_gain`` gates."""

    def __init__(self, dim: int, neighbours: int, memory: int, device):
        self.neighbours = neighbours
        self.scale = RunningScale(dim, device)
        self.seen = StateNeighbours(dim, memory, device)
        self.answered = StateNeighbours(dim, memory, device)
        self.last_seen: Optional[torch.Tensor] = None

    def novelty(self, obs: torch.Tensor) -> Optional[float]:
        """The mean distance of ``obs`` to its nearest seen states (None until there are enough)."""
        if len(self.seen) < self.neighbours:
            return None
        distances, _ = self.seen.nearest(obs, self.neighbours, self.scale)
        return float(distances.mean())

    def advice_gain(self, obs: torch.Tensor) -> Optional[float]:
        """The predicted change of the action an answer would make at ``obs`` (None until enough answers)."""
        if len(self.answered) < self.neighbours:
            return None
        distances, gains = self.answered.nearest(obs, self.neighbours, self.scale)
        weights = 1.0 / (distances + 1e-3)
        return float((weights * gains).sum() / weights.sum())

    def observe(self, obs: torch.Tensor) -> None:
        """A state the learner acted on (after it was scored: a state is never its own neighbour)."""
        self.scale.add(obs)
        self.seen.add(obs)
        self.last_seen = obs

    def answered_with(self, obs: torch.Tensor, gain: float) -> None:
        """An answer at ``obs`` changed the action by ``gain`` ([-1, 1] units, the largest dimension)."""
        self.answered.add(obs, gain)
