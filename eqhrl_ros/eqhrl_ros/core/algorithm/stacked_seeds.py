"""StackedSeeds: N learners of one configuration, seeds apart, updated together.

Each seed keeps its own EQSACLearner: its replay memories D and D_advising, its random
streams, gates, counters and checkpoint are a lone run's. What changes is where its
weights live: every parameter of every seed is a view into one tensor per parameter
with the seeds stacked on a first axis, so that an update of all N seeds runs each layer
as one batched matrix product (networks.linear, TwinCritic.forward) instead of N.

``StackedSeeds.update()`` runs the lone update's function (update.algorithm1_update) once on
the stacked weights:
- each seed samples its batches and draws its noise from its own streams, as its lone
  update does (its ReplayMemories.sample, its Updater.noise_for);
- the loss is the sum of the seeds' losses (N x the mean over the stacked batch), whose
  gradient with respect to seed k's weights is seed k's own gradient;
- Adam steps each seed's own parameters with that seed's own optimiser state (one fused call
  over all of them). A seed whose D_advising is still empty gets no step on the advice
  batch, as a lone run would not.
The result equals N lone runs to float rounding (tests/core/algorithm/test_stacked_seeds.py).
Each seed's Updater counts the update with the stacked update's losses (their mean over the
seeds), so a non-finite update is counted on this path as on the lone one.
"""

from __future__ import annotations

import copy
from typing import Any, Sequence

import torch
from torch import nn

from .learner import EQSACLearner
from .update import adam_, algorithm1_update, refusal
from .updater import named_weights, updates_after_a_step


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
    return refusal(learners[0].config, 'stacked', learners[0].observation.encoder is not None)


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


class StackedSeeds:
    """N learners whose updates run as one (module docstring)."""

    def __init__(self, learners: Sequence[EQSACLearner]):
        why = batchable(learners)
        if why:
            raise ValueError(f'these learners cannot learn together: {why}')
        self.learners = list(learners)
        self.config = self.learners[0].config
        self.n = len(self.learners)
        self.action_dim = self.learners[0].action_dim
        self.updaters = [learner.updater for learner in self.learners]
        self.actor = _stack([learner.actor for learner in self.learners])
        self.critic = _stack([learner.critic for learner in self.learners])
        self.critic_target = _stack([learner.critic_target for learner in self.learners])
        alphas = torch.stack([learner.log_alpha.detach() for learner in self.learners])
        for k, learner in enumerate(self.learners):
            learner.log_alpha.data = alphas[k]
        self.log_alpha = alphas.requires_grad_(True)  # [N]

        # Each seed's own parameters, per stacked parameter: Adam steps these (views into the
        # stacked tensors) with each seed's own optimiser state, so its checkpoint holds what
        # this batch learned.
        self._own = {}
        for network in ('actor', 'critic'):
            self._own[network] = [
                [getattr(learner, network).get_parameter(name) for learner in self.learners]
                for name, _ in getattr(self, network).named_parameters()
            ]
        self._own['alpha'] = [[learner.log_alpha for learner in self.learners]]
        _, _, constants = self.updaters[0].inputs()
        self.constants = {**constants, 'seeds': self.n}
        self.weights = named_weights(self.actor, self.critic, self.critic_target, self.log_alpha)

    def release(self) -> None:
        """Give every seed its weights back in tensors of its own (the batch is no longer used)."""
        for learner in self.learners:
            for module in (learner.actor, learner.critic, learner.critic_target):
                for param in module.parameters():
                    param.data = param.data.clone()
            learner.log_alpha.data = learner.log_alpha.data.clone()

    def _adam_each_seed(self, network: str, params: list, grads: list, advised=None) -> None:
        """algorithm1_update's Adam step for stacked seeds: each seed's slice of the stacked
        gradient to that seed's own parameter and optimiser state (only the seeds in
        ``advised``, a bool mask, when given), in one fused call."""
        take = range(self.n) if advised is None else [k for k in range(self.n) if advised[k]]
        states = [updater.optimizer_state(network) for updater in self.updaters]
        own_params, own_grads, exp_avgs, exp_avg_sqs, steps = [], [], [], [], []
        for i, grad in enumerate(grads):
            # contiguous: the gradient of a weight used transposed (networks.linear) comes in
            # the transposed layout, and torch's fused Adam reads a gradient in its parameter's.
            per_seed = grad.contiguous().unbind(0)
            for k in take:
                own_params.append(self._own[network][i][k])
                own_grads.append(per_seed[k])
                exp_avgs.append(states[k][0][i])
                exp_avg_sqs.append(states[k][1][i])
                steps.append(states[k][2][i])
        adam_(own_params, own_grads, (exp_avgs, exp_avg_sqs, steps), self.constants[f'{network}_adam'])

    def updates_after_a_step(self) -> list[dict]:
        """Algorithm 1's inner loop after an env step of every seed (the seeds are at the same
        step, so their D are ready together), as each lone learner's step() runs it."""
        return updates_after_a_step(self.config, self.learners[0].ready_to_learn, self.update)

    def update(self) -> dict:
        """One gradient update of every seed (Algorithm 1, inner loop): algorithm1_update on the
        stacked weights. Returns the losses (the mean over the seeds) and each seed's alpha."""
        n, size, m = self.n, self.config.batch_size, self.action_dim
        device = self.log_alpha.device
        zeros = torch.zeros(size, m, device=device)
        batches, advice_batches, noises = [], [], []
        advised = torch.zeros(n, dtype=torch.bool)
        for k, learner in enumerate(self.learners):
            # Each seed's own draws, in its lone update's order (the same two calls).
            batch, advice = learner.memories.sample()
            noise = learner.updater.noise_for(batch, advice)
            advised[k] = advice is not None
            target, actor, advice_actor = noise
            if advice is None:  # a stand-in: computed on its main batch, and its step dropped
                target = torch.cat([target, torch.zeros_like(target)])
                advice = batch
            noises.append((target, actor, advice_actor if advice_actor is not None else zeros))
            batches.append(batch.columns())
            advice_batches.append(advice.columns())
        any_advice = bool(advised.any())
        stacked = [torch.stack(field).to(device) for field in zip(*batches)]
        advice_columns = [torch.stack(field).to(device) for field in zip(*advice_batches)] if any_advice else None
        target = torch.stack([t for t, _, _ in noises])
        if not any_advice:
            target = target[:, :size]
        on_advice = self.config.actor_on_advice and any_advice
        noise = (
            target,
            torch.stack([a for _, a, _ in noises]),
            torch.stack([b for _, _, b in noises]) if on_advice else None,
        )
        losses = algorithm1_update(
            (self.actor, self.critic),
            self.weights,
            None,
            stacked,
            advice_columns,
            noise,
            self.constants,
            advised=advised,
            step=self._adam_each_seed,
        )
        info: dict[str, Any] = {name: float(value) for name, value in losses.items()}
        for updater in self.updaters:
            updater.count(info)
        info['alpha'] = [updater.alpha for updater in self.updaters]
        return info
