"""Env steps per second with one update per step: our learner vs Stable-Baselines3's SAC.

    make bench            # or: .venv/bin/python benchmarks/bench_learner.py [--steps 1500]

Same process, same sizes (Table 1: 256x256, batch 256), same thread count. Each
run first fills the replay memory for --warmup steps without updates (not timed),
then times --steps env steps, each followed by one gradient update. EQSAC runs
inside its advising budget with the heuristic expert, so it also pays for D(s),
E(s) and the second critic step on the advice batch.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from eqhrl_ros.core import EQSACLearner, LearnerConfig, heuristic_expert, make_env, run_episode

ENVS = ('Pendulum-v1', 'LunarLanderContinuous-v3')


def ours(env_id: str, mode: str, warmup: int, steps: int) -> float:
    env = make_env(env_id)
    config = LearnerConfig(mode=mode, learning_starts=warmup, advising_budget=10**6, seed=0)
    learner = EQSACLearner(int(np.prod(env.observation_space.shape)), env.action_space.low,
                           env.action_space.high, config)
    expert = heuristic_expert(env_id)
    while learner.total_steps < warmup:
        run_episode(env, learner, expert, seed=0)
    start_steps, start = learner.total_steps, time.perf_counter()
    while learner.total_steps - start_steps < steps:
        run_episode(env, learner, expert)
    elapsed = time.perf_counter() - start
    env.close()
    return (learner.total_steps - start_steps) / elapsed


def sb3(env_id: str, warmup: int, steps: int) -> float:
    from stable_baselines3 import SAC
    from stable_baselines3.common.callbacks import BaseCallback

    class Clock(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps == warmup:
                self.start = time.perf_counter()
            return True

    env = make_env(env_id)
    model = SAC('MlpPolicy', env, learning_rate=3e-4, buffer_size=500_000, learning_starts=warmup,
                batch_size=256, train_freq=1, gradient_steps=1, policy_kwargs={'net_arch': [256, 256]},
                seed=0, device='cpu', verbose=0)
    clock = Clock()
    model.learn(total_timesteps=warmup + steps, callback=clock)
    elapsed = time.perf_counter() - clock.start
    env.close()
    return steps / elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--steps', type=int, default=1500)
    parser.add_argument('--warmup', type=int, default=1000)
    parser.add_argument('--threads', type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    print(f'torch {torch.__version__}, {args.threads} threads, {args.steps} timed steps after {args.warmup}')
    print(f"{'env':28s} {'learner':14s} {'steps/s':>8s} {'vs SB3':>7s}")
    for env_id in ENVS:
        reference = sb3(env_id, args.warmup, args.steps)
        print(f"{env_id:28s} {'SB3 SAC':14s} {reference:8.1f} {1.0:7.2f}", flush=True)
        for mode in ('sac', 'eqsac'):
            rate = ours(env_id, mode, args.warmup, args.steps)
            print(f'{env_id:28s} {"ours " + mode:14s} {rate:8.1f} {rate / reference:7.2f}', flush=True)


if __name__ == '__main__':
    main()
