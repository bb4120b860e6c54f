"""A busy machine: learner updates per second, quiet and beside a CPU-bound process.

    .venv/bin/python benchmarks/bench_busy.py [--seconds 6] [--rounds 3]

A learner rarely has the cores to itself: a simulator, a camera driver or a second
run shares them. torch's OpenMP threads spin-wait for work by default, and on a
loaded machine they fight the other process for the cores. This script measures,
in fresh processes (OpenMP reads its settings once, at start-up), EQSAC updates
per second (the demo's sizes by default, 64x64 and batch 128) for each setting below, quiet and
with one busy-loop process beside it, taking turns in rounds, and prints each
setting's busy/quiet ratio. A learner's fair share beside one CPU-bound process on
2 cores is 50 %.

Settings: torch threads (1 or 2) x OMP_WAIT_POLICY (the default, which spins, or
PASSIVE, which sleeps). No target yet: it is the evidence for choosing the
defaults (issue 22, item 3); the figures are in docs/performance.md.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time

MEASURE = r"""
import sys, time
import numpy as np
import torch
torch.set_num_threads(int(sys.argv[1]))
from eqhrl_ros.core.learner import EQSACLearner, LearnerConfig
learner = EQSACLearner(3, np.array([-2.0], np.float32), np.array([2.0], np.float32),
                       LearnerConfig(hidden=(int(sys.argv[3]),) * 2, batch_size=int(sys.argv[4]),
                                     learning_starts=10**9))
rng = np.random.default_rng(0)
for i in range(2000):
    learner.replay.add(rng.normal(size=3), [0.1], -1.0, rng.normal(size=3), False)
    if i % 20 == 0:
        learner.advice_replay.add(rng.normal(size=3), [0.1], -1.0, rng.normal(size=3), False)
for _ in range(20):
    learner.update()
seconds, n, start = float(sys.argv[2]), 0, time.perf_counter()
while time.perf_counter() - start < seconds:
    learner.update()
    n += 1
print(n / (time.perf_counter() - start))
"""

SETTINGS = [(threads, policy) for threads in (2, 1) for policy in ('default', 'PASSIVE')]


def measure(threads: int, policy: str, seconds: float, hidden: int, batch: int) -> float:
    env = {k: v for k, v in os.environ.items() if k != 'OMP_WAIT_POLICY'}
    if policy != 'default':
        env['OMP_WAIT_POLICY'] = policy
    command = [sys.executable, '-c', MEASURE, str(threads), str(seconds), str(hidden), str(batch)]
    out = subprocess.run(command, env=env, check=True, capture_output=True, text=True).stdout
    return float(out.strip().splitlines()[-1])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--seconds', type=float, default=6.0, help='timed seconds per measurement')
    parser.add_argument('--rounds', type=int, default=3)
    parser.add_argument('--hidden', type=int, default=64, help='width of both hidden layers (Table 1: 256)')
    parser.add_argument('--batch', type=int, default=128, help='batch size (Table 1 runs: 256)')
    args = parser.parse_args()
    quiet = {s: [] for s in SETTINGS}
    busy = {s: [] for s in SETTINGS}
    for round_index in range(args.rounds):
        order = SETTINGS if round_index % 2 == 0 else SETTINGS[::-1]
        for setting in order:
            quiet[setting].append(measure(*setting, args.seconds, args.hidden, args.batch))
        hog = subprocess.Popen([sys.executable, '-c', 'while True: pass'])
        try:
            time.sleep(0.5)
            for setting in order:
                busy[setting].append(measure(*setting, args.seconds, args.hidden, args.batch))
        finally:
            hog.kill()
            hog.wait()
    print(
        f'EQSAC updates per second, {args.hidden}x{args.hidden}, batch {args.batch}; median of {args.rounds} '
        'rounds; busy = one CPU-bound process beside it on this machine'
    )
    print(f'{"torch threads":>13s} {"OMP_WAIT_POLICY":>16s} {"quiet":>8s} {"busy":>8s} {"busy/quiet":>11s}')
    for setting in SETTINGS:
        q, b = statistics.median(quiet[setting]), statistics.median(busy[setting])
        print(f'{setting[0]:>13d} {setting[1]:>16s} {q:8.1f} {b:8.1f} {b / q:10.0%}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
