"""Where a training step's time goes, part by part, for SAC and EQSAC side by side (issue 48).

    .venv/bin/python benchmarks/split_step.py [--env Pendulum-v1] [--compile] [--rounds 6] [--steps 150]

One learner per mode (sac, qasac, eqsac: the same seed, Table 1 sizes), each filled for --warmup
steps without updates, D_advising filled by the heuristic expert inside the advising budget, and
with --compile its whole update compiled before timing, in the same thread (the program that
compile_update: true runs). Then in interleaved rounds (the modes take turns, so that a machine
that speeds up or slows down does so for all), each mode's steps are timed part by part with
time.perf_counter around:

- propose: the action, D(s), E(s) and the gates (learner.propose);
- expert: the heuristic expert's answer when the gates fire;
- env: env.step;
- store: learner.count_step (D, and D_advising when advised);
- sample: memories.sample (the batch from D and, for EQSAC, the one from D_advising);
- noise: the update's noise (updater.noise_for);
- update: algorithm1_update, compiled or eager, to its losses as floats (Updater.run: compiled, the
  program then acts ahead on the next observation, which propose takes: acting_ahead.py).

Then, in each round, the same learner's propose, sampling and update called back to back on one
input ("alone"): what each part costs without the loop's other parts between its calls.

Prints the median ms per step of each part and mode, and each mode's total and its ratio to
SAC's speed; also, timed alone in the same rounds, the two products that bound an update (a
256x256x256 float32 matrix product). Evidence, no target, no exit code.
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
from bench_learner import openmp_spin

from eqhrl_ros.core import EQSACLearner, LearnerConfig, heuristic_expert, make_env, run_episode
from eqhrl_ros.core.algorithm import cpu_threads

PARTS = ('propose', 'expert', 'env', 'store', 'sample', 'noise', 'update')


def make(env_id: str, mode: str, args) -> tuple:
    env = make_env(env_id, max_episode_steps=200)
    learner = EQSACLearner(
        int(np.prod(env.observation_space.shape)),
        env.action_space.low,
        env.action_space.high,
        LearnerConfig(mode=mode, learning_starts=args.warmup, advising_budget=10**6, seed=0),
    )
    expert = heuristic_expert(env_id)
    while learner.total_steps < args.warmup:
        run_episode(env, learner, expert, seed=0)
    run_episode(env, learner, expert)  # updates begin
    # The gates seldom fire before learning (no request in the first 1,200 steps of Pendulum):
    # episodes go on, up to 20, until D_advising holds an answer, so that EQSAC's updates are
    # timed with their second critic step from the first round.
    for _ in range(20):
        if mode == 'sac' or len(learner.advice_replay) > 0:
            break
        run_episode(env, learner, expert)
    if args.compile:  # compiled here, in this thread: nothing compiles while the rounds are timed
        compiled = learner.start_compiling(background=False)
        assert compiled is not None and compiled.ready, 'the update did not compile'
    return env, learner, expert


def timed_round(env, learner, expert, steps: int, obs) -> tuple:
    parts: dict = defaultdict(float)
    clock = time.perf_counter
    updater, memories = learner.updater, learner.memories
    for _ in range(steps):
        t0 = clock()
        proposal = learner.propose(obs)
        t1 = clock()
        if proposal.decision.fire:
            action, advised = learner.resolve_advice(proposal, expert(proposal.request)).action_and_advised()
        else:
            action, advised = proposal.action, False
        t2 = clock()
        next_obs, reward, terminated, truncated, _ = env.step(action)
        t3 = clock()
        learner.count_step(obs, action, reward, next_obs, terminated, advised, None, store=True)
        t4 = clock()
        batch, advice = memories.sample()
        t5 = clock()
        noise = updater.noise_for(batch, advice)
        t6 = clock()
        losses = updater.run(batch, advice, noise, learner.observation.tensor(next_obs))
        {name: float(value) for name, value in losses.items()}
        t7 = clock()
        for name, (a, b) in zip(PARTS, ((t0, t1), (t1, t2), (t2, t3), (t3, t4), (t4, t5), (t5, t6), (t6, t7))):
            parts[name] += b - a
        if terminated or truncated:
            learner.end_episode()
            obs = env.reset()[0]
        else:
            obs = next_obs
    return {name: 1e3 * value / steps for name, value in parts.items()}, obs


def alone_round(learner, obs, calls: int = 50) -> dict:
    """ms per call of propose, of sampling and of the update, each called back to back on the
    same input (no env step, no other part between calls): beside the loop's figures, what the
    loop's interleaving costs each part (caches, the threads' wake-ups)."""
    updater, clock, out = learner.updater, time.perf_counter, {}
    batch, advice = learner.memories.sample()
    noise = updater.noise_for(batch, advice)
    obs_t = learner.observation.tensor(obs)
    for name, call in (
        ('propose', lambda: learner.propose(obs)),
        ('sample', learner.memories.sample),
        ('update', lambda: updater.run(batch, advice, noise, obs_t)),
    ):
        call()
        start = clock()
        for _ in range(calls):
            call()
        out[name] = 1e3 * (clock() - start) / calls
    return out


def product_ms(repeats: int = 50) -> float:
    a, b = torch.randn(256, 256), torch.randn(256, 256)
    for _ in range(5):
        a @ b
    start = time.perf_counter()
    for _ in range(repeats):
        a @ b
    return 1e3 * (time.perf_counter() - start) / repeats


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--env', default='Pendulum-v1')
    parser.add_argument('--modes', nargs='+', default=['sac', 'qasac', 'eqsac'])
    parser.add_argument('--compile', action='store_true')
    parser.add_argument('--warmup', type=int, default=1000)
    parser.add_argument('--rounds', type=int, default=6)
    parser.add_argument('--steps', type=int, default=150)
    parser.add_argument('--threads', type=int, default=2)
    args = parser.parse_args()
    cpu_threads.fix(args.threads)  # fixed: side by side, no contender's threads count as a crowd
    contenders = {mode: make(args.env, mode, args) for mode in args.modes}
    observations = {mode: env.reset(seed=1)[0] for mode, (env, _, _) in contenders.items()}
    rounds: dict = {mode: [] for mode in args.modes}
    alone: dict = {mode: [] for mode in args.modes}
    products = []
    for _ in range(args.rounds):
        for mode, (env, learner, expert) in contenders.items():
            parts, observations[mode] = timed_round(env, learner, expert, args.steps, observations[mode])
            rounds[mode].append(parts)
            alone[mode].append(alone_round(learner, observations[mode]))
        products.append(product_ms())
    path = 'compiled' if args.compile else 'eager'
    print(
        f'{args.env}, {path}, {args.threads} threads, OpenMP spin {openmp_spin()}, '
        f'{args.rounds} x {args.steps} steps per mode, interleaved'
    )
    print(f'one 256x256x256 float32 product alone: {statistics.median(products):.3f} ms (median of rounds)')
    print(f'{"part (ms per step)":22s}' + ''.join(f'{mode:>9s}' for mode in args.modes))
    totals = {mode: statistics.median(sum(r.values()) for r in rounds[mode]) for mode in args.modes}
    for name in PARTS:
        print(f'{name:22s}' + ''.join(f'{statistics.median(r[name] for r in rounds[m]):9.3f}' for m in args.modes))
    print(f'{"total":22s}' + ''.join(f'{totals[m]:9.3f}' for m in args.modes))
    for name in ('propose', 'sample', 'update'):
        print(
            f'{name + ", alone":22s}'
            + ''.join(f'{statistics.median(r[name] for r in alone[m]):9.3f}' for m in args.modes)
        )
    if 'sac' in totals:
        print(f'{"speed vs SAC":22s}' + ''.join(f'{totals["sac"] / totals[m]:9.2f}' for m in args.modes))


if __name__ == '__main__':
    main()
