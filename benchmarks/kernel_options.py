"""The compiled update under inductor's CPU kernel options, side by side (issue 48, item 2).

    .venv/bin/python benchmarks/kernel_options.py [--env Pendulum-v1] [--calls 300] [--rounds 5]

The update that compile_update: true runs (SAC and EQSAC, Table 1 sizes, batch 256) is compiled
once per option set below, each with a code object of its own (so no set reuses another's
program), and the programs are called in interleaved rounds on one fixed pair of batches:

- default: what the learner compiles;
- fused serial: inductor's own kernels (the element-wise work, the reductions, Adam) on one
  thread (cpp.threads 1), while torch's products keep --threads: each of the update's few dozen
  kernels then skips an OpenMP fork and join over data of at most 256x256 floats;
- big chunks: a kernel goes parallel only with at least 16,384 elements a thread
  (cpp.min_chunk_size; inductor's default is 512);
- cpp wrapper: the program's calls made from C++ instead of Python (cpp_wrapper).

Prints each set's median ms per call and its ratio to the default's, per mode, and whether the
set's losses equal the default's on the same inputs (to float rounding: a kernel option may
only reorder sums). Evidence, no target, no exit code; docs/performance.md keeps the figures
with the machine they were measured on.
"""

from __future__ import annotations

import argparse
import statistics
from collections import defaultdict

import torch
import torch._inductor.config as inductor_config
from bench_learner import cpu_model
from profile_update import compiled_update, timed

from eqhrl_ros.core.algorithm import compiled_update as compiled_module

OPTION_SETS = {
    'default': {},
    'fused serial': {'cpp.threads': 1},
    'big chunks': {'cpp.min_chunk_size': 16384},
    'cpp wrapper': {'cpp_wrapper': True},
}


def compiled_with(env_id: str, mode: str, warmup: int, options: dict):
    """compiled_update's (function, arguments), compiled under ``options`` with a fresh code object."""
    compiled_module._COPIES.clear()  # a setting's copy of the update would hand back the last program
    with inductor_config.patch(options):
        return compiled_update(env_id, mode, warmup)


def losses_of(function, arguments) -> dict:
    """The losses of one call on copies of the weights and Adam state (the inputs stay as they were)."""
    nets, weights, state, *rest = arguments
    weights = {
        k: {n: t.clone() for n, t in v.items()} if isinstance(v, dict) else v.clone() for k, v in weights.items()
    }
    state = {k: tuple([t.clone() for t in part] for part in v) for k, v in state.items()}
    return {k: float(v) for k, v in function(nets, weights, state, *rest).items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--env', default='Pendulum-v1')
    parser.add_argument('--warmup', type=int, default=1000)
    parser.add_argument('--calls', type=int, default=300)
    parser.add_argument('--rounds', type=int, default=5)
    parser.add_argument('--threads', type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    modes = ('sac', 'eqsac')
    programs = {
        (name, mode): compiled_with(args.env, mode, args.warmup, options)
        for name, options in OPTION_SETS.items()
        for mode in modes
    }
    same = {}
    for (name, mode), (function, _) in programs.items():  # each program on the default's inputs
        reference = losses_of(*programs[('default', mode)])
        ours = losses_of(function, programs[('default', mode)][1])
        same[(name, mode)] = all(abs(ours[k] - reference[k]) <= 1e-4 * max(1.0, abs(reference[k])) for k in reference)
    figures: dict = defaultdict(list)
    for _ in range(args.rounds):
        for key, (function, arguments) in programs.items():
            figures[key].append(timed(function, arguments, args.calls))
    print(f'{args.env}, {args.threads} threads ({cpu_model()}), medians of {args.rounds} rounds, ms per update call')
    print('| options | ' + ' | '.join(f'{m} ms | {m} vs default' for m in modes) + ' | losses as default |')
    print('|---|' + '---|---|' * len(modes) + '---|')
    for name in OPTION_SETS:
        cells = []
        for mode in modes:
            ms, base = statistics.median(figures[(name, mode)]), statistics.median(figures[('default', mode)])
            cells.append(f'{ms:.3f} | {base / ms:.2f}x')
        equal = 'yes' if all(same[(name, m)] for m in modes) else 'no'
        print(f'| {name} | ' + ' | '.join(cells) + f' | {equal} |')


if __name__ == '__main__':
    main()
