"""What the exact E(s) costs on the acting path, against the K = 32 Monte Carlo estimate.

    .venv/bin/python benchmarks/bench_entropy.py [--rounds 6] [--steps 2000]

One EQSAC learner per estimator (same seed, same weights), Pendulum-v1 and
LunarLanderContinuous-v3 at Table 1 sizes; each round times ``propose()`` (the action,
D(s), E(s) and the gates: everything an env step waits for) over the same observations,
the estimators in turn, so that a machine that speeds up or slows down does so for both.
Also times E(s) alone for a trained-looking policy (every std <= 1, one quadrature rule)
and an untrained-looking one (std > 1 in every dimension: both rules). Prints medians over
rounds and the ratio exact / monte_carlo. Evidence, no target.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import torch

from eqhrl_ros.core import EQSACLearner, LearnerConfig
from eqhrl_ros.core.algorithm import equations as eq
from eqhrl_ros.core.envs.gymnasium_envs import gym_spec

ESTIMATORS = ('exact', 'monte_carlo')


def time_propose(learner: EQSACLearner, observations: np.ndarray) -> float:
    start = time.perf_counter()
    for obs in observations:
        learner.propose(obs)
    return (time.perf_counter() - start) / len(observations)


def time_entropy(estimator: str, mean: torch.Tensor, log_std: torch.Tensor, calls: int) -> float:
    noise = torch.randn((32, *mean.shape))
    with torch.inference_mode():
        start = time.perf_counter()
        for _ in range(calls):
            if estimator == 'exact':
                eq.policy_entropy(mean, log_std)
            else:
                eq.policy_entropy_monte_carlo(mean, log_std, noise)
        return (time.perf_counter() - start) / calls


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--rounds', type=int, default=6)
    parser.add_argument('--steps', type=int, default=2000)
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(f'torch {torch.__version__}, 1 thread, {args.rounds} rounds, medians')
    for env_id in ('Pendulum-v1', 'LunarLanderContinuous-v3'):
        spec = gym_spec(env_id)
        learners = {
            name: EQSACLearner(
                spec.observation_size,
                spec.action_low,
                spec.action_high,
                LearnerConfig(mode='eqsac', entropy_estimator=name, advising_budget=10**6),
            )
            for name in ESTIMATORS
        }
        rng = np.random.default_rng(0)
        observations = rng.uniform(-1.0, 1.0, (args.steps, spec.observation_size)).astype(np.float32)
        times = {name: [] for name in ESTIMATORS}
        for _ in range(args.rounds):
            for name in ESTIMATORS:
                times[name].append(time_propose(learners[name], observations))
        med = {name: statistics.median(t) * 1e6 for name, t in times.items()}
        print(
            f'{env_id:26s} propose(): exact {med["exact"]:6.1f} us, monte_carlo K=32 {med["monte_carlo"]:6.1f} us, '
            f'ratio {med["exact"] / med["monte_carlo"]:.2f}x'
        )
        m = len(spec.action_low)
        for label, log_std in (('std <= 1', -1.0), ('std > 1', 1.5)):
            mean, ls = torch.zeros(1, m), torch.full((1, m), log_std)
            alone = {name: [] for name in ESTIMATORS}
            for _ in range(args.rounds):
                for name in ESTIMATORS:
                    alone[name].append(time_entropy(name, mean, ls, args.steps))
            e = {name: statistics.median(t) * 1e6 for name, t in alone.items()}
            print(
                f'{"":26s} E(s) alone, {label}: exact {e["exact"]:6.1f} us, monte_carlo {e["monte_carlo"]:6.1f} us, '
                f'ratio {e["exact"] / e["monte_carlo"]:.2f}x'
            )


if __name__ == '__main__':
    main()
