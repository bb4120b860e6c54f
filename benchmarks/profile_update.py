"""Inside the compiled update: products, fused kernels, and the call around them (issue 48, item 1).

    .venv/bin/python benchmarks/profile_update.py [--env Pendulum-v1] [--calls 300] [--threads 2]

For SAC and EQSAC (Table 1 sizes, batch 256, EQSAC with a full D_advising batch), the update that
compile_update: true runs is compiled in this thread with inductor's kernel profiling on (each
generated C++ kernel records its name), and called on one fixed pair of batches and noise:

- call: the wall time of one call of the compiled update, as the learner makes it;
- without guards: the same call under torch.compiler.set_stance(skip_guard_eval_unsafe=True),
  so the difference is what checking the program's guards costs each call;
- then one profiled stretch of calls, split by operator into the products (aten mm, addmm, bmm,
  baddbmm: the kernels torch calls for the matrix products), inductor's fused kernels (the
  element-wise work, the reductions, Adam), and the rest of the call (Python, the guards, the
  wrappers around the program, threads waiting);
- a 256x256x256 float32 product timed alone, and the update's count of them (PRODUCTS of
  bench_learner.py) at that time: the floor of the products;
- the twin critics' pair of products as one batched bmm against two mm, in the forward layout
  and the backward pass's transposed ones.
--python-wrapper and --max-autotune compile with those inductor options instead (item 2).

Medians of 5 interleaved rounds. Evidence, no target, no exit code; docs/performance.md keeps the
figures with the machine they were measured on. The profiler adds its own cost to each operation it
records, most to memory-bound ones on large tensors (EQSAC's 512-row ReLU: 0.26-0.67 ms a call in
the profile, about 43 us under perf without it); each kernel's share comes from perf.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections import defaultdict

import eqhrl_ros  # noqa: F401 - first, as in a user's nodes (eqhrl_ros/__init__.py runs before torch loads)

# isort: split
import numpy as np
import torch
import torch._inductor.config as inductor_config
from bench_learner import PRODUCTS, cpu_model  # the products an update does, and the CPU's name
from torch.profiler import ProfilerActivity, profile

from eqhrl_ros.core import EQSACLearner, LearnerConfig, heuristic_expert, make_env, run_episode
from eqhrl_ros.core.algorithm import compiled_update as compiled_module
from eqhrl_ros.core.algorithm import cpu_threads

PRODUCT_OPS = ('aten::mm', 'aten::addmm', 'aten::bmm', 'aten::baddbmm')
# The same products called from inductor's C++ wrapper (the default): its shims, not the dispatcher.
PRODUCT_OPS += tuple(f'aoti_torch_cpu_{name.split("::")[1]}_out' for name in PRODUCT_OPS)


def compiled_update(env_id: str, mode: str, warmup: int):
    """(the compiled function, its arguments) for ``mode``'s learner after ``warmup`` steps."""
    env = make_env(env_id)
    config = LearnerConfig(mode=mode, learning_starts=warmup, advising_budget=10**6, seed=0, compile_update=False)
    learner = EQSACLearner(
        int(np.prod(env.observation_space.shape)), env.action_space.low, env.action_space.high, config
    )
    expert = heuristic_expert(env_id)
    while learner.total_steps < warmup:  # inside the budget: D_advising fills with the expert's answers
        run_episode(env, learner, expert, seed=learner.total_steps)
    updater = learner.updater
    learner.update()  # an eager update first: the optimisers' state exists
    compiled = updater.start_compiling(background=False)
    assert compiled is not None and compiled.ready, f'the update did not compile: {compiled and compiled.failed}'
    batch, advice = learner.memories.sample()
    noise = updater.noise_for(batch, advice)
    weights, state, constants = updater.inputs()
    ahead = updater.ahead.inputs(learner.observation.tensor(env.reset(seed=1)[0]), updater.obs_dim)  # acting ahead
    arguments = (updater.nets, weights, state, batch.columns(), advice and advice.columns(), noise, constants, ahead)
    return compiled.function, arguments


def timed(function, arguments, calls: int, skip_guards: bool = False) -> float:
    """ms per call of ``function(*arguments)``."""
    stance = torch.compiler.set_stance('default', skip_guard_eval_unsafe=skip_guards)
    with stance:
        start = time.perf_counter()
        for _ in range(calls):
            function(*arguments)
        return (time.perf_counter() - start) / calls * 1e3


def split(function, arguments, calls: int) -> dict:
    """ms per call in the products, in inductor's fused kernels, and in all, from one profile."""
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        start = time.perf_counter()
        for _ in range(calls):
            function(*arguments)
        wall = (time.perf_counter() - start) / calls * 1e3
    parts: dict = defaultdict(float)
    for event in prof.key_averages():
        name = event.key
        if name in PRODUCT_OPS:
            parts['products'] += event.self_cpu_time_total
        elif 'cpp_fused' in name:
            parts['fused kernels'] += event.self_cpu_time_total
    out = {name: value / calls / 1e3 for name, value in parts.items()}
    out['profiled call'] = wall
    return out


def product_alone(calls: int = 200) -> float:
    a, b = torch.randn(256, 256), torch.randn(256, 256)
    for _ in range(20):
        torch.mm(a, b)
    start = time.perf_counter()
    for _ in range(calls):
        torch.mm(a, b)
    return (time.perf_counter() - start) / calls * 1e3


def pair_products(calls: int = 300) -> dict:
    """ms for the twin critics' pair of 256x256x256 products: one batched bmm against two mm, in
    the forward layout and in the backward pass's two transposed ones."""
    a, b = torch.randn(2, 256, 256), torch.randn(2, 256, 256)
    out, one, two = torch.empty(2, 256, 256), torch.empty(256, 256), torch.empty(256, 256)
    layouts = {'forward': (a, b), 'A^T': (a.transpose(1, 2), b), 'B^T': (a, b.transpose(1, 2))}
    figures = {}
    for name, (x, y) in layouts.items():
        for kind, run in (
            ('bmm', lambda x=x, y=y: torch.bmm(x, y, out=out)),
            ('2 mm', lambda x=x, y=y: (torch.mm(x[0], y[0], out=one), torch.mm(x[1], y[1], out=two))),
        ):
            for _ in range(20):
                run()
            start = time.perf_counter()
            for _ in range(calls):
                run()
            figures[f'{name} {kind}'] = (time.perf_counter() - start) / calls * 1e3
    return figures


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--env', default='Pendulum-v1')
    parser.add_argument('--warmup', type=int, default=1000)
    parser.add_argument('--calls', type=int, default=300)
    parser.add_argument('--rounds', type=int, default=5)
    parser.add_argument('--threads', type=int, default=2)
    parser.add_argument(
        '--python-wrapper', action='store_true', help="inductor's Python wrapper instead of its C++ one (the default)"
    )
    parser.add_argument(
        '--max-autotune', action='store_true', help="inductor's autotuner over its CPP GEMM templates and ATen"
    )
    args = parser.parse_args()
    # Over the program's own options (compiled_update.py): torch.compile's would override a global setting.
    if args.python_wrapper:
        compiled_module.CPU_PROGRAM_OPTIONS = {**compiled_module.CPU_PROGRAM_OPTIONS, 'cpp_wrapper': False}
    if args.max_autotune:
        compiled_module.PROGRAM_OPTIONS = {
            **compiled_module.PROGRAM_OPTIONS,
            'max_autotune': True,
            'max_autotune_gemm_backends': 'CPP,ATEN',
        }

    cpu_threads.fix(args.threads)  # fixed: side by side, no contender's threads count as a crowd
    inductor_config.cpp.enable_kernel_profile = True  # each generated kernel names itself in the profile
    modes = ('sac', 'eqsac')
    programs = {mode: compiled_update(args.env, mode, args.warmup) for mode in modes}
    figures: dict = defaultdict(lambda: defaultdict(list))
    for _ in range(args.rounds):
        for mode, (function, arguments) in programs.items():
            figures[mode]['call'].append(timed(function, arguments, args.calls))
            figures[mode]['without guards'].append(timed(function, arguments, args.calls, skip_guards=True))
            for name, value in split(function, arguments, max(args.calls // 3, 20)).items():
                figures[mode][name].append(value)
        figures['product']['alone'].append(product_alone())
        for name, value in pair_products().items():
            figures['pair'][name].append(value)
    product = statistics.median(figures['product']['alone'])
    print(f'{args.env}, {args.threads} threads ({cpu_model()}), medians of {args.rounds} rounds, ms per update call')
    print('| part | ' + ' | '.join(modes) + ' |')
    print('|---|' + '---|' * len(modes))
    rows = ('call', 'without guards', 'profiled call', 'products', 'fused kernels')
    medians = {mode: {row: statistics.median(figures[mode][row] or [0.0]) for row in rows} for mode in modes}
    for row in rows:
        print(f'| {row} | ' + ' | '.join(f'{medians[m][row]:.3f}' for m in modes) + ' |')
    rest = {m: medians[m]['profiled call'] - medians[m]['products'] - medians[m]['fused kernels'] for m in modes}
    print('| rest of the profiled call | ' + ' | '.join(f'{rest[m]:.3f}' for m in modes) + ' |')
    floor = {m: PRODUCTS[m] * product for m in modes}
    print(
        f'| {"/".join(str(PRODUCTS[m]) for m in modes)} products at {product:.3f} ms alone | '
        + ' | '.join(f'{floor[m]:.3f}' for m in modes)
        + ' |'
    )
    pairs = ', '.join(f'{name} {statistics.median(v):.3f}' for name, v in figures['pair'].items())
    print(f'the twin pair of products, ms: {pairs}')
    print(
        f'EQSAC / SAC, call: {medians["eqsac"]["call"] / medians["sac"]["call"]:.2f}x '
        f'(products: {PRODUCTS["eqsac"] / PRODUCTS["sac"]:.2f}x)'
    )


if __name__ == '__main__':
    main()
