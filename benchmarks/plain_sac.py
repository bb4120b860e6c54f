"""A plain single-file SAC in torch, the way CleanRL writes one: a contender in bench_learner.

Written here, for the benchmark only, so that it measures what a careful user gets from
torch with no framework around it: every step of the update in order, in one function,
eager, with the cheap tunings such a user would apply (Adam's foreach path, gradients set
to None, the log-probability written out, acting under inference_mode, the target update
as one foreach lerp, the replay memory as preallocated numpy arrays). The same sizes and
rates as this package's learner (Table 1: 256x256, batch 256, actor 1e-4, critics 1e-3,
temperature 1e-4 learnt towards -dim(A)), one update per env step, the actor updated at
every step.

Not used by the package and not a reference for its numbers: tests/core/algorithm holds
those. It only has to do the same work per step.
"""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import torch
from torch import nn

LOG_STD_MIN, LOG_STD_MAX = -5.0, 2.0
HALF_LOG_2PI = 0.5 * math.log(2 * math.pi)


def mlp(inputs: int, outputs: int, hidden: int = 256) -> nn.Sequential:
    return nn.Sequential(nn.Linear(inputs, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU())


class Critic(nn.Module):
    def __init__(self, obs_dim: int, act_dim: int):
        super().__init__()
        self.body, self.head = mlp(obs_dim + act_dim, 1), nn.Linear(256, 1)

    def forward(self, obs: torch.Tensor, act: torch.Tensor) -> torch.Tensor:
        return self.head(self.body(torch.cat([obs, act], 1)))


class Actor(nn.Module):
    def __init__(self, obs_dim: int, space: gym.spaces.Box):
        super().__init__()
        act_dim = int(np.prod(space.shape))
        self.body, self.mean, self.log_std = mlp(obs_dim, act_dim), nn.Linear(256, act_dim), nn.Linear(256, act_dim)
        self.register_buffer('scale', torch.as_tensor((space.high - space.low) / 2.0, dtype=torch.float32))
        self.register_buffer('bias', torch.as_tensor((space.high + space.low) / 2.0, dtype=torch.float32))

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """A squashed Gaussian sample and its log-probability (the tanh change of variables),
        written out rather than through torch.distributions, whose argument checks cost more
        than the arithmetic at one observation."""
        h = self.body(obs)
        log_std = LOG_STD_MIN + 0.5 * (LOG_STD_MAX - LOG_STD_MIN) * (torch.tanh(self.log_std(h)) + 1)
        eps = torch.randn_like(log_std)
        squashed = torch.tanh(self.mean(h) + log_std.exp() * eps)
        log_prob = -0.5 * eps.pow(2) - log_std - HALF_LOG_2PI - torch.log(self.scale * (1 - squashed.pow(2)) + 1e-6)
        return squashed * self.scale + self.bias, log_prob.sum(1, keepdim=True)


class PlainSAC:
    """Env, replay memory and update in one object, advanced a given number of env steps at a time."""

    def __init__(self, env: gym.Env, warmup: int, batch_size: int = 256, capacity: int = 500_000, seed: int = 0):
        torch.manual_seed(seed)
        self.env, self.batch_size, self.rng = env, batch_size, np.random.default_rng(seed)
        obs_dim, act_dim = int(np.prod(env.observation_space.shape)), int(np.prod(env.action_space.shape))
        self.actor = Actor(obs_dim, env.action_space)
        self.q1, self.q2 = Critic(obs_dim, act_dim), Critic(obs_dim, act_dim)
        self.q1_target, self.q2_target = Critic(obs_dim, act_dim), Critic(obs_dim, act_dim)
        self.q1_target.load_state_dict(self.q1.state_dict())
        self.q2_target.load_state_dict(self.q2.state_dict())
        self.critic_params = [*self.q1.parameters(), *self.q2.parameters()]
        self.target_params = [*self.q1_target.parameters(), *self.q2_target.parameters()]
        self.log_alpha = torch.zeros(1, requires_grad=True)
        self.target_entropy = -float(act_dim)
        self.q_optimizer = torch.optim.Adam(self.critic_params, lr=1e-3, foreach=True)
        self.actor_optimizer = torch.optim.Adam(self.actor.parameters(), lr=1e-4, foreach=True)
        self.alpha_optimizer = torch.optim.Adam([self.log_alpha], lr=1e-4)
        self.obs_buf = np.zeros((capacity, obs_dim), np.float32)
        self.next_obs_buf = np.zeros((capacity, obs_dim), np.float32)
        self.act_buf = np.zeros((capacity, act_dim), np.float32)
        self.rew_buf = np.zeros((capacity, 1), np.float32)
        self.done_buf = np.zeros((capacity, 1), np.float32)
        self.size, self.capacity, self.learning_starts, self.steps = 0, capacity, warmup, 0
        self.obs, _ = env.reset(seed=seed)
        env.action_space.seed(seed)
        self.run(warmup)

    def act(self) -> np.ndarray:
        if self.steps < self.learning_starts:
            return self.env.action_space.sample()
        with torch.inference_mode():
            action, _ = self.actor(torch.as_tensor(self.obs, dtype=torch.float32).unsqueeze(0))
        return action[0].numpy()

    def run(self, steps: int) -> None:
        for _ in range(steps):
            action = self.act()
            next_obs, reward, terminated, truncated, _ = self.env.step(action)
            i = self.size % self.capacity
            self.obs_buf[i], self.act_buf[i], self.rew_buf[i] = self.obs, action, reward
            self.next_obs_buf[i], self.done_buf[i] = next_obs, float(terminated)
            self.size += 1
            self.steps += 1
            self.obs = self.env.reset()[0] if terminated or truncated else next_obs
            if self.steps > self.learning_starts:
                self.update()

    def update(self, gamma: float = 0.99, tau: float = 0.005) -> None:
        index = self.rng.integers(0, min(self.size, self.capacity), self.batch_size)
        obs, act = torch.from_numpy(self.obs_buf[index]), torch.from_numpy(self.act_buf[index])
        rew, done = torch.from_numpy(self.rew_buf[index]), torch.from_numpy(self.done_buf[index])
        next_obs = torch.from_numpy(self.next_obs_buf[index])
        alpha = self.log_alpha.exp().detach()

        # The soft Bellman target, from the target critics at the policy's next action.
        with torch.no_grad():
            next_act, next_log_prob = self.actor(next_obs)
            next_q = torch.min(self.q1_target(next_obs, next_act), self.q2_target(next_obs, next_act))
            target = rew + gamma * (1 - done) * (next_q - alpha * next_log_prob)

        # The twin critics, one step on the sum of their squared errors.
        q_loss = (self.q1(obs, act) - target).pow(2).mean() + (self.q2(obs, act) - target).pow(2).mean()
        self.q_optimizer.zero_grad(set_to_none=True)
        q_loss.backward()
        self.q_optimizer.step()

        # The actor: maximise min Q minus alpha times the log-probability.
        new_act, log_prob = self.actor(obs)
        actor_loss = (alpha * log_prob - torch.min(self.q1(obs, new_act), self.q2(obs, new_act))).mean()
        self.actor_optimizer.zero_grad(set_to_none=True)
        actor_loss.backward()
        self.actor_optimizer.step()

        # The temperature, towards the target entropy.
        alpha_loss = -(self.log_alpha.exp() * (log_prob.detach() + self.target_entropy)).mean()
        self.alpha_optimizer.zero_grad(set_to_none=True)
        alpha_loss.backward()
        self.alpha_optimizer.step()

        # Polyak averaging of the target critics, one foreach call.
        with torch.no_grad():
            torch._foreach_lerp_(self.target_params, self.critic_params, tau)
