"""The Updater: what learning owns. The temperature, the three optimisers, the update's inputs,
the compile, the losses with their non-finite check, and the compiled program's acting ahead
(acting_ahead.py).

Every update, lone or of stacked seeds, runs update.algorithm1_update; this part gathers what
that function reads (views of the live weights and of the optimisers' own moments, which it
steps in place) and keeps count. The lone learner calls ``update(batch, advice)``; stacked seeds
(stacked_seeds.py) read ``inputs()`` and ``optimizer_state()`` of each seed's Updater and
``count(losses)`` each seed's update.
"""

from __future__ import annotations

import copy
import math
from typing import TYPE_CHECKING, Any, Callable, Optional

import torch

from ..data.replay import Minibatch
from . import cpu_threads
from .acting_ahead import ActingAhead, weights_token
from .config import LearnerConfig
from .critics import Critics
from .policy import Policy
from .update import algorithm1_update, refusal, update_noise

if TYPE_CHECKING:
    from .compiled_update import CompiledUpdate

OPTIMIZED = ('actor', 'critic', 'alpha')  # the networks an update steps, each with its Adam
ENCODER = 'encoder'  # and, with a camera, the image encoder (its Adam at the critic's rate, as DrQ-v2's)


def adam(params, lr: float, state: dict | None = None) -> torch.optim.Adam:
    """A torch Adam that holds a network's moments and step counts; a loaded ``state`` keeps them.

    It is never stepped itself: update.adam_ steps its state in place with torch's fused
    functional Adam. It is what checkpoints save (its state_dict) and where adam_state finds
    the tensors."""
    optimizer = torch.optim.Adam(params, lr=lr, fused=True)
    if state is not None:
        # A copy: torch's load_state_dict keeps the given moment and step tensors themselves, so
        # loading another live learner's state_dict() would have both step the same moments.
        optimizer.load_state_dict(copy.deepcopy(state))
        for group in optimizer.param_groups:
            group.update(fused=True, foreach=None)
    return optimizer


def adam_state(optimizer: torch.optim.Adam) -> tuple:
    """(exp_avgs, exp_avg_sqs, steps) of each parameter, the optimiser's own tensors; those it
    has not made yet (before its first step) made as torch's fused Adam makes them."""
    per = []
    for p in optimizer.param_groups[0]['params']:
        state = optimizer.state[p]
        if 'exp_avg' not in state:
            state['step'] = torch.zeros((), dtype=torch.float32, device=p.device)
            state['exp_avg'] = torch.zeros_like(p, memory_format=torch.preserve_format)
            state['exp_avg_sq'] = torch.zeros_like(p, memory_format=torch.preserve_format)
        per.append(state)
    return tuple([s[key] for s in per] for key in ('exp_avg', 'exp_avg_sq', 'step'))


def non_finite(losses: dict) -> list[str]:
    """The losses of an update that are not finite (a diverged update), by name."""
    return [name for name, value in losses.items() if isinstance(value, float) and not math.isfinite(value)]


def updates_after_a_step(config: LearnerConfig, ready: bool, update: Callable[[], dict]) -> list[dict]:
    """Algorithm 1's inner loop after an env step: updates_per_step updates once D is ready."""
    return [update() for _ in range(config.updates_per_step)] if ready else []


def named_weights(actor, critic, critic_target, log_alpha) -> dict:
    """The weights algorithm1_update reads: views (detached) of the live tensors."""
    return {
        'actor': {k: v.detach() for k, v in actor.named_parameters()},
        'critic': {k: v.detach() for k, v in critic.named_parameters()},
        'critic_target': {k: v.detach() for k, v in critic_target.named_parameters()},
        'log_alpha': log_alpha.detach(),
    }


class Updater:
    """Learns the policy's actor, the critics and the temperature alpha (Algorithm 1's update)."""

    def __init__(
        self,
        config: LearnerConfig,
        policy: Policy,
        critics: Critics,
        device: torch.device,
        log=None,
        acts=(False, False),
    ):
        """``acts``: whether the gates read D(s) and the exact E(s), which the compiled update then
        computes ahead for the next observation (acting_ahead.py)."""
        self.config = config
        self.policy = policy
        self.critics = critics
        self.device = device
        self.log_alpha = torch.tensor(math.log(config.initial_alpha), device=device, requires_grad=True)
        self.target_entropy = -float(policy.action_dim)  # Table 1: target alpha = -action dim
        self.updates = 0
        self.non_finite_updates = 0  # updates whose losses were not finite (counted on every path)
        # The optimisers are made at the first update: torch imports its compiler
        # (torch._dynamo, over a second: docs/performance.md) when the first one is made,
        # which would otherwise delay the first env step by that much.
        self.optimizers: Optional[dict] = None
        # compile_update: the CompiledUpdate, made after the first eager update (compiled_update.py);
        # compile_refused says why a configuration that cannot be compiled stays eager.
        self.compiled: Optional[CompiledUpdate] = None
        self.compile_refused = ''
        self._inputs: tuple[Any, Any] = (None, None)  # inputs(): ((owners, storage, parameters), the inputs)
        self._nets: Optional[tuple] = None
        self.log = log  # the compiler's logger (info, warning); None: Python's; a node sets its own
        self.ahead = ActingAhead(policy.streams, policy.action_dim, *acts)

    @property
    def obs_dim(self) -> int:
        return self.policy.observation.dim

    @property
    def encoder(self):
        """The observation's encoder (a camera's), trained with the critics; None for a vector."""
        return self.policy.observation.encoder

    @property
    def optimized(self) -> tuple:
        """The networks this learner's update steps: OPTIMIZED, and the encoder with a camera."""
        return OPTIMIZED if self.encoder is None else (*OPTIMIZED, ENCODER)

    @property
    def action_dim(self) -> int:
        return self.policy.action_dim

    @property
    def alpha(self) -> float:
        return float(self.log_alpha.detach().exp())

    def make_optimizers(self) -> dict:
        """The optimisers, made on first use: {'actor', 'critic', 'alpha'} -> torch Adam."""
        if self.optimizers is None:
            cfg = self.config
            self.optimizers = {
                'actor': adam(self.policy.actor.parameters(), cfg.actor_lr),
                'critic': adam(self.critics.critic.parameters(), cfg.critic_lr),
                'alpha': adam([self.log_alpha], cfg.alpha_lr),
            }
            if self.encoder is not None:
                self.optimizers[ENCODER] = adam(self.encoder.parameters(), cfg.critic_lr)
        return self.optimizers

    def noise_for(self, batch: Minibatch, advice: Optional[Minibatch]) -> tuple:
        """An update's noise from the 'update' stream, in the order every path draws it."""
        sizes = [len(batch.reward)] + ([len(advice.reward)] if advice is not None else [])
        streams = self.policy.streams
        return update_noise(
            lambda shape: streams.noise(shape, 'update'), self.action_dim, sizes, self.config.actor_on_advice
        )

    def _owners(self) -> tuple:
        optimizers = self.make_optimizers()
        return (
            self.policy.actor,
            self.critics.critic,
            self.critics.critic_target,
            self.log_alpha,
            *(optimizers[name] for name in self.optimized),
            *(() if self.encoder is None else (self.encoder,)),
        )

    def inputs(self) -> tuple:
        """(weights, Adam state, constants) for algorithm1_update: views of the live weights and
        of the optimisers' own moments, which the update steps in place (so checkpoints save what
        it learned). Gathered again only when the objects that hold them were replaced (loading a
        checkpoint does) or the tensors behind them (stacked_seeds.py stacks and releases them);
        an optimiser without moments yet gets torch's initial ones."""
        owners = self._owners()
        held, inputs = self._inputs
        replaced = held is None or len(owners) != len(held[0]) or any(a is not b for a, b in zip(owners, held[0]))
        # The parameters of the modules held, listed once per set of owners: module.parameters()
        # walks the module tree: 20 us an update for the three networks, against 3.5 for all of inputs().
        if replaced:
            modules = (*owners[:3], *([] if self.encoder is None else [self.encoder]))
            parameters = [p for module in modules for p in module.parameters()] + [self.log_alpha]
        else:
            parameters = held[2]
        storage = tuple(p.data_ptr() for p in parameters)
        if replaced or storage != held[1]:
            weights = named_weights(*owners[:4])
            if self.encoder is not None:
                weights[ENCODER] = {k: v.detach() for k, v in self.encoder.named_parameters()}
            cfg = self.config
            state = {}
            constants: dict[str, Any] = {
                'gamma': cfg.gamma,
                'tau': cfg.tau,
                'seeds': 1,
                'target_entropy': self.target_entropy,
            }
            optimizers = self.make_optimizers()
            for name in self.optimized:
                optimizer = optimizers[name]
                state[name] = adam_state(optimizer)
                group = optimizer.param_groups[0]  # Adam's settings from the optimiser itself
                constants[f'{name}_adam'] = {'lr': group['lr'], 'betas': tuple(group['betas']), 'eps': group['eps']}
            inputs = (weights, state, constants)
            self._inputs = ((owners, storage, parameters), inputs)
        return inputs

    @property
    def acts_ahead(self) -> bool:
        """Whether the next update's program acts ahead: only then does it read the next observation."""
        compiled = self.compiled
        return self.ahead.enabled and compiled is not None and compiled.ready

    def weights_token(self) -> tuple:
        """acting_ahead.weights_token of the weights the update reads (after inputs() gathered them)."""
        return weights_token((self.policy.actor, self.critics.critic), self._inputs[0][2])

    def acted_ahead(self, obs_t: torch.Tensor) -> Optional[dict]:
        """What the last compiled update computed for acting on ``obs_t``, if it still holds
        (acting_ahead.py); None otherwise."""
        return self.ahead.take(obs_t, self.weights_token)

    def optimizer_state(self, network: str) -> tuple:
        """adam_state of ``network``'s optimiser ('actor', 'critic' or 'alpha')."""
        return adam_state(self.make_optimizers()[network])

    @property
    def nets(self) -> tuple:
        """The actor's and the twin critic's structure for algorithm1_update (copies: it gives
        them their weights, and must not touch the modules the learner acts with)."""
        if self._nets is None:
            self._nets = (copy.deepcopy(self.policy.actor), copy.deepcopy(self.critics.critic))
            if self.encoder is not None:
                self._nets += (copy.deepcopy(self.encoder),)
        return self._nets

    def update(self, batch: Minibatch, advice: Optional[Minibatch], next_obs: Optional[torch.Tensor] = None) -> dict:
        """One gradient update on these batches: Algorithm 1's inner loop, algorithm1_update,
        compiled once compile_update has its program ready; the compiled program then acts ahead
        on ``next_obs`` (the observation the learner expects to act on next, [1, obs_dim]; None:
        none). The noise is drawn here, after the batches, in every path's order. Returns the
        losses and alpha, as floats."""
        losses = self.run(batch, advice, self.noise_for(batch, advice), next_obs)
        # As floats in one read (one per loss cost a call each, after the update: docs/performance.md).
        info = dict(zip(losses, torch.stack(list(losses.values())).tolist()))
        info['alpha'] = self.alpha
        self.count(info)
        if self.config.compile_update and self.compiled is None and not self.compile_refused:
            self.start_compiling()
        cpu_threads.adapt()  # torch's threads fitted to the machine, from this (the updates') thread
        return info

    def run(self, batch: Minibatch, advice: Optional[Minibatch], noise: tuple, next_obs=None) -> dict:
        """update()'s work without its counting: algorithm1_update on these batches and this
        ``noise``, or its compiled program where ready, which then acts ahead on ``next_obs``.
        Returns the losses as tensors."""
        weights, state, constants = self.inputs()
        compiled = self.compiled
        columns = (batch.columns(), advice and advice.columns())
        self.ahead.forget()
        if compiled is None or not compiled.ready:
            return algorithm1_update(self.nets, weights, state, *columns, noise, constants)
        ahead = self.ahead.inputs(next_obs, self.obs_dim)
        losses, acted = compiled.program()(self.nets, weights, state, *columns, noise, constants, ahead)
        if ahead is not None:  # (the weights' token reads every weight's version: not for nothing)
            self.ahead.keep(ahead, acted, self.weights_token())
        return losses

    def count(self, losses: dict) -> None:
        """One more update done (with these losses): stacked seeds count each seed's here too."""
        self.updates += 1
        self.non_finite_updates += bool(non_finite(losses))

    def start_compiling(self, background: bool = True):
        """compile_update: the whole update compiled in a background thread (compiled_update.py),
        from the optimisers' state after an eager update; a configuration that cannot be compiled
        stays eager, said in one log line. Returns the CompiledUpdate (or None)."""
        from .compiled_update import LOG, CompiledUpdate

        why = refusal(self.config, 'compiled', self.encoder is not None)
        if why:
            self.compile_refused = why  # asked once, refused once
            (self.log or LOG).warning(f'compile_update: {why}; the learner stays with the eager update')
            return None
        self.make_optimizers()
        self.compiled = CompiledUpdate(self, log=self.log, background=background)
        return self.compiled

    def state_dict(self) -> dict:
        """The temperature and the optimisers, under the checkpoint's keys."""
        optimizers = self.make_optimizers()
        return {
            'log_alpha': self.log_alpha.detach().clone(),
            **{f'{name}_optimizer': optimizers[name].state_dict() for name in self.optimized},
        }

    def loaded_parts(self, state: dict, actor, critic, encoder=None) -> tuple:
        """(log_alpha, optimisers) from a checkpoint's state, for the networks ``actor`` and
        ``critic`` (and a camera's ``encoder``) about to replace the live ones; nothing here
        changes until adopt()."""
        log_alpha = state['log_alpha'].detach().clone().reshape(()).to(self.device).requires_grad_(True)
        cfg = self.config
        optimizers = {
            'actor': adam(actor.parameters(), cfg.actor_lr, state['actor_optimizer']),
            'critic': adam(critic.parameters(), cfg.critic_lr, state['critic_optimizer']),
            'alpha': adam([log_alpha], cfg.alpha_lr, state['alpha_optimizer']),
        }
        if encoder is not None:
            optimizers[ENCODER] = adam(encoder.parameters(), cfg.critic_lr, state[f'{ENCODER}_optimizer'])
        return log_alpha, optimizers

    def adopt(self, log_alpha: torch.Tensor, optimizers: dict, updates: int) -> None:
        """Take over what loaded_parts() made (the policy and critics hold the new networks)."""
        self.log_alpha, self.optimizers, self.updates = log_alpha, optimizers, updates
        self.ahead.forget()
