"""Built-in experts: controllers written for the shipped envs, and the check that an expert fits an env."""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from ..data.advice import Advice, AdviceRequest


@dataclass
class PendulumSwingUpExpert:
    """Pendulum-v1 controller: energy-based swing-up far from the top, PD balance near it.

    Pendulum-v1's dynamics are I*theta'' = (m*g*l/2) * sin(theta) + u with I = m*l^2/3 and
    theta = 0 upright, so E = I*theta'^2/2 + (m*g*l/2) * cos(theta) has dE/dt = theta' * u:
    pushing with the angular velocity pumps energy in until E reaches the upright
    value m*g*l/2; near the top a PD law holds the pendulum up.
    """

    observation_size = 3  # the spaces it is written for (checked against the env's)
    action_size = 1
    g: float = 10.0
    m: float = 1.0
    l: float = 1.0
    max_torque: float = 2.0
    swing_gain: float = 5.0
    kp: float = 12.0
    kd: float = 2.5
    balance_cos: float = math.cos(math.radians(35.0))
    name: str = 'pendulum_swing_up'

    def action(self, obs: np.ndarray) -> np.ndarray:
        cos_th, sin_th, th_dot = (float(v) for v in obs[:3])
        theta = math.atan2(sin_th, cos_th)
        if cos_th >= self.balance_cos:
            u = -self.kp * theta - self.kd * th_dot
        else:
            inertia = self.m * self.l**2 / 3.0
            energy = 0.5 * inertia * th_dot**2 + 0.5 * self.m * self.g * self.l * cos_th
            energy_up = 0.5 * self.m * self.g * self.l
            # Pump along theta' (a kick from rest when theta' is zero).
            direction = math.copysign(1.0, th_dot if abs(th_dot) > 1e-3 else 1.0)
            u = self.swing_gain * (energy_up - energy) * direction
        return np.array([np.clip(u, -self.max_torque, self.max_torque)], dtype=np.float32)

    def __call__(self, request: AdviceRequest) -> Advice:
        return Advice(self.action(request.observation), expert_name=self.name)


class LunarLanderExpert:
    """LunarLanderContinuous-v3: gymnasium's stock heuristic controller."""

    name = 'lunar_lander_heuristic'
    observation_size, action_size = 8, 2

    def __init__(self):
        from gymnasium.envs.box2d.lunar_lander import heuristic

        self._heuristic = heuristic
        # The heuristic reads env.unwrapped.continuous and nothing else of the env.
        self._env = SimpleNamespace(unwrapped=SimpleNamespace(continuous=True))

    def action(self, obs: np.ndarray) -> np.ndarray:
        return np.asarray(self._heuristic(self._env, obs), dtype=np.float32)

    def __call__(self, request: AdviceRequest) -> Advice:
        return Advice(self.action(request.observation), expert_name=self.name)


@dataclass
class DoubleIntegratorExpert:
    """The example env double_integrator (x'' = u, u in [-1, 1]): a PD law u = -kp x - kd v,
    critically damped for kp = 1, kd = 2 (both closed-loop poles at -1)."""

    observation_size = 2
    action_size = 1
    kp: float = 1.0
    kd: float = 2.0
    name: str = 'double_integrator_pd'

    def action(self, obs: np.ndarray) -> np.ndarray:
        x, v = float(obs[0]), float(obs[1])
        return np.array([np.clip(-self.kp * x - self.kd * v, -1.0, 1.0)], dtype=np.float32)

    def __call__(self, request: AdviceRequest) -> Advice:
        return Advice(self.action(request.observation), expert_name=self.name)


# Env names (a gymnasium id's prefix, or an env node's EnvInfo.name) and their controllers.
HEURISTICS = {
    'Pendulum': PendulumSwingUpExpert,
    'LunarLander': LunarLanderExpert,
    'double_integrator': DoubleIntegratorExpert,
}


def heuristic_expert(env_name: str):
    """The built-in controller for an env, or a ValueError naming the ones that exist."""
    for prefix, controller in HEURISTICS.items():
        if env_name.startswith(prefix):
            return controller()
    raise ValueError(
        f'no heuristic expert for {env_name[:64]!r}; built in: Pendulum-v1, LunarLanderContinuous-v3, '
        'double_integrator (use the policy backend for other envs)'
    )


def expert_disagreements(expert, observation_size: int, action_size: int) -> list[str]:
    """Where an expert written for given spaces (its observation_size and action_size, if it
    says) cannot answer for an env with these sizes."""
    found = []
    own_obs, own_action = getattr(expert, 'observation_size', None), getattr(expert, 'action_size', None)
    if own_obs is not None and own_obs != observation_size:
        found.append(f'it reads {own_obs} observation values, the env has {observation_size}')
    if own_action is not None and own_action != action_size:
        found.append(f'it gives {own_action} action values, the env takes {action_size}')
    return found
