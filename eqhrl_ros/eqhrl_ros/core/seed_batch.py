"""SeedBatch: N learners of one configuration, seeds apart, updated together.

Each seed keeps its own EQSACLearner: its replay memories D and D_advising, its random
streams, gates, counters and checkpoint are a lone run's. What changes is where its
weights live: every parameter of every seed is a view into one tensor per parameter
with the seeds stacked on a first axis, so that an update of all N seeds runs each layer
as one batched matrix product (networks.linear, TwinCritic.forward) instead of N.

``SeedBatch.update()`` is ``EQSACLearner.update()`` step for step, for every seed at once:
- each seed samples its batches and draws its noise from its own streams, in the order
  its lone update does;
- the loss is the sum of the seeds' losses (N x the mean over the stacked batch), whose
  gradient with respect to seed k's weights is seed k's own gradient;
- Adam steps each seed's own parameters, with each seed's own step count (one fused
  call over all of them). A seed whose D_advising is still empty gets no gradient for the
  second critic step, so Adam leaves it as a lone run would.
The result equals N lone runs to float rounding (tests/core/test_seed_batch.py).
"""

from __future__ import annotations

import copy
from typing import Sequence

import torch
from torch import nn

from . import equations as eq
from .config import asks_for_advice
from .learner import EQSACLearner, adam, policy_loss, soft_bellman_targets, twin_critic_loss
from .replay import Batch


def batchable(learners: Sequence[EQSACLearner]) -> str:
    """'' when these learners can learn together, else why not."""
    if not learners:
        return 'no learners'
    first = learners[0].config.to_dict()
    first.pop('seed')
    for learner in learners[1:]:
        other = learner.config.to_dict()
        other.pop('seed')
        if other != first:
            differ = sorted(k for k in first if first[k] != other.get(k))
            return f'their settings differ apart from the seed ({", ".join(differ)})'
        if learner.obs_dim != learners[0].obs_dim or learner.action_dim != learners[0].action_dim:
            return 'their observation or action sizes differ'
    if learners[0].config.advice_batch != 'full':
        return "advice_batch 'proportional' gives each seed an advice batch of its own size"
    return ''


def _stack(modules: Sequence[nn.Module]) -> nn.Module:
    """A copy of modules[0] whose every parameter holds the modules' parameters stacked on a
    new first axis. Each module's parameter becomes a view into the stacked one (values kept),
    so an optimiser step on a seed's own parameter is seen by the stacked network."""
    stacked = copy.deepcopy(modules[0])
    for name, first in modules[0].named_parameters():
        params = [module.get_parameter(name) for module in modules]
        data = torch.stack([p.detach() for p in params])
        for k, param in enumerate(params):
            param.data = data[k]
        owner, _, attribute = name.rpartition('.')
        setattr(stacked.get_submodule(owner), attribute, nn.Parameter(data, requires_grad=first.requires_grad))
    return stacked


class SeedBatch:
    """N learners whose updates run as one (module docstring)."""

    def __init__(self, learners: Sequence[EQSACLearner]):
        why = batchable(learners)
        if why:
            raise ValueError(f'these learners cannot learn together: {why}')
        self.learners = list(learners)
        self.config = self.learners[0].config
        self.n = len(self.learners)
        self.action_dim = self.learners[0].action_dim
        self.target_entropy = self.learners[0].target_entropy
        self.actor = _stack([learner.actor for learner in self.learners])
        self.critic = _stack([learner.critic for learner in self.learners])
        self.critic_target = _stack([learner.critic_target for learner in self.learners])
        alphas = torch.stack([learner.log_alpha.detach() for learner in self.learners])
        for k, learner in enumerate(self.learners):
            learner.log_alpha.data = alphas[k]
        self.log_alpha = alphas.requires_grad_(True)  # [N]

        # One Adam per network over every seed's own parameters. Each per-parameter state
        # (moments, step count) is the very dict of that seed's own optimiser, so the seed's
        # checkpoint holds what this batch learned.
        cfg = self.config
        self._own = {}  # network -> for each stacked parameter, the seeds' own parameters
        self.optimizers = {}
        for network, lr in (('actor', cfg.actor_lr), ('critic', cfg.critic_lr), ('alpha', cfg.alpha_lr)):
            for learner in self.learners:
                learner._make_optimizers()
            if network == 'alpha':
                own = [[learner.log_alpha for learner in self.learners]]
            else:
                own = [
                    [getattr(learner, network).get_parameter(name) for learner in self.learners]
                    for name, _ in getattr(self, network).named_parameters()
                ]
            self._own[network] = own
            optimizer = adam([p for params in own for p in params], lr)
            for k, learner in enumerate(self.learners):
                own_optimizer = getattr(learner, f'{network}_optimizer')
                for params in own:
                    optimizer.state[params[k]] = own_optimizer.state[params[k]]
            self.optimizers[network] = optimizer

    def release(self) -> None:
        """Give every seed its weights back in tensors of its own (the batch is no longer used)."""
        for learner in self.learners:
            for module in (learner.actor, learner.critic, learner.critic_target):
                for param in module.parameters():
                    param.data = param.data.clone()
            learner.log_alpha.data = learner.log_alpha.data.clone()

    def _stacked_parameters(self, network: str) -> list:
        return [self.log_alpha] if network == 'alpha' else list(getattr(self, network).parameters())

    def _step(self, network: str, loss: torch.Tensor, seeds: torch.Tensor | None = None) -> None:
        """Backpropagate the seeds' summed loss into the stacked network, hand each seed its own
        gradient (only the seeds in ``seeds``, a bool mask, when given) and step Adam."""
        stacked = self._stacked_parameters(network)
        grads = torch.autograd.grad(loss, stacked)
        take = range(self.n) if seeds is None else [k for k in range(self.n) if seeds[k]]
        for grad, own in zip(grads, self._own[network]):
            # contiguous: the gradient of a weight used transposed (networks.linear) comes in
            # the transposed layout, and torch's fused Adam reads a gradient in its parameter's.
            per_seed = grad.contiguous().unbind(0)
            for param in own:
                param.grad = None
            for k in take:
                own[k].grad = per_seed[k]
        self.optimizers[network].step()
        self.optimizers[network].zero_grad(set_to_none=True)

    def update(self) -> None:
        """One gradient update of every seed (Algorithm 1, inner loop), in the paper's order."""
        cfg, n, size, m = self.config, self.n, self.config.batch_size, self.action_dim
        batches, advice_batches, noise, advice_noise, actor_noise, advice_actor_noise = [], [], [], [], [], []
        has_advice = torch.zeros(n, dtype=torch.bool)
        device = self.log_alpha.device
        zeros = torch.zeros(size, m, device=device)
        # Each seed's draws, in its lone update's order: the batch from D, the one from
        # D_advising (if any), then from 'update' the noise of both targets, of the actor step
        # and of the actor step on advice.
        for k, learner in enumerate(self.learners):
            batch = learner.replay.sample(size, learner.rng['replay'])
            advice_batch = None
            if asks_for_advice(learner.mode) and len(learner.advice_replay) > 0:
                advice_batch = learner.advice_replay.sample(
                    size, learner.rng['replay'], replacement=len(learner.advice_replay) < size
                )
                has_advice[k] = True
            advised = advice_batch is not None
            noise.append(learner.noise((size, m), 'update'))
            advice_noise.append(learner.noise((size, m), 'update') if advised else zeros)
            actor_noise.append(learner.noise((size, m), 'update'))
            on_advice = cfg.actor_on_advice and advised
            advice_actor_noise.append(learner.noise((size, m), 'update') if on_advice else zeros)
            batches.append(batch)
            # A seed without advice yet computes on its main batch, and its gradients are dropped.
            advice_batches.append(advice_batch if advised else batch)
        batch = _stacked(batches, device)
        any_advice = bool(has_advice.any())
        advice_batch = _stacked(advice_batches, device) if any_advice else None

        # Eq. 4 targets of both batches, as one forward pass (the actor, alpha and the target
        # critics stay as they are until the end of the update).
        alpha = self.log_alpha.detach().exp().unsqueeze(-1)  # [N, 1], against [N, batch]
        with torch.no_grad():
            parts = [batch] if advice_batch is None else [batch, advice_batch]
            y = soft_bellman_targets(
                self.actor,
                self.critic_target,
                torch.cat([b.next_obs for b in parts], 1),
                torch.cat([b.reward for b in parts], 1),
                torch.cat([b.terminated for b in parts], 1),
                torch.cat([torch.stack(noise)] + ([torch.stack(advice_noise)] if any_advice else []), 1),
                alpha,
                cfg.gamma,
            )
            y, advice_y = (y, None) if advice_batch is None else y.split(size, 1)

        # 1st critic update: the batch from D (Eq. 5).
        self._step('critic', n * twin_critic_loss(self.critic, batch.obs, batch.action, y))
        # 2nd critic update: the batch from D_advising (Eq. 5 again, on the updated critics).
        if any_advice:
            loss = n * twin_critic_loss(self.critic, advice_batch.obs, advice_batch.action, advice_y)
            self._step('critic', loss, has_advice)

        # Actor (Eq. 6) and temperature on the batch from D.
        self._actor_and_alpha_step(batch.obs, torch.stack(actor_noise))
        if cfg.actor_on_advice and any_advice:
            self._actor_and_alpha_step(advice_batch.obs, torch.stack(advice_actor_noise), has_advice)

        # Target critics: theta^- <- tau * theta + (1 - tau) * theta^-, every seed at once.
        eq.soft_update(self.critic_target.parameters(), self.critic.parameters(), cfg.tau)
        for learner in self.learners:
            learner.updates += 1

    def _actor_and_alpha_step(self, obs, noise, seeds=None) -> None:
        n = self.n
        alpha = self.log_alpha.detach().exp().unsqueeze(-1)
        loss, log_prob = policy_loss(self.actor, self.critic, obs, noise, alpha)
        # Gradients for the actor only: the critics' weights are not trained by Eq. 6.
        self._step('actor', n * loss, seeds)
        alpha_loss = eq.temperature_loss(self.log_alpha.unsqueeze(-1), log_prob, self.target_entropy)
        self._step('alpha', n * alpha_loss, seeds)


def _stacked(batches: Sequence[Batch], device) -> Batch:
    """The seeds' batches as one, each field [N, batch, ...]."""
    return Batch(*(torch.stack([getattr(b, f) for b in batches]).to(device) for f in Batch.__dataclass_fields__))
