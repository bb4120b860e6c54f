"""The whole update as one compiled program (LearnerConfig.compile_update; issue 22, item 2).

EQSACLearner.update() runs Algorithm 1's inner loop eagerly: PyTorch dispatches hundreds
of small operations per update and builds an autograd graph for each loss. Here the same
update, step by step in the same order with the same loss functions (learner.py) and the
same equations (equations.py), is one pure function of tensors: gradients come from
torch.func, Adam is torch's own functional Adam applied in place to the learner's weights
and to its optimisers' own moments and step counts. torch.compile(fullgraph=True) turns that
function into one program, with everything around the matrix products fused.

What a user sees:
- The first updates run eagerly. The compiler runs in a background thread on copies of the
  weights, off the acting path; once it is done, the next update is the compiled one.
- Its cost in seconds is reported in one log line, as is any failure, after which the
  learner stays eager. Nothing else changes.
- Random draws (the replay batches and the noise) are made outside, in the eager update's
  order from the same streams, so compiled and eager updates compute the same numbers to
  float rounding (tests/core/test_compiled_update.py).
"""

from __future__ import annotations

import copy
import logging
import threading
import time
import types
from typing import Callable, Optional

import torch
from torch.func import functional_call, grad_and_value
from torch.optim.adam import adam as functional_adam

from . import equations as eq
from .config import asks_for_advice
from .losses import policy_loss, soft_bellman_targets, twin_critic_loss

LOG = logging.getLogger('eqhrl_ros.compile')


def compile_refusal(config) -> str:
    """Why this configuration cannot be compiled (''=it can). A batch from D_advising whose
    size follows D_advising's ('proportional') would recompile at every new size."""
    if config.advice_batch != 'full':
        return f"advice_batch '{config.advice_batch}' changes the batch size at every step"
    if config.updates_per_step < 1:
        return 'updates_per_step is 0: there is no update to compile'
    return ''


# --------------------------------------------------------------------------- the pure update


def _adam_(params, grads, state, settings: dict) -> None:
    """torch's functional Adam, in place on ``params`` and on the optimiser's own moments;
    ``settings``: lr, betas and eps, as the learner's torch.optim.Adam holds them."""
    exp_avgs, exp_avg_sqs, steps = state
    functional_adam(
        params,
        grads,
        exp_avgs,
        exp_avg_sqs,
        [],
        steps,
        foreach=False,
        # Compiled: step counts stay tensors (no .item()), so the update is one graph.
        capturable=torch.compiler.is_compiling(),
        amsgrad=False,
        beta1=settings['betas'][0],
        beta2=settings['betas'][1],
        lr=settings['lr'],
        weight_decay=0.0,
        eps=settings['eps'],
        maximize=False,
    )


def _with(net, weights):
    """``net`` as a function of its inputs, computed with ``weights`` (name -> tensor)."""
    return lambda *inputs: functional_call(net, weights, inputs)


def algorithm1_update(nets, weights, state, batch, advice, noise, hyper) -> dict:
    """One update of Algorithm 1's inner loop in its order; learner.EQSACLearner.update() eagerly.

    ``nets``: the actor and twin-critic modules (their structure; their weights come from
    ``weights``: name -> tensor dicts for 'actor', 'critic', 'critic_target' and the tensor
    'log_alpha'); ``state``: each optimiser's (exp_avgs, exp_avg_sqs, steps) in the order of
    ``weights``; ``batch``/``advice``: (obs, action, reward, next_obs, terminated) from D and
    from D_advising (or None); ``noise``: the target noise of both batches, the actor's noise
    and the actor's noise on advice (or None). Updates the weights in place; returns the losses.
    """
    actor_net, critic_net = nets
    actor_w, critic_w, target_w = weights['actor'], weights['critic'], weights['critic_target']
    actor = _with(actor_net, actor_w)
    critic_target = _with(critic_net, target_w)
    target_noise, actor_noise, advice_actor_noise = noise
    losses = {}

    # Eq. 4 targets of both batches in one pass (the actor, alpha and the target critics
    # stay as they are until the end of the update).
    with torch.no_grad():
        both = batch if advice is None else [torch.cat(pair) for pair in zip(batch, advice)]
        alpha = weights['log_alpha'].exp()
        y = soft_bellman_targets(actor, critic_target, both[3], both[2], both[4], target_noise, alpha, hyper['gamma'])
        y, advice_y = (y, None) if advice is None else y.split([len(batch[2]), len(advice[2])])

    def critic_step(obs, action, y):
        def loss_of(w):
            return twin_critic_loss(_with(critic_net, w), obs, action, y)

        grads, loss = grad_and_value(loss_of)(critic_w)
        _adam_(list(critic_w.values()), list(grads.values()), state['critic'], hyper['critic_adam'])
        return loss

    # 1st critic update: the batch from D (Eq. 5); 2nd: the batch from D_advising.
    losses['critic_loss'] = critic_step(batch[0], batch[1], y)
    if advice is not None:
        losses['advice_critic_loss'] = critic_step(advice[0], advice[1], advice_y)

    def actor_and_alpha_step(obs, noise):
        alpha = weights['log_alpha'].detach().exp()
        critic = _with(critic_net, {k: v.detach() for k, v in critic_w.items()})

        def loss_of(w):  # Eq. 6; log pi for the temperature
            return policy_loss(_with(actor_net, w), critic, obs, noise, alpha)

        grads, (loss, log_prob) = grad_and_value(loss_of, has_aux=True)(actor_w)
        _adam_(list(actor_w.values()), list(grads.values()), state['actor'], hyper['actor_adam'])

        def alpha_loss_of(log_alpha):
            return eq.temperature_loss(log_alpha, log_prob, hyper['target_entropy'])

        alpha_grad, alpha_loss = grad_and_value(alpha_loss_of)(weights['log_alpha'])
        _adam_([weights['log_alpha']], [alpha_grad], state['alpha'], hyper['alpha_adam'])
        return loss, alpha_loss

    # Actor (Eq. 6) and temperature on the batch from D (and on advice, actor_on_advice).
    losses['actor_loss'], losses['alpha_loss'] = actor_and_alpha_step(batch[0], actor_noise)
    if advice_actor_noise is not None and advice is not None:
        losses['advice_actor_loss'], _ = actor_and_alpha_step(advice[0], advice_actor_noise)

    # Target critics: theta^- <- tau * theta + (1 - tau) * theta^-.
    eq.soft_update(list(target_w.values()), list(critic_w.values()), hyper['tau'])
    return losses


# --------------------------------------------------------------------------- the guards

# torch.compile checks, before every call, that the program still fits its inputs (its
# "guards"): about 1,350 checks for EQSAC's update, 0.39 ms a call, most of them on what
# cannot change between calls: the modules' structure (``nets``: their weights come from
# ``weights``, so the weights' shapes fix it) and the globals (this package's equations and
# torch's own functions). Kept: the guards on the data arguments (each tensor's shape, dtype,
# device and stride, which of advice and the advice noise is None, the hyperparameters baked
# into the program as constants, so two learners that differ only in gamma get two programs)
# and torch's global state (grad mode and the like). 140 checks, 0.2 ms a call
# (docs/performance.md).
GUARDED_ARGUMENTS = ('weights', 'state', 'batch', 'advice', 'noise', 'hyper')


def keep_guard(name: str, is_global: bool) -> bool:
    """Whether a guard on ``name`` (its source, as dynamo writes it: "batch[0]",
    "hyper['gamma']", "nets[0].action_dim", "G['torch']"; '' for torch's global state) stays."""
    if is_global:
        return False
    root = name.split('[', 1)[0].split('.', 1)[0]
    return root == '' or root in GUARDED_ARGUMENTS


def _guards_to_keep(entries) -> list:
    """torch.compile's guard_filter_fn."""
    return [keep_guard(entry.name, entry.is_global) for entry in entries]


# --------------------------------------------------------------------------- one program per setting

# Dynamo keeps the programs it compiles on the function's code object, at most 8 of them
# (torch._dynamo.config.recompile_limit); past that, a fullgraph compile fails. A learner needs
# one or two (with and without an advice batch), but a process with learners of several
# settings (a sweep, a benchmark) would pass 8. So each setting gets a copy of
# algorithm1_update with a code object of its own, shared by the learners of that setting.
_COPIES: dict = {}
_COPIES_LOCK = threading.Lock()
# One warm-up at a time in a process: learners started together would each miss the program
# that the first of them is compiling, and compile it again, up to the limit above.
_COMPILING = threading.Lock()


def update_function_for(setting) -> Callable:
    """algorithm1_update, the same copy for every learner whose ``setting`` (a hashable
    summary of what its program is specialised to) is equal."""
    with _COPIES_LOCK:
        function = _COPIES.get(setting)
        if function is None:
            original = algorithm1_update
            function = types.FunctionType(original.__code__.replace(), original.__globals__, original.__name__)
            function.__doc__, function.__qualname__ = original.__doc__, original.__qualname__
            _COPIES[setting] = function
        return function


# --------------------------------------------------------------------------- the learner's side


class CompiledUpdate:
    """A learner's update compiled in the background; ``ready`` once it can be called.

    ``log``: where the one line about the compiler goes: info() with its cost, or warning() with
    why the learner stays eager. Python's logger 'eqhrl_ros.compile' by default; a node passes
    its ROS logger (rclpy's loggers have the same two methods).
    """

    def __init__(self, learner, log=None, background: bool = True):
        self.learner = learner
        self.log = log or LOG
        self.ready = False
        self.failed = ''
        self.error: Optional[BaseException] = None
        self.seconds: Optional[float] = None
        # The networks' structure, on copies: functional_call() gives them their weights, and
        # tracing them in the background must not touch the modules the learner acts with.
        self._nets = (copy.deepcopy(learner.actor), copy.deepcopy(learner.critic))
        self._live_inputs = (None, None)  # (the objects they came from, (weights, state))
        self._variants = self._advice_variants()
        self._settings = self._hyper()  # the config's constants, baked into the program
        # loop_ordering_after_fusion off: with it, torch 2.11's inductor failed an assertion on
        # this program on CUDA; on the CPU it makes no difference in speed (docs/performance.md).
        self._function = torch.compile(
            update_function_for(self._setting()),
            fullgraph=True,
            dynamic=False,
            options={'loop_ordering_after_fusion': False, 'guard_filter_fn': _guards_to_keep},
        )
        if background:
            self._thread = threading.Thread(target=self._warm_up, args=(self._copies(),), daemon=True)
            self._thread.start()
        else:
            self._thread = None
            self._warm_up(self._copies())

    def _setting(self) -> tuple:
        """What the program is specialised to: the shapes, the device, the variants and the
        constants. (Its guards check all of it again; this only keeps the settings apart.)"""
        learner, cfg = self.learner, self.learner.config
        shapes = (learner.obs_dim, learner.action_dim, tuple(cfg.hidden), cfg.batch_size)
        return (*shapes, str(learner.device), cfg.actor_on_advice, tuple(self._variants), repr(self._settings))

    def _advice_variants(self) -> list:
        """Whether an update has an advice batch, for every kind of update this learner makes."""
        cfg = self.learner.config
        if not asks_for_advice(self.learner.mode) or not cfg.dual_replay:
            return [False]
        return [False, True]

    # The inputs of algorithm1_update(), from the learner's live tensors or copies of them.

    def _weights(self, copy: bool = False) -> dict:
        take = (lambda t: t.detach().clone()) if copy else (lambda t: t.detach())
        learner = self.learner  # read at every call: loading a checkpoint replaces the modules
        return {
            'actor': {k: take(v) for k, v in learner.actor.named_parameters()},
            'critic': {k: take(v) for k, v in learner.critic.named_parameters()},
            'critic_target': {k: take(v) for k, v in learner.critic_target.named_parameters()},
            'log_alpha': take(learner.log_alpha),
        }

    def _state(self, copy: bool = False) -> dict:
        take = (lambda t: t.clone()) if copy else (lambda t: t)
        learner = self.learner
        state = {}
        for name, optimizer in (
            ('actor', learner.actor_optimizer),
            ('critic', learner.critic_optimizer),
            ('alpha', learner.alpha_optimizer),
        ):
            params = [p for group in optimizer.param_groups for p in group['params']]
            per = [optimizer.state[p] for p in params]
            state[name] = tuple([take(s[key]) for s in per] for key in ('exp_avg', 'exp_avg_sq', 'step'))
        return state

    def _inputs(self) -> tuple:
        """The live weights and optimiser state, gathered again only when the learner replaced
        the objects that hold them (loading a checkpoint does): the compiled program steps them
        in place, so the same tensors serve every call (gathering them took 0.2 ms a call)."""
        learner = self.learner
        owners = (
            learner.actor,
            learner.critic,
            learner.critic_target,
            learner.log_alpha,
            learner.actor_optimizer,
            learner.critic_optimizer,
            learner.alpha_optimizer,
        )
        held, inputs = self._live_inputs
        if held is None or any(a is not b for a, b in zip(owners, held)):
            if not self._has_moments():
                return None
            inputs = (self._weights(), self._state())
            self._live_inputs = (owners, inputs)
        return inputs

    def _has_moments(self) -> bool:
        """Whether every optimiser holds Adam's moments: a learner that loaded a state saved
        before its first update holds none until an eager update makes them."""
        learner = self.learner
        optimizers = (learner.actor_optimizer, learner.critic_optimizer, learner.alpha_optimizer)
        return all(
            'exp_avg' in optimizer.state.get(p, {})
            for optimizer in optimizers
            for p in optimizer.param_groups[0]['params']
        )

    def _hyper(self) -> dict:
        learner = self.learner
        hyper = {'gamma': learner.config.gamma, 'tau': learner.config.tau, 'target_entropy': learner.target_entropy}
        for name in ('actor', 'critic', 'alpha'):  # Adam's settings from the optimisers themselves
            group = getattr(learner, f'{name}_optimizer').param_groups[0]
            hyper[f'{name}_adam'] = {'lr': group['lr'], 'betas': tuple(group['betas']), 'eps': group['eps']}
        return hyper

    def _copies(self):
        """Copies of the weights and the optimiser state, and made-up batches of the right shapes,
        for compiling without touching the learner (made here, in the caller's thread)."""
        learner, size = self.learner, self.learner.config.batch_size
        device = learner.device

        def made_up_batch():
            return (
                torch.randn(size, learner.obs_dim, device=device),
                torch.rand(size, learner.action_dim, device=device) * 2 - 1,
                torch.randn(size, device=device),
                torch.randn(size, learner.obs_dim, device=device),
                torch.zeros(size, device=device),
            )

        return self._weights(copy=True), self._state(copy=True), made_up_batch, self._settings

    def _noise(self, sizes: list, actor_on_advice: bool, draw) -> tuple:
        m = self.learner.action_dim
        target = torch.cat([draw((n, m)) for n in sizes])
        actor = draw((sizes[0], m))
        advice_actor = draw((sizes[1], m)) if actor_on_advice and len(sizes) > 1 else None
        return target, actor, advice_actor

    def _warm_up(self, copies) -> None:
        start = time.perf_counter()
        try:
            with _COMPILING:
                self._compile(*copies)
        except Exception as error:  # noqa: BLE001 - any compiler failure leaves the eager update
            self.error = error  # the whole exception, for whoever wants more than the line
            self.failed = f'{type(error).__name__}: {str(error).strip().splitlines()[0] if str(error).strip() else ""}'
            self.log.warning(
                f'compile_update: the compiler failed ({self.failed}); the learner stays with the eager update'
            )
            return
        self.seconds = time.perf_counter() - start
        self.ready = True
        self.log.info(
            f'compile_update: the whole update is compiled ({self.seconds:.1f} s in the background; '
            f'{len(self._variants)} variant(s)); updates from now on run compiled'
        )

    def _compile(self, weights, state, made_up_batch, hyper) -> None:
        """One call of each variant on made-up inputs: the first call of a variant compiles it."""
        device = self.learner.device
        for with_advice in self._variants:
            batch = made_up_batch()
            advice = made_up_batch() if with_advice else None
            sizes = [len(batch[2])] + ([len(advice[2])] if advice is not None else [])
            noise = self._noise(
                sizes, self.learner.config.actor_on_advice, lambda shape: torch.randn(shape, device=device)
            )
            self._function(self._nets, weights, state, batch, advice, noise, hyper)

    def wait(self, timeout: Optional[float] = None) -> bool:
        """Block until the background compile ended (tests, benchmarks); True if it is ready."""
        if self._thread is not None:
            self._thread.join(timeout)
        return self.ready

    def __call__(self, batch, advice_batch) -> Optional[dict]:
        """The update on the learner's live weights, with the noise drawn as the eager update draws
        it; None, having drawn nothing, while the optimisers hold no moments (the eager update makes them)."""
        learner = self.learner
        live = self._inputs()
        if live is None:
            return None
        weights, state = live
        fields = ('obs', 'action', 'reward', 'next_obs', 'terminated')

        def as_tuple(b):
            # Contiguous, as in the warm-up: a compiled program is specialised to its inputs'
            # layout, and a batch's fields are column views of its rows (replay.py).
            return tuple(getattr(b, f).contiguous() for f in fields)

        advice = as_tuple(advice_batch) if advice_batch is not None else None
        sizes = [len(batch.reward)] + ([len(advice_batch.reward)] if advice_batch is not None else [])
        noise = self._noise(sizes, learner.config.actor_on_advice, lambda shape: learner.noise(shape, 'update'))
        losses = self._function(self._nets, weights, state, as_tuple(batch), advice, noise, self._settings)
        info = {name: float(value) for name, value in losses.items()}
        info['alpha'] = learner.alpha
        return info
