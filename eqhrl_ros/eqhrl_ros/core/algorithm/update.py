"""Algorithm 1's update, written once: ``algorithm1_update``.

Every way this package updates runs this one function:
- the eager learner (EQSACLearner.update, learner.py) calls it as it is;
- ``compile_update`` compiles this same function into one program (compiled_update.py);
- seeds learning together (stacked_seeds.py) call it on weights stacked on a leading seed axis,
  with an Adam step that gives each seed its own gradient and step count.

It is a function of tensors: the networks' weights (name -> tensor), their Adam state, one
update's batches from D and D_advising and its noise. It steps the weights and the Adam state
in place, in the paper's order, each equation one call into equations.py. Random draws (the
batches, the noise) are made by the caller, from the learner's streams, in the order
``update_noise`` gives; so every path computes the same numbers to float rounding.

With a camera (``nets`` has a third member, the ObservationEncoder; ``weights['encoder']``), the
networks read the encoder's features of each observation (DrQ-v2, Section 3.1): the critics'
loss trains the encoder with its own Adam (Eq. 5), the targets read the encoder as it is (no
target encoder), and the actor's step reads the features the first critic step computed,
detached, so that the actor's loss never moves the encoder.

Gradients: torch.func when compiling (the compiler traces it), torch.autograd otherwise (the
same derivatives, without torch.func's per-operation wrapping, which cost an eager update a
third more). Either way a step differentiates only the weights it updates: the critics are
constants of the actor's loss, the actor and the target critics constants of Eq. 4.
"""

from __future__ import annotations

from typing import Callable, Optional

import torch
from torch.func import functional_call, grad_and_value
from torch.optim.adam import adam as functional_adam

from ..data.replay import BATCH_COLUMNS, ROW_COLUMNS
from . import equations as eq

ENCODER = 'encoder/'  # the encoder's weights beside the critic's, in the critic step's gradient

# A batch as the update reads it: its BATCH_COLUMNS (data/replay.py), each with the batch on its
# first axis ([batch, ...]), or on its second when seeds are stacked ([N, batch, ...]).


def refusal(config, path: str, camera: bool = False) -> str:
    """Why ``config`` (with a ``camera``, or not) cannot take the update path ``path``
    ('compiled' or 'stacked'); '' when it can. The one place where an option is refused a path."""
    if camera and path == 'compiled':
        # Measured (docs/performance.md, "Learning from pixels"): 35.6 ms compiled against 33.9
        # eager at 24x24, batch 64, the convolutions being the same kernels, after 94 s of compiling.
        return "a camera's update stays eager: compiled, it was no faster (its convolutions are the same kernels)"
    if camera:
        return 'seeds together do not stack the encoder yet'

    if config.advice_batch != 'full':
        # A D_advising batch whose size follows |D_advising| changes shape at every step: a
        # compiled program would be recompiled each time, and stacked seeds would not stack.
        why = 'changes the batch size at every step' if path == 'compiled' else 'gives each seed its own batch size'
        return f"advice_batch '{config.advice_batch}' {why}"
    if path == 'compiled' and config.updates_per_step < 1:
        return 'updates_per_step is 0: there is no update to compile'
    return ''


def update_noise(draw: Callable, action_dim: int, sizes: list, actor_on_advice: bool) -> tuple:
    """One update's noise, drawn in the order every path uses: the targets' a' of the batch
    from D and of the one from D_advising (``sizes``: their lengths), the actor step's, and the
    actor step's on advice (actor_on_advice; else None). ``draw(shape)``: standard normal."""
    target = torch.cat([draw((n, action_dim)) for n in sizes])
    actor = draw((sizes[0], action_dim))
    advice_actor = draw((sizes[1], action_dim)) if actor_on_advice and len(sizes) > 1 else None
    return target, actor, advice_actor


def tracing() -> bool:
    """Whether torch.compile is tracing this very call. Not torch.compiler.is_compiling(): that
    is a process-wide flag, true in every thread while a compile runs in any (compile_update
    compiles in the background while the eager updates go on), and with it an eager update
    took the compiled path's Adam, which fails outside a compiled program on the CPU."""
    return torch.compiler.is_dynamo_compiling()


def with_weights(net, weights: dict):
    """``net`` as a function of its inputs, computed with ``weights`` (name -> tensor)."""
    return lambda *inputs: functional_call(net, weights, inputs)


def gradient_and_value(loss_of: Callable, weights, has_aux: bool = False):
    """torch.func.grad_and_value(loss_of)(weights): the gradient with respect to ``weights`` (a
    tensor, or a dict of them) and the value (with ``has_aux``: loss_of returns (loss, aux))."""
    if tracing():
        return grad_and_value(loss_of, has_aux=has_aux)(weights)
    if isinstance(weights, dict):
        leaves = {name: t.detach().requires_grad_(True) for name, t in weights.items()}
        inputs = list(leaves.values())
    else:
        leaves = weights.detach().requires_grad_(True)
        inputs = [leaves]
    with torch.enable_grad():
        out = loss_of(leaves)
    loss = out[0] if has_aux else out
    found = torch.autograd.grad(loss, inputs)
    grads = dict(zip(leaves, found)) if isinstance(weights, dict) else found[0]
    if has_aux:
        return grads, (loss.detach(), out[1].detach())
    return grads, loss.detach()


@torch.no_grad()
def adam_(params: list, grads: list, state: tuple, settings: dict) -> None:
    """torch's Adam, in place on ``params`` and on ``state`` (exp_avgs, exp_avg_sqs, steps: the
    moments and step counts a torch.optim.Adam holds); ``settings``: its lr, betas and eps.

    Eagerly, torch's fused Adam (one kernel over every tensor), as the learner's optimiser is.
    Compiled, the steps of torch's capturable Adam (step counts as tensors, so that the update is
    one graph), written out here for one reason: traced from torch's function, each weight's
    bias corrections (beta ** step, a tensor the compiler cannot hoist out of a loop) were
    recomputed in every 16-float chunk of its loop, which made the Adam step 2-2.7x slower
    (docs/performance.md). A network's weights step together, so their counts are equal: taken
    as a reduction over them, the corrections are computed once, in a kernel of their own, and
    the loops read them. The same numbers as torch's capturable Adam (to the bit on the machine
    it was measured on; tests/core/algorithm/test_compiled_update.py checks float rounding)."""
    exp_avgs, exp_avg_sqs, steps = state
    beta1, beta2 = settings['betas']
    lr, eps = settings['lr'], settings['eps']
    if not tracing():
        functional_adam(
            params,
            grads,
            exp_avgs,
            exp_avg_sqs,
            [],
            steps,
            foreach=False,
            capturable=False,
            fused=True,
            amsgrad=False,
            beta1=beta1,
            beta2=beta2,
            lr=lr,
            weight_decay=0.0,
            eps=eps,
            maximize=False,
        )
        return
    torch._foreach_add_(steps, 1)
    step = torch.stack(steps)
    step_size_neg = (lr / (1 - beta1**step)).neg().amax()
    bias_correction2_sqrt = (1 - beta2**step).sqrt().amax()
    for param, grad, exp_avg, exp_avg_sq in zip(params, grads, exp_avgs, exp_avg_sqs):
        exp_avg.lerp_(grad, 1 - beta1)
        exp_avg_sq.mul_(beta2).addcmul_(grad, grad, value=1 - beta2)
        param.addcdiv_(exp_avg, (exp_avg_sq.sqrt() / (bias_correction2_sqrt * step_size_neg)).add_(eps / step_size_neg))


@torch.no_grad()
def soft_targets(nets, weights, batch, advice, target_noise, gamma: float) -> tuple:
    """Eq. 4's y for the batch from D and for the one from D_advising (None when there is none),
    in one pass: a' ~ pi(.|s') from the current actor, Q from the target critics."""
    actor_net, critic_net = nets[:2]
    sizes = [batch[2].shape[-1]] + ([advice[2].shape[-1]] if advice is not None else [])
    if len(nets) > 2:  # the encoder's features of s' (its weights as they are: DrQ-v2 keeps no target encoder),
        encode = with_weights(nets[2], weights['encoder'])  # batch by batch: joined, the frames cost twice the time
        batch = (*batch[:3], encode(batch[3]), batch[4])
        advice = None if advice is None else (*advice[:3], encode(advice[3]), advice[4])
    if advice is None:
        both = batch
    else:
        both = [
            torch.cat(pair, dim=-1 if name in ROW_COLUMNS else -2)
            for name, pair in zip(BATCH_COLUMNS, zip(batch, advice))
        ]
    _, _, reward, next_obs, terminated = both
    alpha = weights['log_alpha'].exp().unsqueeze(-1)
    next_mean, next_log_std = with_weights(actor_net, weights['actor'])(next_obs)
    next_action, next_log_prob = eq.squashed_gaussian_sample(next_mean, next_log_std, target_noise)
    next_q1, next_q2 = with_weights(critic_net, weights['critic_target'])(next_obs, next_action)
    y = eq.soft_bellman_target(reward, terminated, next_q1, next_q2, next_log_prob, alpha, gamma)
    return (y, None) if advice is None else tuple(y.split(sizes, dim=-1))


def encoded_critic_step(nets, weights, obs, action, y, seeds, adam_step) -> tuple:
    """Eq. 5 for Q_theta1 and Q_theta2 through a camera's encoder, which learns from this loss
    (its own Adam). Returns (loss, the features before this step, detached: the actor's input)."""
    critic_net, encoder_net = nets[1], nets[2]
    critic_w, encoder_w = weights['critic'], weights['encoder']
    joint = {**critic_w, **{ENCODER + name: t for name, t in encoder_w.items()}}

    def loss_of(w):
        features = with_weights(encoder_net, {name: w[ENCODER + name] for name in encoder_w})(obs)
        q1, q2 = with_weights(critic_net, {name: w[name] for name in critic_w})(features, action)
        return seeds * (eq.critic_loss(q1, y) + eq.critic_loss(q2, y)), features

    grads, (loss, features) = gradient_and_value(loss_of, joint, has_aux=True)
    adam_step('critic', list(critic_w.values()), [grads[name] for name in critic_w])
    adam_step('encoder', list(encoder_w.values()), [grads[ENCODER + name] for name in encoder_w])
    return loss / seeds, features


def algorithm1_update(
    nets, weights, state, batch, advice, noise, constants, advised=None, step: Optional[Callable] = None
) -> dict:
    """One update of Algorithm 1's inner loop, in its order. Returns the losses (tensors).

    ``nets``: (actor, twin critic) modules, and with a camera the ObservationEncoder, for their
    structure (the weights come from ``weights``: 'actor', 'critic', 'critic_target' name ->
    tensor dicts, 'log_alpha', and 'encoder' with a camera);
    ``state``: each network's Adam state ('actor', 'critic', 'alpha', 'encoder': see adam_);
    ``batch``, ``advice``: the batches from D and D_advising (BATCH_COLUMNS order; advice None when
    there is none); ``noise``: update_noise's; ``constants``: gamma, tau, target_entropy, each
    network's Adam settings ('<network>_adam') and 'seeds' (1, or N stacked seeds).
    Stacked seeds: ``advised`` says which seeds have advice (the others' advice batch is a
    stand-in and gets no step), and ``step(network, params, grads, advised)`` replaces adam_.
    """
    actor_net, critic_net = nets[:2]
    actor_w, critic_w, target_w = weights['actor'], weights['critic'], weights['critic_target']
    seeds = constants['seeds']  # the loss of N stacked seeds is their mean: N x it gives each its own gradient
    losses = {}

    def adam_step(network, params, grads, only=None):
        if step is None:
            adam_(params, grads, state[network], constants[f'{network}_adam'])
        else:
            step(network, params, grads, only)

    # Eq. 4 targets of both batches in one pass: the actor, alpha and the target critics stay
    # as they are until the end of the update.
    target_noise, actor_noise, advice_actor_noise = noise
    y, advice_y = soft_targets(nets, weights, batch, advice, target_noise, constants['gamma'])

    def critic_step(obs, action, y, only=None):  # Eq. 5 for Q_theta1 and Q_theta2; returns (loss, what they read)
        if len(nets) == 2:

            def loss_of(w):
                q1, q2 = with_weights(critic_net, w)(obs, action)
                return seeds * (eq.critic_loss(q1, y) + eq.critic_loss(q2, y))

            grads, loss = gradient_and_value(loss_of, critic_w)
            adam_step('critic', list(critic_w.values()), list(grads.values()), only)
            return loss / seeds, obs
        return encoded_critic_step(nets, weights, obs, action, y, seeds, lambda *a: adam_step(*a, only))

    # 1st critic update: the batch from D (Eq. 5); 2nd: the batch from D_advising (Section 3.3).
    losses['critic_loss'], features = critic_step(batch[0], batch[1], y)
    if advice is not None:
        losses['advice_critic_loss'], advice_features = critic_step(advice[0], advice[1], advice_y, advised)

    def actor_and_alpha_step(obs, noise, only=None):
        alpha = weights['log_alpha'].detach().exp().unsqueeze(-1)
        critic = with_weights(critic_net, {name: t.detach() for name, t in critic_w.items()})

        def loss_of(w):  # Eq. 6 with a = tanh(mean + std * noise); log pi for the temperature
            mean, log_std = with_weights(actor_net, w)(obs)
            action, log_prob = eq.squashed_gaussian_sample(mean, log_std, noise)
            q1, q2 = critic(obs, action)
            return seeds * eq.actor_loss(log_prob, q1, q2, alpha), log_prob

        grads, (loss, log_prob) = gradient_and_value(loss_of, actor_w, has_aux=True)
        adam_step('actor', list(actor_w.values()), list(grads.values()), only)

        def alpha_loss_of(log_alpha):
            return seeds * eq.temperature_loss(log_alpha.unsqueeze(-1), log_prob, constants['target_entropy'])

        alpha_grad, alpha_loss = gradient_and_value(alpha_loss_of, weights['log_alpha'])
        adam_step('alpha', [weights['log_alpha']], [alpha_grad], only)
        return loss / seeds, alpha_loss / seeds

    # Actor (Eq. 6) and temperature on the batch from D (and on advice: actor_on_advice).
    losses['actor_loss'], losses['alpha_loss'] = actor_and_alpha_step(features, actor_noise)
    if advice_actor_noise is not None and advice is not None:
        losses['advice_actor_loss'], _ = actor_and_alpha_step(advice_features, advice_actor_noise, advised)

    # Target critics: theta^- <- tau * theta + (1 - tau) * theta^-.
    eq.soft_update(list(target_w.values()), list(critic_w.values()), constants['tau'])
    return losses


def update_then_act(nets, weights, state, batch, advice, noise, constants, ahead) -> tuple:
    """algorithm1_update, then the next step's acting from the weights it leaves: the function
    compile_update compiles (acting_ahead.py says why). ``ahead``: (s_{t+1} as the networks read
    it, [1, obs_dim]; the 'act' noise of a_{t+1}, [1, action_dim]; whether to compute D(s);
    whether to compute the exact E(s); None: no acting). Returns (the losses, {'mean', 'log_std',
    'action', and 'discrepancy', 'entropy' where asked} or None), as Learner.propose computes them
    eagerly."""
    losses = algorithm1_update(nets, weights, state, batch, advice, noise, constants)
    if ahead is None:
        return losses, None
    obs, act_noise, with_discrepancy, with_entropy = ahead
    mean, log_std = with_weights(nets[0], weights['actor'])(obs)
    action = eq.squashed_gaussian_action(mean, log_std, act_noise)  # a_{t+1} ~ pi(.|s_{t+1})
    acted = {'mean': mean, 'log_std': log_std, 'action': action}
    if with_discrepancy:
        q1, q2 = with_weights(nets[1], weights['critic'])(obs, action)
        acted['discrepancy'] = eq.q_discrepancy(q1, q2)  # Eq. 8
    if with_entropy:
        acted['entropy'] = eq.policy_entropy(mean, log_std)  # Eq. 9, exactly
    return losses, acted
