"""Learning before and after the speed work: same returns within noise over seeds.

    .venv/bin/python benchmarks/learning_unchanged.py --before /tmp/old/eqhrl_ros [--seeds 0 1 2]

--before is the eqhrl_ros package folder of the code to compare with, e.g. from
`git archive 7e12bad eqhrl_ros/eqhrl_ros | tar -x -C /tmp/old`. Each (code, mode, seed)
trains in its own process, 2 at a time, with the learning smoke test's small setting
(Pendulum-v1, 64x64, batch 128, 60 episodes of 100 steps). Prints the mean return of
the first and last 10 episodes per run, and the mean and spread over seeds.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

RUN = """
import sys, numpy as np, torch
torch.set_num_threads(1)
from eqhrl_ros.core import EQSACLearner, LearnerConfig, make_env, success_criterion, train, heuristic_expert
mode, seed = sys.argv[1], int(sys.argv[2])
env = make_env('Pendulum-v1')
config = LearnerConfig(mode=mode, hidden=(64, 64), batch_size=128, learning_starts=500, actor_lr=1e-3,
                       critic_lr=1e-3, alpha_lr=1e-3, advising_budget=20, seed=seed)
learner = EQSACLearner(3, env.action_space.low, env.action_space.high, config, success_criterion('Pendulum-v1'))
returns = [s.episode_return for s in train(env, learner, 60, heuristic_expert('Pendulum-v1'), seed=seed)]
print(' '.join(f'{r:.3f}' for r in returns))
"""


def run(code: str, mode: str, seed: int) -> np.ndarray:
    env = dict(os.environ, PYTHONPATH=code)
    out = subprocess.run(
        [sys.executable, '-c', RUN, mode, str(seed)], env=env, check=True, capture_output=True, text=True
    ).stdout
    return np.array([float(x) for x in out.split()])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--before', required=True, help='eqhrl_ros package folder of the earlier code')
    parser.add_argument('--after', default=str(Path(__file__).resolve().parents[1] / 'eqhrl_ros'))
    parser.add_argument('--seeds', type=int, nargs='+', default=[0, 1, 2])
    parser.add_argument('--modes', nargs='+', default=['sac', 'eqsac'])
    args = parser.parse_args()
    jobs = [(code, mode, seed) for mode in args.modes for seed in args.seeds for code in ('before', 'after')]
    with ThreadPoolExecutor(2) as pool:
        results = dict(zip(jobs, pool.map(lambda j: run(getattr(args, j[0]), j[1], j[2]), jobs)))
    print(
        f'{"mode":6s} {"code":7s} ' + ' '.join(f'seed {s:<13d}' for s in args.seeds) + '  last 10, mean ± sd over seeds'
    )
    for mode in args.modes:
        for code in ('before', 'after'):
            runs = [results[(code, mode, s)] for s in args.seeds]
            last = np.array([r[-10:].mean() for r in runs])
            cells = ' '.join(f'{r[:10].mean():7.1f}→{r[-10:].mean():6.1f}' for r in runs)
            print(f'{mode:6s} {code:7s} {cells}  {last.mean():7.1f} ± {last.std(ddof=1):.1f}')


if __name__ == '__main__':
    main()
