"""Milliseconds per update of each update path, eager and compiled, for one source tree or
for two side by side (before and after a change to the update).

    .venv/bin/python benchmarks/bench_update_paths.py                      # this tree
    .venv/bin/python benchmarks/bench_update_paths.py --trees OLD_CHECKOUT .   # old beside new
    .venv/bin/python benchmarks/bench_update_paths.py --sizes 256x256 64x128 64x64 # the shipped params files' sizes

Each tree is measured in child processes that import its ``eqhrl_ros`` package; with two
trees the children alternate (old, new, old, new, ...: --reps each), so a machine that speeds
up or slows down does so for both. A child fills a learner per configuration (Table 1 sizes:
256x256, batch 256; EQSAC with D_advising filled, so its updates take the second critic step),
compiles the compiled copies before timing, then times the eager and compiled updates of every
configuration in interleaved rounds. Prints the median ms per update of each tree and path and,
with two trees, the ratio of the second's speed to the first's. With one tree, also the compile's
seconds and the updates after which it has paid for itself (its seconds over what a compiled
update saves; the compile runs in a thread of its own, so on a free core it costs less). --sizes
HIDDENxBATCH: hidden layer width (two layers) and batch size, Table 1's 256x256 by default.
No target, no exit code.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

CONFIGS = (('Pendulum-v1', 'sac'), ('Pendulum-v1', 'eqsac'), ('LunarLanderContinuous-v3', 'eqsac'))
SIZES = {'Pendulum-v1': (3, 1), 'LunarLanderContinuous-v3': (8, 2)}


def child(tree: str, rounds: int, updates: int, threads: int, sizes: list) -> dict:
    sys.path.insert(0, str(Path(tree).resolve() / 'eqhrl_ros'))
    import numpy as np
    import torch

    from eqhrl_ros.core import EQSACLearner, LearnerConfig

    torch.set_num_threads(threads)
    learners = {}
    compile_s = {}
    for (env_id, mode), size in ((c, s) for s in sizes for c in CONFIGS):
        obs_dim, action_dim = SIZES[env_id]
        width, batch = (int(v) for v in size.split('x'))
        for compiled in (False, True):
            config = LearnerConfig(
                mode=mode, learning_starts=1, seed=0, compile_update=compiled, hidden=(width, width), batch_size=batch
            )
            learner = EQSACLearner(obs_dim, [-1.0] * action_dim, [1.0] * action_dim, config)
            rng = np.random.default_rng(0)
            for i in range(2000):
                learner.store(
                    rng.normal(size=obs_dim),
                    rng.uniform(-1, 1, size=action_dim),
                    float(rng.normal()),
                    rng.normal(size=obs_dim),
                    bool(i % 200 == 199),
                    advised=i % 10 == 0,
                )
            learner.update()  # the first update; with compile_update it starts the compiler
            if compiled and not learner.compiled_update.wait():
                raise RuntimeError(f'compile failed: {learner.compiled_update.failed}')
            if compiled:
                compile_s['|'.join((env_id, mode, size))] = learner.compiled_update.seconds
            learners[(env_id, mode, size, compiled)] = learner
    seconds = {key: [] for key in learners}
    for _ in range(rounds):
        for key, learner in learners.items():
            start = time.perf_counter()
            for _ in range(updates):
                learner.update()
            seconds[key].append((time.perf_counter() - start) / updates * 1e3)
    return {'times': {'|'.join(map(str, key)): values for key, values in seconds.items()}, 'compile_s': compile_s}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--trees', nargs='+', default=['.'], help='source trees (repository roots), 1 or 2')
    parser.add_argument('--reps', type=int, default=2, help='child processes per tree, alternating')
    parser.add_argument('--rounds', type=int, default=4, help='timed rounds per child')
    parser.add_argument('--updates', type=int, default=30, help='updates per configuration and round')
    parser.add_argument('--threads', type=int, default=2)
    parser.add_argument('--sizes', nargs='+', default=['256x256'], help='HIDDENxBATCH, e.g. 256x256 64x128')
    parser.add_argument('--child', help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(args.child, args.rounds, args.updates, args.threads, args.sizes)))
        return 0
    times = {tree: {} for tree in args.trees}
    compile_s = {}
    for _ in range(args.reps):
        for tree in args.trees:
            out = subprocess.run(
                [
                    sys.executable,
                    __file__,
                    '--child',
                    tree,
                    '--rounds',
                    str(args.rounds),
                    '--updates',
                    str(args.updates),
                    '--threads',
                    str(args.threads),
                    '--sizes',
                    *args.sizes,
                ],
                capture_output=True,
                text=True,
                check=True,
            ).stdout
            result = json.loads(out.strip().splitlines()[-1])
            for key, values in result['times'].items():
                times[tree].setdefault(key, []).extend(values)
            if tree == args.trees[0]:
                for key, value in result['compile_s'].items():
                    compile_s.setdefault(key, []).append(value)
    print(
        f'{args.threads} threads; per tree {args.reps} processes x {args.rounds} rounds x {args.updates} updates, '
        'trees alternating; median ms per update'
    )
    names = ''.join(f' {Path(t).resolve().name[:14]:>14s}' for t in args.trees)
    header = f'{"env":26s} {"mode":6s} {"size":8s} {"path":9s}' + names
    print(header + (' second/first speed' if len(args.trees) == 2 else ' compiled/eager speed, compile s, pays after'))
    for key in times[args.trees[0]]:
        env_id, mode, size, compiled = key.split('|')
        medians = [statistics.median(times[t][key]) for t in args.trees]
        line = f'{env_id:26s} {mode:6s} {size:8s} {"compiled" if compiled == "True" else "eager":9s}'
        line += ''.join(f' {m:14.2f}' for m in medians)
        if len(medians) == 2:
            line += f' {medians[0] / medians[1]:10.3f}x'
        elif compiled == 'True':
            eager = statistics.median(times[args.trees[0]][key.rsplit('|', 1)[0] + '|False'])
            seconds = statistics.median(compile_s['|'.join((env_id, mode, size))])
            saved_ms = eager - medians[0]
            pays = f'{seconds / saved_ms * 1e3:,.0f} updates' if saved_ms > 0 else 'never'
            line += f' {eager / medians[0]:10.2f}x {seconds:6.1f} s  {pays}'
        print(line, flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
