"""The compiled update under inductor's CPU kernel options, side by side (issue 48, item 2).

    .venv/bin/python benchmarks/kernel_options.py [--env Pendulum-v1] [--calls 100] [--rounds 15] [--sets NAME ...]

The update that compile_update: true runs (SAC and EQSAC, Table 1 sizes, batch 256) is compiled
once per option set below, each with a code object of its own (so no set reuses another's
program), and the programs are called in interleaved rounds (in a new order each round) on one
fixed pair of batches:

- default: what the learner compiles;
- fused serial: inductor's own kernels (the element-wise work, the reductions, Adam) on one
  thread (cpp.threads 1), while torch's products keep --threads: each of the update's few dozen
  kernels then skips an OpenMP fork and join over data of at most 256x256 floats;
- big chunks: a kernel goes parallel only with at least 16,384 elements a thread
  (cpp.min_chunk_size; inductor's default is 512);
- python wrapper: the program's calls made from a generated Python function instead of from C++
  (cpp_wrapper off: the learner's default until 2026-12-04);
- dynamic threads: the fused kernels read torch's thread count when called, not the one at
  compile time (cpp.dynamic_threads), so that one program serves every count;
- no input asserts: the program's Python wrapper without its checks of each input's size,
  stride and alignment (size_asserts, scalar_asserts, alignment_asserts);
- memory planning: the program's buffers planned into one pool (memory_planning).

Then other ways of writing the update's code, which inductor turns into other kernels (code
forms, defined here and swapped into networks.py or update.py while their program compiles):

- sleef tanh: the actor's hidden tanh as torch.tanh, which inductor makes Sleef's vector tanh
  (the update's form before 2026-12-04; networks.tanh now compiles the one-exponential form of
  networks._ExpTanh, about twice as fast);
- tanh sign by where: that form with its sign restored by a select (torch.where) instead of
  copysign, which inductor calls from Sleef through the PLT, a call per vector (the same floats);
- bias apart: each layer's product and its bias as a product and a sum, so that the sum is
  fused into the activation's kernel: the library's addmm / baddbmm first copies the bias into
  every row of its output;
- thin layers: bias apart, and a layer of at most THIN inputs (the first: the observation and
  the action) as a sum of products that inductor fuses, instead of a product with a few columns;
- thin bias apart: bias apart for the thin layers only (their bias copy costs more than their
  product), the others as shipped;
- thin fused: the thin layers only as a fused sum of products, the others as shipped (no bias
  copy, no product and no separate ReLU kernel for the first layers);
- torch's adam traced: the Adam step as the update compiled it before 2026-12-04, torch's own
  capturable Adam traced as it is (update.adam_ now writes its steps out so that each network's
  bias corrections are computed once);
- targets apart: Eq. 4's targets of the batch from D and of the one from D_advising in a pass
  each (update.soft_targets joins them: EQSAC's 512 rows of activations, 1 MB a layer, fill a
  core's L2 cache; for SAC the two forms are one).

Prints each set's median ms per call and its speed against the default's (the median of the
rounds' ratios, each round's sets side by side), per mode, and whether the set's losses equal
the default's on the same inputs (to float rounding: a kernel option may only reorder sums; the
two tanh forms are within 1e-7 of each other). Evidence, no target, no exit code; docs/performance.md keeps
the figures with the machine they were measured on.
"""

from __future__ import annotations

import argparse
import random
import statistics
from collections import defaultdict

import eqhrl_ros  # noqa: F401 - first, as in a user's nodes (eqhrl_ros/__init__.py runs before torch loads)

# isort: split
import torch
from bench_learner import cpu_model
from profile_update import compiled_update, timed
from torch.optim.adam import adam as torchs_adam

from eqhrl_ros.core.algorithm import compiled_update as compiled_module
from eqhrl_ros.core.algorithm import cpu_threads, networks, update

OPTION_SETS = {
    'default': {},
    'fused serial': {'cpp.threads': 1},
    'big chunks': {'cpp.min_chunk_size': 16384},
    'python wrapper': {'cpp_wrapper': False},
    # The fused kernels read the thread count when called, instead of the one at compile time.
    'dynamic threads': {'cpp.dynamic_threads': True},
    # The program's Python wrapper without its checks of each input's size, stride and alignment.
    'no input asserts': {'size_asserts': False, 'scalar_asserts': False, 'alignment_asserts': False},
    # The program's buffers planned into one pool, instead of one allocation each per call.
    'memory planning': {'memory_planning': True},
}


def sleef_tanh(x: torch.Tensor) -> torch.Tensor:
    """networks.tanh as it was before 2026-12-04: torch.tanh when compiling (Sleef's vector tanh)."""
    return torch.tanh(x) if torch.compiler.is_dynamo_compiling() else SHIPPED['tanh'](x)


class _SignedByWhere(networks._TanhGradient):
    """networks._ExpTanh with the sign restored by a select instead of copysign (which inductor
    calls from Sleef through the PLT, one call per vector)."""

    @staticmethod
    def forward(x: torch.Tensor) -> torch.Tensor:
        t = torch.exp(-2.0 * x.abs())
        r = (1.0 - t) / (1.0 + t)
        return torch.where(x < 0, -r, r)


def tanh_signed_by_where(x: torch.Tensor) -> torch.Tensor:
    """networks.tanh with _SignedByWhere when compiling."""
    if torch.compiler.is_dynamo_compiling() and x.numel() >= networks.NUMPY_TANH_FROM:
        return _SignedByWhere.apply(x)
    return SHIPPED['tanh'](x)


def linear_bias_apart(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    """networks.linear with the bias added after the product, when compiling."""
    if not torch.compiler.is_dynamo_compiling():
        return SHIPPED['linear'](x, weight, bias)
    return torch.matmul(x, weight.transpose(-1, -2)) + bias.unsqueeze(-2)


def product_bias_apart(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    """networks.biased_product with the bias added after the product, when compiling."""
    if not torch.compiler.is_dynamo_compiling():
        return SHIPPED['biased_product'](x, weight, bias)
    return torch.bmm(x, weight) + bias


THIN = 16  # a layer with at most this many inputs


def thin_linear(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor, otherwise) -> torch.Tensor:
    """networks.linear with a thin layer as a sum of products when compiling; ``otherwise`` for the others."""
    if not torch.compiler.is_dynamo_compiling() or weight.shape[-1] > THIN:
        return otherwise(x, weight, bias)
    return (x.unsqueeze(-2) * weight).sum(-1) + bias


def thin_product(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor, otherwise) -> torch.Tensor:
    """networks.biased_product with a thin layer as a sum of products when compiling; ``otherwise`` for the others."""
    if not torch.compiler.is_dynamo_compiling() or weight.shape[-2] > THIN:
        return otherwise(x, weight, bias)
    return (x.unsqueeze(-1) * weight.unsqueeze(-3)).sum(-2) + bias


def linear_thin(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    """networks.linear, a thin layer as a sum of products and the others with the bias apart."""
    return thin_linear(x, weight, bias, BIAS_APART['linear'])


def product_thin(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    """networks.biased_product, a thin layer as a sum of products and the others with the bias apart."""
    return thin_product(x, weight, bias, BIAS_APART['biased_product'])


@torch.no_grad()
def adam_traced(params: list, grads: list, state: tuple, settings: dict) -> None:
    """update.adam_ as it was before 2026-12-04: torch's capturable Adam traced as it is, which
    recomputes each weight's bias corrections in every chunk of its loop."""
    if not torch.compiler.is_dynamo_compiling():
        return SHIPPED['adam_'](params, grads, state, settings)
    exp_avgs, exp_avg_sqs, steps = state
    beta1, beta2 = settings['betas']
    torchs_adam(
        params, grads, exp_avgs, exp_avg_sqs, [], steps, foreach=False, capturable=True, amsgrad=False,
        beta1=beta1, beta2=beta2, lr=settings['lr'], weight_decay=0.0, eps=settings['eps'], maximize=False,
    )  # fmt: skip
    return None


def linear_thin_fused(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    """networks.linear, a thin layer as a sum of products and the others as shipped."""
    return thin_linear(x, weight, bias, SHIPPED['linear'])


def product_thin_fused(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    """networks.biased_product, a thin layer as a sum of products and the others as shipped."""
    return thin_product(x, weight, bias, SHIPPED['biased_product'])


@torch.no_grad()
def targets_apart(nets, weights, batch, advice, target_noise, gamma: float) -> tuple:
    """update.soft_targets with Eq. 4's y of the batch from D and of the one from D_advising
    computed in a pass each, when compiling: joined, their 512 rows' activations outgrow a core's
    L2 cache."""
    if not torch.compiler.is_dynamo_compiling() or advice is None:
        return SHIPPED['soft_targets'](nets, weights, batch, advice, target_noise, gamma)
    noise, advice_noise = target_noise.split([batch[2].shape[-1], advice[2].shape[-1]], dim=-2)
    y, _ = SHIPPED['soft_targets'](nets, weights, batch, None, noise, gamma)
    advice_y, _ = SHIPPED['soft_targets'](nets, weights, advice, None, advice_noise, gamma)
    return y, advice_y


def linear_thin_bias_apart(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    """networks.linear with the bias apart for a thin layer only, when compiling."""
    if weight.shape[-1] > THIN:
        return SHIPPED['linear'](x, weight, bias)
    return BIAS_APART['linear'](x, weight, bias)


def product_thin_bias_apart(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    """networks.biased_product with the bias apart for a thin layer only, when compiling."""
    if weight.shape[-2] > THIN:
        return SHIPPED['biased_product'](x, weight, bias)
    return BIAS_APART['biased_product'](x, weight, bias)


SHIPPED = {name: getattr(networks, name) for name in ('tanh', 'linear', 'biased_product')}
UPDATE_FUNCTIONS = ('adam_', 'soft_targets')  # code forms of update.py; the others are networks.py's
SHIPPED.update({name: getattr(update, name) for name in UPDATE_FUNCTIONS})
BIAS_APART = {'linear': linear_bias_apart, 'biased_product': product_bias_apart}
THIN_LAYERS = {'linear': linear_thin, 'biased_product': product_thin}
CODE_FORMS = {
    'bias apart': BIAS_APART,
    'thin layers': THIN_LAYERS,
    'thin bias apart': {'linear': linear_thin_bias_apart, 'biased_product': product_thin_bias_apart},
    'thin fused': {'linear': linear_thin_fused, 'biased_product': product_thin_fused},
    "torch's adam traced": {'adam_': adam_traced},
    'sleef tanh': {'tanh': sleef_tanh},
    'tanh sign by where': {'tanh': tanh_signed_by_where},
    'targets apart': {'soft_targets': targets_apart},
}
VARIANTS = {
    **{name: (options, {}) for name, options in OPTION_SETS.items()},
    **{name: ({}, forms) for name, forms in CODE_FORMS.items()},
}


def compiled_with(env_id: str, mode: str, warmup: int, options: dict, forms: dict):
    """compiled_update's (function, arguments), compiled under ``options`` with the code ``forms``
    (networks' functions by name) and a fresh code object."""
    compiled_module._COPIES.clear()  # a setting's copy of the update would hand back the last program
    # Set over the program's own options: torch.compile's options would override a global patch
    # of inductor's config for the keys they name (the thread count, the C++ wrapper).
    shipped_options = compiled_module.PROGRAM_OPTIONS
    compiled_module.PROGRAM_OPTIONS = {**shipped_options, **options}
    try:
        for name, function in forms.items():
            setattr(update if name in UPDATE_FUNCTIONS else networks, name, function)
        return compiled_update(env_id, mode, warmup)
    finally:  # the program keeps what it traced; the module gets the shipped code back
        compiled_module.PROGRAM_OPTIONS = shipped_options
        for name, function in SHIPPED.items():
            setattr(update if name in UPDATE_FUNCTIONS else networks, name, function)


def losses_of(function, arguments) -> dict:
    """The losses of one call on copies of the weights and Adam state (the inputs stay as they were)."""
    nets, weights, state, *rest = arguments
    weights = {
        k: {n: t.clone() for n, t in v.items()} if isinstance(v, dict) else v.clone() for k, v in weights.items()
    }
    state = {k: tuple([t.clone() for t in part] for part in v) for k, v in state.items()}
    losses, _ = function(nets, weights, state, *rest)  # (and the acting ahead)
    return {k: float(v) for k, v in losses.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--env', default='Pendulum-v1')
    parser.add_argument('--warmup', type=int, default=1000)
    parser.add_argument('--calls', type=int, default=100)
    parser.add_argument('--rounds', type=int, default=15)
    parser.add_argument('--threads', type=int, default=2)
    parser.add_argument('--sets', nargs='+', choices=list(VARIANTS), help='only these (default: every set)')
    args = parser.parse_args()
    variants = {name: VARIANTS[name] for name in ['default', *(args.sets or VARIANTS)] if name in VARIANTS}
    cpu_threads.fix(args.threads)  # fixed: side by side, no contender's threads count as a crowd
    modes = ('sac', 'eqsac')
    programs = {
        (name, mode): compiled_with(args.env, mode, args.warmup, options, forms)
        for name, (options, forms) in variants.items()
        for mode in modes
    }
    same = {}
    for (name, mode), (function, _) in programs.items():  # each program on the default's inputs
        reference = losses_of(*programs[('default', mode)])
        ours = losses_of(function, programs[('default', mode)][1])
        same[(name, mode)] = all(abs(ours[k] - reference[k]) <= 1e-4 * max(1.0, abs(reference[k])) for k in reference)
    figures: dict = defaultdict(list)
    order, shuffle = list(programs), random.Random(0).shuffle
    for _ in range(args.rounds):
        shuffle(order)  # a new order each round: no set always runs first, or right after another
        for key in order:
            function, arguments = programs[key]
            figures[key].append(timed(function, arguments, args.calls))
    print(
        f'{args.env}, {args.threads} threads ({cpu_model()}), medians of {args.rounds} rounds, ms per update call; '
        'speed vs default: the median of the per-round ratios'
    )
    print('| options | ' + ' | '.join(f'{m} ms | {m} vs default' for m in modes) + ' | losses as default |')
    print('|---|' + '---|---|' * len(modes) + '---|')
    for name in variants:
        cells = []
        for mode in modes:
            ms = statistics.median(figures[(name, mode)])
            # Each round's ratio to the default's in the same round: a machine that drifts
            # between rounds moves both alike (this VM's speed drifts by 20 % within minutes).
            ratio = statistics.median(b / m for b, m in zip(figures[('default', mode)], figures[(name, mode)]))
            cells.append(f'{ms:.3f} | {ratio:.2f}x')
        equal = 'yes' if all(same[(name, m)] for m in modes) else 'no'
        print(f'| {name} | ' + ' | '.join(cells) + f' | {equal} |')


if __name__ == '__main__':
    main()
