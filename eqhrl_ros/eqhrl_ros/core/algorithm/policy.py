"""The policy that acts, pi(.|s): the squashed-Gaussian actor in env units, and E(s) of it."""

from __future__ import annotations

import numpy as np
import torch

from ..envs.spec import ActionScaler
from . import equations as eq
from .config import LearnerConfig
from .networks import SquashedGaussianActor
from .observations import CameraObservation, VectorObservation
from .streams import RandomStreams


class Policy:
    """The acting half of SAC. Its actor's weights are learned by the Updater; acting never
    changes them (inference mode), and draws only from the 'act', 'warmup' and 'entropy' streams."""

    def __init__(
        self,
        actor: SquashedGaussianActor,
        scaler: ActionScaler,
        observation: VectorObservation | CameraObservation,
        streams: RandomStreams,
        config: LearnerConfig,
    ):
        self.actor = actor
        self.scaler = scaler
        self.observation = observation
        self.streams = streams
        self.config = config

    @property
    def action_dim(self) -> int:
        return self.scaler.dim

    @torch.inference_mode()
    def act(self, obs, deterministic: bool = False) -> np.ndarray:
        """The policy's action in env units, without gates or counters (evaluation)."""
        mean, log_std = self.actor(self.observation.features(self.observation.tensor(obs)))
        if deterministic:
            return self.scaler.to_env(torch.tanh(mean)[0].cpu().numpy())
        noise = self.streams.noise(mean.shape, 'act')
        return self.scaler.to_env(eq.squashed_gaussian_action(mean, log_std, noise)[0].cpu().numpy())

    def sample(self, obs_t: torch.Tensor, warming_up: bool) -> tuple:
        """(mean, log_std, a_t in [-1, 1]) for s_t (``obs_t``: what the networks read, the
        observation part's features): a_t ~ pi(.|s_t), or uniform while ``warming_up``
        (random_warmup_steps)."""
        mean, log_std = self.actor(obs_t)
        if warming_up:
            action = self.streams.noise(mean.shape, 'warmup', uniform=True) * 2.0 - 1.0
        else:
            action = eq.squashed_gaussian_action(mean, log_std, self.streams.noise(mean.shape, 'act'))
        return mean, log_std, action

    def entropy(self, mean: torch.Tensor, log_std: torch.Tensor) -> float:
        """E(s), Eq. 9: exact, or by Monte Carlo (entropy_estimator)."""
        if self.config.entropy_estimator == 'exact':
            return float(eq.policy_entropy(mean, log_std))
        k_noise = self.streams.noise((self.config.entropy_samples, *mean.shape), 'entropy')
        return float(eq.policy_entropy_monte_carlo(mean, log_std, k_noise))

    def to_env(self, action: torch.Tensor) -> np.ndarray:
        """A [1, action_dim] action in [-1, 1] in env units."""
        return self.scaler.to_env(action[0].cpu().numpy())

    def normalize(self, action) -> np.ndarray:
        """An action in env units as stored in D: mapped to [-1, 1] and clipped there."""
        return np.clip(self.scaler.to_normalized(action), -1.0, 1.0)
