"""The twin critics Q_theta1, Q_theta2 and their target copies, and D(s) from them (Eq. 8)."""

from __future__ import annotations

import copy

import torch

from . import equations as eq
from .networks import TwinCritic


class Critics:
    """The critics the Updater learns (Eq. 5) and the ask gate reads (Eq. 8)."""

    def __init__(self, critic: TwinCritic):
        self.critic = critic
        self.critic_target = copy.deepcopy(critic).requires_grad_(False)

    def discrepancy(self, obs_t: torch.Tensor, action: torch.Tensor) -> float:
        """D(s) = |Q_theta1(s, a) - Q_theta2(s, a)|, a the action about to be taken (Eq. 8)."""
        q1, q2 = self.critic(obs_t, action)
        return float(eq.q_discrepancy(q1, q2))
