"""Where a training step's time goes: torch.profiler's top operators for the in-process loop.

    .venv/bin/python benchmarks/profile_learner.py [--env Pendulum-v1] [--mode eqsac] [--steps 200]

Fills the replay memory without updates, then profiles --steps env steps of the
in-process loop (propose, the expert when the gates fire, env.step, store, one
update), the benchmark's setting. Prints the wall time per step, then the top
operators by self CPU time; docs/profile.md keeps the before/after tables.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from torch.profiler import ProfilerActivity, profile

from eqhrl_ros.core import EQSACLearner, LearnerConfig, heuristic_expert, make_env, run_episode
from eqhrl_ros.core.algorithm import cpu_threads
from eqhrl_ros.core.algorithm.config import MODES


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--env', default='Pendulum-v1')
    parser.add_argument('--mode', default='eqsac', choices=MODES)
    parser.add_argument('--warmup', type=int, default=1000)
    parser.add_argument('--steps', type=int, default=200)
    parser.add_argument('--threads', type=int, default=2)
    parser.add_argument('--rows', type=int, default=15)
    args = parser.parse_args()
    cpu_threads.fix(args.threads)  # fixed: side by side, no contender's threads count as a crowd

    env = make_env(args.env, max_episode_steps=args.steps + 1)
    learner = EQSACLearner(
        int(np.prod(env.observation_space.shape)),
        env.action_space.low,
        env.action_space.high,
        LearnerConfig(mode=args.mode, learning_starts=args.warmup, advising_budget=10**6, seed=0),
    )
    expert = heuristic_expert(args.env)
    while learner.total_steps < args.warmup:
        run_episode(env, learner, expert, seed=0)
    run_episode(env, learner, expert)  # one episode of updates before measuring

    def timed_steps() -> float:
        obs, _ = env.reset(seed=1)
        start = time.perf_counter()
        for _ in range(args.steps):
            proposal = learner.propose(obs)
            action, advised = (
                learner.resolve_advice(proposal, expert(proposal.request)).action_and_advised()
                if proposal.decision.fire
                else (proposal.action, False)
            )
            next_obs, reward, terminated, truncated, _ = env.step(action)
            learner.step(obs, action, reward, next_obs, terminated, truncated, advised)
            obs = next_obs if not (terminated or truncated) else env.reset()[0]
        return (time.perf_counter() - start) / args.steps

    plain = timed_steps()
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        profiled = timed_steps()
    print(
        f'{args.env} {args.mode}, {args.threads} threads: {plain * 1e3:.2f} ms per step '
        f'({profiled * 1e3:.2f} ms under the profiler), {args.steps} steps'
    )
    print(prof.key_averages().table(sort_by='self_cpu_time_total', row_limit=args.rows, max_name_column_width=40))


if __name__ == '__main__':
    main()
