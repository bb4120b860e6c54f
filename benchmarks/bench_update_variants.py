"""What compilation and bfloat16 matrix products would buy the learner's update (issue 8).

    make bench-variants    # or: .venv/bin/python benchmarks/bench_update_variants.py [--rounds 6]

Evidence for a decision on target 1 (2.5x / 2x Stable-Baselines3), not a target check:
the shipped learner misses it, and `make bench-learner` shows that even the float32
matrix products alone take most of the time the target allows. This script measures
the two levers left that keep the code in PyTorch:

- compiled: the learner's three loss functions (``_targets``, ``_critic_loss``,
  ``_actor_loss``: every forward pass of an update) through ``torch.compile``, which fuses
  the element-wise work of the forward and backward passes into generated C++ loops;
- bfloat16: the same functions under ``torch.autocast('cpu', torch.bfloat16)``, so that
  the matrix products run in bfloat16 (float32 accumulation; twice the float32 rate on
  CPUs with AVX512-BF16 or AMX). Weights, gradients and Adam stay float32. This changes
  the arithmetic, so learning would have to be shown unchanged over seeds first.

Copies of one learner (same seed, same replay contents) run ``update()`` in turns, over
interleaved rounds, so that a machine that speeds up or slows down does so for all. Prints
the median time per update, each variant's speed-up over the shipped float32 eager update,
the compile warm-up, and how far each variant's first losses are from the shipped ones.
"""

from __future__ import annotations

import argparse
import copy
import statistics
import time

import numpy as np
import torch

from eqhrl_ros.core import EQSACLearner, LearnerConfig, make_env

LOSS_FUNCTIONS = ('_targets', '_critic_loss', '_actor_loss')
VARIANTS = {  # name: (compiled, bfloat16)
    'float32 eager (shipped)': (False, False),
    'float32 compiled': (True, False),
    'bfloat16 eager': (False, True),
    'bfloat16 compiled': (True, True),
}


def in_bfloat16(fn):
    """fn under CPU autocast to bfloat16, its tensor results returned as float32."""

    def wrapped(*args):
        with torch.autocast('cpu', dtype=torch.bfloat16):
            result = fn(*args)
        if isinstance(result, tuple):
            return tuple(r.float() for r in result)
        return result.float()

    return wrapped


def filled_learner(env_id: str, mode: str, transitions: int) -> EQSACLearner:
    """A learner whose D holds ``transitions`` random-action transitions, and D_advising every 10th."""
    env = make_env(env_id)
    learner = EQSACLearner(
        int(np.prod(env.observation_space.shape)),
        env.action_space.low,
        env.action_space.high,
        LearnerConfig(mode=mode, learning_starts=10**9, seed=0),
    )
    env.action_space.seed(0)
    obs, _ = env.reset(seed=0)
    for i in range(transitions):
        action = env.action_space.sample()
        next_obs, reward, terminated, truncated, _ = env.step(action)
        learner.step(obs, action, reward, next_obs, terminated, truncated, advised=(i % 10 == 0))
        obs = env.reset()[0] if terminated or truncated else next_obs
    return learner


def make_variant(learner: EQSACLearner, compiled: bool, bfloat16: bool) -> EQSACLearner:
    learner = copy.deepcopy(learner)
    for name in LOSS_FUNCTIONS:
        fn = getattr(learner, name)
        if bfloat16:
            fn = in_bfloat16(fn)
        if compiled:
            fn = torch.compile(fn)
        setattr(learner, name, fn)
    return learner


def compare(env_id: str, mode: str, args) -> dict:
    base = filled_learner(env_id, mode, args.transitions)
    learners, warmup_s, first = {}, {}, {}
    for name, (compiled, bfloat16) in VARIANTS.items():
        learners[name] = make_variant(base, compiled, bfloat16)
        start = time.perf_counter()
        first[name] = learners[name].update()  # compiles, if compiled
        warmup_s[name] = time.perf_counter() - start
        for _ in range(4):
            learners[name].update()
    ms = {name: [] for name in VARIANTS}
    for _ in range(args.rounds):
        for name, learner in learners.items():
            start = time.perf_counter()
            for _ in range(args.round_updates):
                learner.update()
            ms[name].append((time.perf_counter() - start) / args.round_updates * 1e3)

    shipped = next(iter(VARIANTS))
    print(f'\n{env_id}, {mode}: ms per update (median of {args.rounds} rounds of {args.round_updates})')
    print(f'  {"variant":26s} {"ms":>7s} {"speed-up":>9s} {"first update":>13s} {"critic loss vs shipped":>23s}')
    speedups = {}
    for name in VARIANTS:
        speedups[name] = statistics.median(a / b for a, b in zip(ms[shipped], ms[name]))
        drift = abs(first[name]['critic_loss'] / first[shipped]['critic_loss'] - 1.0)
        print(
            f'  {name:26s} {statistics.median(ms[name]):7.2f} {speedups[name]:8.2f}x '
            f'{warmup_s[name]:11.1f} s {drift:22.1e}'
        )
    return speedups


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--rounds', type=int, default=6)
    parser.add_argument('--round-updates', type=int, default=40)
    parser.add_argument('--transitions', type=int, default=2000)
    parser.add_argument('--threads', type=int, default=2)
    parser.add_argument('--envs', nargs='+', default=['Pendulum-v1', 'LunarLanderContinuous-v3'])
    parser.add_argument('--modes', nargs='+', default=['sac', 'eqsac'])
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    print(
        f'torch {torch.__version__}, {args.threads} threads, CPU capability {torch.backends.cpu.get_cpu_capability()}'
    )
    for env_id in args.envs:
        for mode in args.modes:
            compare(env_id, mode, args)
    print(
        '\nfirst update: torch.compile compiles once per process; later compiled variants of the '
        'same functions reuse that work, so only the first shows the compile time.'
    )
    print(
        'A speed-up s of the update alone moves a step of u ms update and o ms other work by '
        'a factor (u + o) / (u / s + o); see the README for what that means for target 1.'
    )
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
