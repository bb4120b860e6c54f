"""Where each thread of a training loop spends a step, and how often it sleeps (issue 48, item 1).

    .venv/bin/python benchmarks/profile_threads.py [--env Pendulum-v1] [--modes sac eqsac] [--seconds 8] [--rounds 2]

One learner per mode (Table 1 sizes, the update compiled as compile_update: true runs it, in
this thread, before anything is measured; split_step.make), then in rounds the modes take turns
running their training loop for --seconds each (propose, the expert when asked, env.step, store,
sample, the compiled update: split_step.timed_round). For each mode's turns it reads, per thread
of the process, from /proc/self/task:

- on CPU: the thread's run time per step (schedstat);
- waiting for a CPU: its time runnable but not running per step (another thread or process had
  the core);
- sleeps: its voluntary context switches per step (an OpenMP thread that stopped spinning and
  waits on a futex, a blocking call): each one is a wake-up to pay later.

With linux perf on the PATH (Debian: linux-perf) it also samples the process (cpu-clock, user
and kernel) during each turn and splits each thread's time on CPU by where it runs (CATEGORIES):
the products (MKL / oneDNN GEMM), OpenMP's waiting (libgomp: spinning at a barrier or for work),
Python (the interpreter, torch's and numpy's bindings), inductor's compiled kernels, torch's other
kernels, math libraries (Sleef, libm), the OS kernel, the C libraries. Without perf it says so
and prints the /proc figures alone.

Prints, per mode, a table of ms per step by thread, the step's wall time, and the products' share
of the main thread. Evidence, no target, no exit code; docs/performance.md keeps the figures with
the machine they were measured on.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import tempfile
import threading
import time
from collections import Counter, defaultdict

import eqhrl_ros  # noqa: F401 - first, as in a user's nodes (eqhrl_ros/__init__.py runs before torch loads)

# isort: split
import torch
from bench_learner import cpu_model, openmp_spin
from split_step import make, timed_round

from eqhrl_ros.core.algorithm import cpu_threads

# (name, test on (symbol, library path)), first match wins; the last catches everything else.
CATEGORIES = (
    ('products', lambda sym, dso: 'gemm' in sym or sym.startswith('mkl_') or 'dnnl' in dso or 'mkldnn' in sym),
    ('OpenMP waiting', lambda sym, dso: 'libgomp' in dso or 'libiomp' in dso),
    ('Python', lambda sym, dso: 'python' in os.path.basename(dso)),
    ('inductor kernels', lambda sym, dso: 'torchinductor' in dso),
    ('math (Sleef, libm)', lambda sym, dso: 'Sleef' in sym or os.path.basename(dso).startswith('libm.')),
    ('torch other', lambda sym, dso: os.path.basename(dso).startswith(('libtorch', 'libc10'))),
    ('OS kernel', lambda sym, dso: 'kernel' in dso and dso.startswith('[')),
    ('C libraries', lambda sym, dso: os.path.basename(dso).startswith(('libc.', 'libstdc++', 'ld-linux'))),
    ('other', lambda sym, dso: True),
)
SAMPLE = re.compile(r'^\s*(\d+)\s+[0-9a-f]+\s+(.*?)\s+\((.*)\)\s*$')


def category(symbol: str, library: str) -> str:
    return next(name for name, test in CATEGORIES if test(symbol, library))


def threads_now() -> dict:
    """tid -> (ns on CPU, ns waiting for a CPU, voluntary context switches) of this process's threads."""
    out = {}
    for tid in os.listdir('/proc/self/task'):
        try:
            with open(f'/proc/self/task/{tid}/schedstat') as f:
                run_ns, wait_ns = (int(v) for v in f.read().split()[:2])
            with open(f'/proc/self/task/{tid}/status') as f:
                sleeps = next(int(line.split()[1]) for line in f if line.startswith('voluntary_ctxt_switches'))
        except (OSError, StopIteration, ValueError):  # the thread ended meanwhile
            continue
        out[int(tid)] = (run_ns, wait_ns, sleeps)
    return out


def perf_samples(path: str) -> Counter:
    """(tid, category) -> samples, from a perf.data file."""
    script = subprocess.run(
        ['perf', 'script', '-i', path, '-F', 'tid,ip,sym,dso'], capture_output=True, text=True, check=True
    ).stdout
    counts: Counter = Counter()
    for line in script.splitlines():
        match = SAMPLE.match(line)
        if match:
            tid, symbol, library = match.groups()
            counts[(int(tid), category(symbol, library))] += 1
    return counts


def one_turn(contender: list, seconds: float, perf: str | None, folder: str, index: int) -> dict:
    """Run one mode's loop for ``seconds``; its steps, wall seconds, the threads' /proc deltas and,
    with perf, its samples."""
    env, learner, expert, obs = contender
    recorder, data = None, os.path.join(folder, f'turn{index}.data')
    if perf:
        recorder = subprocess.Popen(
            [perf, 'record', '-q', '-e', 'cpu-clock', '-F', '1999', '-p', str(os.getpid()), '-o', data],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        time.sleep(0.3)  # perf attaches to every thread before the measured steps start
    before, start, steps = threads_now(), time.perf_counter(), 0
    while time.perf_counter() - start < seconds:
        _, obs = timed_round(env, learner, expert, 25, obs)
        steps += 25
    wall, after = time.perf_counter() - start, threads_now()
    contender[3] = obs
    samples: Counter = Counter()
    if recorder is not None:
        recorder.send_signal(2)  # SIGINT: perf writes its file and exits
        recorder.wait(timeout=30)
        samples = perf_samples(data)
    deltas = {
        tid: tuple(a - b for a, b in zip(after[tid], before.get(tid, (0, 0, 0)))) for tid in after if tid in before
    }
    return {'steps': steps, 'wall': wall, 'threads': deltas, 'samples': samples}


def report(mode: str, turns: list, main_tid: int) -> None:
    steps = sum(t['steps'] for t in turns)
    wall_ms = 1e3 * sum(t['wall'] for t in turns) / steps
    threads: dict = defaultdict(lambda: [0, 0, 0])
    samples: Counter = Counter()
    for turn in turns:
        for tid, values in turn['threads'].items():
            for i, v in enumerate(values):
                threads[tid][i] += v
        samples.update(turn['samples'])
    busy = [tid for tid, (run, _, _) in threads.items() if run / steps > 0.01e6]  # over 10 us a step
    busy.sort(key=lambda tid: (tid != main_tid, -threads[tid][0]))
    names = [name for name, _ in CATEGORIES] if samples else []
    print(f'\n{mode}: {steps} steps, {wall_ms:.3f} ms a step (wall); ms per step by thread')
    print('| thread | on CPU | waiting for a CPU | sleeps per step | ' + ' | '.join(names) + ' |')
    print('|---|---|---|---|' + '---|' * len(names))
    for tid in busy:
        run, wait, sleeps = threads[tid]
        label = 'main (Python, OpenMP thread 0)' if tid == main_tid else f'worker {tid}'
        cells = [f'{run / steps / 1e6:.3f}', f'{wait / steps / 1e6:.3f}', f'{sleeps / steps:.1f}']
        total = sum(samples[(tid, name)] for name in names)
        for name in names:  # the thread's time on CPU, split by the share of its samples
            cells.append(f'{run / steps / 1e6 * samples[(tid, name)] / total:.3f}' if total else '-')
        print(f'| {label} | ' + ' | '.join(cells) + ' |')


def wake_up_cost(regions: int = 200) -> tuple:
    """(the spin's length, the cost of a sleep) in microseconds, as this process's OpenMP has them:
    one small parallel region (an in-place add over 2^18 floats) after a busy pause of a given
    length in the main thread. The spin: the shortest pause after which the worker slept after
    most regions. The cost: a region after a 1 ms pause (the worker asleep) against one after
    2 us (the worker spinning)."""
    x = torch.ones(1 << 18)
    me = threading.get_native_id()

    def region_us(pause_us: float) -> tuple:
        before = sum(v[2] for tid, v in threads_now().items() if tid != me)
        spent = 0.0
        for _ in range(regions):
            start = time.perf_counter()
            x.add_(1.0)
            spent += time.perf_counter() - start
            until = time.perf_counter() + pause_us * 1e-6
            while time.perf_counter() < until:
                pass
        sleeps = sum(v[2] for tid, v in threads_now().items() if tid != me) - before
        return 1e6 * spent / regions, sleeps / regions

    region_us(2)  # the team exists
    spin = next((p for p in (2, 5, 10, 20, 50, 100, 200, 500, 1000) if region_us(p)[1] > 0.5), None)
    return spin, region_us(1000)[0] - region_us(2)[0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--env', default='Pendulum-v1')
    parser.add_argument('--modes', nargs='+', default=['sac', 'eqsac'])
    parser.add_argument('--warmup', type=int, default=1000)
    parser.add_argument('--seconds', type=float, default=8.0)
    parser.add_argument('--rounds', type=int, default=2)
    parser.add_argument('--threads', type=int, default=2)
    args = parser.parse_args()
    args.compile = True  # split_step.make's flag: the update compiled before anything is timed
    cpu_threads.fix(args.threads)  # fixed: side by side, no contender's threads count as a crowd
    perf = shutil.which('perf')
    contenders = {}
    for mode in args.modes:
        env, learner, expert = make(args.env, mode, args)
        contenders[mode] = [env, learner, expert, env.reset(seed=1)[0]]
        _, contenders[mode][3] = timed_round(env, learner, expert, 50, contenders[mode][3])  # the OpenMP team exists
    turns: dict = defaultdict(list)
    with tempfile.TemporaryDirectory() as folder:
        for r in range(args.rounds):
            for i, mode in enumerate(args.modes):
                turns[mode].append(one_turn(contenders[mode], args.seconds, perf, folder, r * len(args.modes) + i))
    print(
        f'{args.env}, compiled update, {args.threads} threads, OpenMP spin {openmp_spin()} ({cpu_model()}), '
        f'{args.rounds} turns of {args.seconds:g} s per mode, interleaved'
    )
    spin_us, cost_us = wake_up_cost()
    print(
        f'OpenMP worker: sleeps after a pause of {spin_us if spin_us else "over 1000"} us; '
        f'a parallel region after it slept costs {cost_us:.0f} us more (wake-up)'
    )
    if not perf:
        print('perf not found (Debian: apt install linux-perf): the split by library is left out')
    for mode in args.modes:
        report(mode, turns[mode], threading.get_native_id())


if __name__ == '__main__':
    main()
