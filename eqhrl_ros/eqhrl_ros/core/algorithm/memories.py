"""The learner's two replay memories: D, and D_advising for the advised transitions (Section 3.3)."""

from __future__ import annotations

import numpy as np

from ..data.replay import Minibatch, ReplayBuffer
from .config import LearnerConfig, asks_for_advice
from .streams import RandomStreams


class ReplayMemories:
    """D and D_advising, what goes into each, and an update's batches from both."""

    def __init__(self, config: LearnerConfig, obs_dim: int, action_dim: int, streams: RandomStreams, device):
        self.config = config
        self.streams = streams
        self.device = device
        self.replay = ReplayBuffer(config.replay_capacity, obs_dim, action_dim)  # D
        self.advice_replay = ReplayBuffer(config.replay_capacity, obs_dim, action_dim)  # D_advising

    @property
    def keeps_advice(self) -> bool:
        """Whether advised transitions also go to D_advising (QASAC, EQSAC and the like, with dual_replay)."""
        return asks_for_advice(self.config.mode) and self.config.dual_replay

    def store(self, obs, normalized_action, reward: float, next_obs, terminated: bool, advised: bool) -> None:
        """(s_t, a_t, r_t, s_{t+1}) into D, and into D_advising when advised (QASAC, EQSAC).
        ``normalized_action`` in [-1, 1]. A bad transition raises ValueError."""
        self.replay.add(obs, normalized_action, reward, next_obs, terminated)
        if advised and self.keeps_advice:
            self.advice_replay.add(obs, normalized_action, reward, next_obs, terminated)

    def add_prior(self, observations, normalized_actions, rewards, next_observations, terminated) -> int:
        """Earlier runs' advised and person-initiated transitions, as prior data (RLPD, HIL-SERL):
        into D, and into D_advising where this mode has it. Actions in [-1, 1]. Each row is
        checked as store() checks it (ValueError names the first bad one; the rows before it stay)."""
        rows = 0
        for obs, action, reward, next_obs, done in zip(
            observations, normalized_actions, rewards, next_observations, terminated
        ):
            self.store(obs, np.clip(action, -1.0, 1.0), float(reward), next_obs, bool(done), advised=True)
            rows += 1
        return rows

    def ready(self) -> bool:
        """D holds learning_starts transitions: every step from now on updates."""
        return len(self.replay) >= self.config.learning_starts

    def sample(self) -> tuple[Minibatch, Minibatch | None]:
        """An update's batches: from D, and from D_advising (EQSAC and QASAC, Section 3.3; None
        while it is empty or in mode sac), sampled with replacement while it holds fewer than
        the batch asks for; ``advice_batch: proportional``: D_advising's share of the batch."""
        cfg, generator = self.config, self.streams['replay']
        batch = self.replay.sample(cfg.batch_size, generator).to(self.device)
        if not asks_for_advice(cfg.mode) or len(self.advice_replay) == 0:
            return batch, None
        size = cfg.batch_size
        if cfg.advice_batch == 'proportional':  # an ablation
            size = max(1, round(cfg.batch_size * len(self.advice_replay) / len(self.replay)))
        advice = self.advice_replay.sample(size, generator, replacement=len(self.advice_replay) < size)
        return batch, advice.to(self.device)
