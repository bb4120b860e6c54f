"""Many seeds in one process: seed-steps per second, seeds together vs apart.

    make bench-seeds     # or: .venv/bin/python benchmarks/bench_seeds.py [--steps 60 --curve 1 2 5 10 20]

Every figure is env steps of all seeds per second of wall time while learning (one update
per env step after --warmup steps without updates; the warm-up is not timed), EQSAC at
Table 1's sizes (256x256, batch 256) inside its advising budget with the heuristic expert.

- apart: today's runner, eqhrl-experiment --seeds-apart: --processes processes, one
  torch thread each, each running its share of the seeds one after the other;
- together: the seeds in one process (core/algorithm/stacked_seeds.py), with --processes torch threads;
- together x P: the seeds split over --processes processes of one thread each, each
  process running its share together (what eqhrl-experiment does by default);
- with --compiled, also apart compiled: apart with compile_update on (compiled_update.py),
  at the target's N only; printed beside the target, not counted in it (the target is
  about running seeds together).

The contenders are measured one after the other on the same machine, so run it on a quiet
one. Prints the curve for N seeds together and each target's figure beside its anchor
(10 seeds: together >= 2x apart on Pendulum-v1, >= 1.5x on LunarLanderContinuous-v3);
exits 1 on a miss. Before timing, checks that one seed's update together equals its lone
update (float tolerance).
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import sys
import time

TARGETS = {'Pendulum-v1': 2.0, 'LunarLanderContinuous-v3': 1.5}


SIZES = {'hidden': (256, 256), 'batch_size': 256}  # Table 1; --hidden and --batch change them


def _make(env_id: str, seed: int, warmup: int, budget: int, sizes: dict = SIZES, compiled: bool = False):
    from eqhrl_ros.core import EQSACLearner, LearnerConfig, make_env

    env = make_env(env_id)
    config = LearnerConfig(
        mode='eqsac', seed=seed, learning_starts=warmup, advising_budget=budget, compile_update=compiled, **sizes
    )
    learner = EQSACLearner(env.observation_space.shape[0], env.action_space.low, env.action_space.high, config)
    return env, learner


def _seeds_apart(env_id, seeds, args, barrier, results, compiled: bool = False) -> None:
    """One process of today's runner: its seeds one after the other, one update per step
    (``compiled``: with compile_update, compiled before timing)."""
    import torch

    from eqhrl_ros.core import heuristic_expert
    from eqhrl_ros.core.runs.in_process import _Acting

    torch.set_num_threads(1)
    loops = []
    for seed in seeds:  # every seed warmed up first, so that only learning is timed
        env, learner = _make(env_id, seed, args.warmup, 10**6, args.sizes, compiled)
        acting = _Acting(env, learner, heuristic_expert(env_id))
        acting.reset(seed)
        loops.append((acting, learner))
        for _ in range(args.warmup + (2 if compiled else 0)):  # the first update starts the compiler
            _step_alone(acting, learner)
    for _, learner in loops:
        if compiled and not learner.compiled_update.wait(timeout=900):
            raise RuntimeError(f'compile_update failed: {learner.compiled_update.failed}')
    barrier.wait()
    start = time.perf_counter()
    for acting, learner in loops:
        for _ in range(args.steps):
            _step_alone(acting, learner)
    results.put(time.perf_counter() - start)


def _step_alone(acting, learner) -> None:
    obs, action, reward, next_obs, terminated, truncated, advised = acting.act()
    if learner.step(obs, action, reward, next_obs, terminated, truncated, advised) is not None:
        acting.reset()


def _seeds_together(env_id, seeds, threads, args, barrier, results) -> None:
    """One process with its seeds together (core/runs/in_process.StackedSeedRuns)."""
    import torch

    from eqhrl_ros.core import heuristic_expert
    from eqhrl_ros.core.runs.in_process import SeedRun, StackedSeedRuns

    torch.set_num_threads(threads)
    runs = []
    for seed in seeds:
        env, learner = _make(env_id, seed, args.warmup, 10**6, args.sizes)
        runs.append(SeedRun(env, learner, heuristic_expert(env_id), seed))
    together = StackedSeedRuns(runs, episodes=10**9)
    for _ in range(args.warmup):
        together.step()
    barrier.wait()
    start = time.perf_counter()
    for _ in range(args.steps):
        together.step()
    results.put(time.perf_counter() - start)
    together.close()


def measure(kind: str, env_id: str, n: int, args) -> float:
    """Seed-steps per second of n seeds, ``kind`` 'apart', 'apart compiled', 'together' or 'together xP'."""
    context = mp.get_context('spawn')
    processes = args.processes if kind != 'together' else 1
    shares = [list(range(n))[i::processes] for i in range(processes)]
    shares = [share for share in shares if share]
    barrier, results = context.Barrier(len(shares)), context.Queue()
    workers = []
    for share in shares:
        options = {}
        if kind.startswith('apart'):
            target, extra, options = _seeds_apart, (), {'compiled': kind == 'apart compiled'}
        else:
            target, extra = _seeds_together, (args.processes if kind == 'together' else 1,)
        workers.append(
            context.Process(target=target, args=(env_id, share, *extra, args, barrier, results), kwargs=options)
        )
    for worker in workers:
        worker.start()
    seconds = [results.get() for _ in workers]
    for worker in workers:
        worker.join()
        if worker.exitcode != 0:
            raise RuntimeError(f'{kind} {env_id} n={n}: a worker exited with {worker.exitcode}')
    return n * args.steps / max(seconds)


def check_equal(env_id: str) -> float:
    """Largest weight difference between two seeds updated alone and together (200 updates)."""
    import torch

    from eqhrl_ros.core.algorithm.stacked_seeds import StackedSeeds

    torch.set_num_threads(1)
    alone, together = [], []
    for seed in (0, 1):
        for group in (alone, together):
            env, learner = _make(env_id, seed, 1, 10**6)
            obs, _ = env.reset(seed=seed)
            env.action_space.seed(seed)
            for step in range(300):
                action = env.action_space.sample()
                next_obs, reward, terminated, truncated, _ = env.step(action)
                learner.store(obs, learner.normalize(action), reward, next_obs, terminated, advised=step % 5 == 0)
                obs = env.reset()[0] if terminated or truncated else next_obs
            group.append(learner)
    batch = StackedSeeds(together)
    for _ in range(200):
        for learner in alone:
            learner.update()
        batch.update()
    batch.release()
    return max(
        float((a - b).abs().max())
        for x, y in zip(alone, together)
        for a, b in zip(x.actor.state_dict().values(), y.actor.state_dict().values())
    )


# 256x256x256 matrix products in one EQSAC update at Table 1's sizes (bench_learner.PRODUCTS).
EQSAC_PRODUCTS = 25


def product_floor(processes: int, size: int = 256) -> float:
    """Seed-steps per second if an update cost only its size^3 matrix products, on ``processes``
    cores of one thread: the most any way of running the seeds can reach (float32)."""
    import torch

    torch.set_num_threads(1)
    a, b = torch.randn(size, size), torch.randn(size, size)
    for _ in range(30):
        a @ b
    start = time.perf_counter()
    for _ in range(300):
        a @ b
    product_s = (time.perf_counter() - start) / 300
    return processes / (EQSAC_PRODUCTS * product_s)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--envs', nargs='+', default=list(TARGETS))
    parser.add_argument('--seeds', type=int, default=10, help='seeds of the target figure')
    parser.add_argument('--curve', nargs='+', type=int, default=[1, 2, 5, 10, 20], help='N of the curve')
    parser.add_argument('--steps', type=int, default=40, help='timed env steps per seed')
    parser.add_argument('--warmup', type=int, default=300, help='env steps per seed before updates (not timed)')
    parser.add_argument('--processes', type=int, default=2, help='processes (and threads) of the contenders')
    parser.add_argument('--hidden', type=int, default=256, help='width of both hidden layers (Table 1: 256)')
    parser.add_argument('--batch', type=int, default=256, help='batch size (Table 1: 256)')
    parser.add_argument('--no-targets', action='store_true', help='print figures only (exit 0)')
    parser.add_argument('--compiled', action='store_true', help='also time the seeds apart with compile_update')
    args = parser.parse_args(argv)
    args.sizes = {'hidden': (args.hidden, args.hidden), 'batch_size': args.batch}

    missed = []
    for env_id in args.envs:
        difference = check_equal(env_id)
        print(f'{env_id}: after 200 updates, largest actor weight difference alone vs together: {difference:.1e}')
        print(
            f'\n{env_id}, EQSAC, hidden {args.hidden}x{args.hidden}, batch {args.batch}: '
            f'seed-steps per second ({args.steps} timed steps per seed)'
        )
        print(f'{"N":>3} {"apart":>8} {"together":>9} {"x" + str(args.processes) + " proc":>8} {"best/apart":>10}')
        figures = {}
        for n in sorted(set(args.curve) | {args.seeds}):
            apart = measure('apart', env_id, n, args)
            one = measure('together', env_id, n, args)
            split = measure('together xP', env_id, n, args) if n >= args.processes else float('nan')
            best = max(one, split) if split == split else one
            figures[n] = (apart, best)
            print(f'{n:>3} {apart:8.1f} {one:9.1f} {split:8.1f} {best / apart:10.2f}', flush=True)
        apart, best = figures[args.seeds]
        if args.hidden == 256 and args.batch == 256:
            floor = product_floor(args.processes)
            print(
                f'floor: the 256^3 matrix products alone on {args.processes} cores allow {floor:.1f} seed-steps/s, '
                f'{floor / apart:.2f}x apart'
            )
        target = TARGETS.get(env_id)
        if target is not None:
            verdict = 'met' if best / apart >= target else 'MISSED'
            print(
                f'target: {args.seeds} seeds together {best:.1f} seed-steps/s vs apart {apart:.1f}: '
                f'{best / apart:.2f}x (anchor {target}x) {verdict}'
            )
            if best / apart < target:
                missed.append(env_id)
        if args.compiled:
            fast = measure('apart compiled', env_id, args.seeds, args)
            print(f'{args.seeds} seeds apart with compile_update: {fast:.1f} seed-steps/s, {fast / apart:.2f}x apart')
    return 1 if missed and not args.no_targets else 0


if __name__ == '__main__':
    sys.exit(main())
