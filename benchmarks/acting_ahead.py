"""What acting ahead inside the compiled update buys a training step, side by side (issue 48).

    .venv/bin/python benchmarks/acting_ahead.py [--env Pendulum-v1] [--rounds 16] [--steps 100]

One learner per mode (sac, eqsac: Table 1 sizes, EQSAC inside its budget with the heuristic
expert and D_advising filled), its update compiled before timing as compile_update: true runs it.
Each learner then runs Algorithm 1's loop (propose, the expert where asked, env.step,
learner.step) in three ways, taking turns within each round, in a new order each round:

- ahead: as shipped: the compiled program updates, then acts ahead on the next observation,
  and propose takes what it computed (core/algorithm/acting_ahead.py);
- not taken: the same program, but propose computes its acting eagerly (what acting ahead
  costs inside the program, paid for nothing);
- before: the update alone compiled (algorithm1_update, as before acting ahead existed), propose
  eager.

Prints, per mode, the median ms per env step, the median of propose's share of it, and the
median per-round ratio of each way's speed to "before". Evidence, no target, no exit code.
"""

from __future__ import annotations

import argparse
import random
import statistics
import time
import types

import eqhrl_ros  # noqa: F401 - first, as in a user's nodes (eqhrl_ros/__init__.py runs before torch loads)

# isort: split
from bench_learner import openmp_spin
from split_step import make

from eqhrl_ros.core.algorithm import compiled_update, cpu_threads
from eqhrl_ros.core.algorithm.update import algorithm1_update

WAYS = ('ahead', 'not taken', 'before')


def update_alone_compiled(updater):
    """Updater.run with algorithm1_update alone compiled (the program before acting ahead)."""
    original = algorithm1_update
    function = types.FunctionType(original.__code__.replace(), original.__globals__, 'a1', original.__defaults__)
    program = compiled_update.compile_program(function, updater.compiled.threads)

    def run(batch, advice, noise, next_obs=None):
        weights, state, constants = updater.inputs()
        updater.ahead.forget()
        return program(updater.nets, weights, state, batch.columns(), advice and advice.columns(), noise, constants)

    return run


def set_way(learner, way: str, before) -> None:
    updater = learner.updater
    for name in ('run', 'acted_ahead'):
        updater.__dict__.pop(name, None)  # the Updater's own methods
    if way != 'ahead':
        updater.acted_ahead = lambda obs_t: None
    if way == 'before':
        updater.run = before


def loop(env, learner, expert, obs, steps: int) -> tuple:
    """(ms per step, ms of it in propose, the next observation)."""
    clock, proposing = time.perf_counter, 0.0
    start = clock()
    for _ in range(steps):
        t0 = clock()
        proposal = learner.propose(obs)
        proposing += clock() - t0
        if proposal.decision.fire:
            action, advised = learner.resolve_advice(proposal, expert(proposal.request)).action_and_advised()
        else:
            action, advised = proposal.action, False
        next_obs, reward, terminated, truncated, _ = env.step(action)
        learner.step(obs, action, reward, next_obs, terminated, truncated, advised)
        obs = env.reset()[0] if terminated or truncated else next_obs
    return 1e3 * (clock() - start) / steps, 1e3 * proposing / steps, obs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--env', default='Pendulum-v1')
    parser.add_argument('--modes', nargs='+', default=['sac', 'eqsac'])
    parser.add_argument('--warmup', type=int, default=1000)
    parser.add_argument('--rounds', type=int, default=16)
    parser.add_argument('--steps', type=int, default=100)
    parser.add_argument('--threads', type=int, default=2)
    args = parser.parse_args()
    args.compile = True  # split_step.make's flag
    cpu_threads.fix(args.threads)
    contenders = {mode: make(args.env, mode, args) for mode in args.modes}
    befores, observations = {}, {}
    for mode, (env, learner, expert) in contenders.items():
        befores[mode] = update_alone_compiled(learner.updater)
        set_way(learner, 'before', befores[mode])
        observations[mode] = loop(env, learner, expert, env.reset(seed=1)[0], 3)[2]  # compiles it
    figures = {(mode, way): [] for mode in args.modes for way in WAYS}
    for _ in range(args.rounds):
        for mode, (env, learner, expert) in contenders.items():
            for way in random.sample(WAYS, len(WAYS)):
                set_way(learner, way, befores[mode])
                step, proposing, observations[mode] = loop(env, learner, expert, observations[mode], args.steps)
                figures[(mode, way)].append((step, proposing))
    print(
        f'{args.env}, compiled update, {args.threads} threads, OpenMP spin {openmp_spin()}, '
        f'{args.rounds} rounds x {args.steps} steps per way, interleaved'
    )
    print(f'{"mode":6s} {"way":10s} {"step ms":>8s} {"propose ms":>11s} {"speed vs before":>16s}')
    for mode in args.modes:
        before = [step for step, _ in figures[(mode, 'before')]]
        for way in WAYS:
            steps = [step for step, _ in figures[(mode, way)]]
            proposing = statistics.median(p for _, p in figures[(mode, way)])
            ratio = statistics.median(b / s for b, s in zip(before, steps))
            print(f'{mode:6s} {way:10s} {statistics.median(steps):8.3f} {proposing:11.3f} {ratio:15.3f}x')


if __name__ == '__main__':
    main()
