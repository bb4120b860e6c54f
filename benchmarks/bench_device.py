"""The learner on a GPU: the same loops on the CPU and on a torch device.

    .venv/bin/python benchmarks/bench_device.py                    # cpu only (what CI machines have)
    python benchmarks/bench_device.py --device cuda               # on a machine with a GPU

Nothing in the project needs a GPU: the learner takes ``device: cuda`` (LearnerConfig.device)
and this script measures what that buys. Table 1's sizes (256x256, batch 256), one update
per env step after --warmup steps without updates (not timed), EQSAC inside its advising
budget with the heuristic expert, so it also pays for D(s), E(s) and the second critic step.

Prints, for each env and mode, side by side in interleaved rounds on the same machine:
- env steps per second of one lone learner on the CPU (--threads torch threads) and on the device;
- milliseconds per update alone (the replay memory full, no env), median of --updates;
- with --compiled, the same with compile_update: true (compiled before timing);
- the device's curve of seeds together (core/algorithm/stacked_seeds.py): seed-steps per second for N seeds.
The figures are the machine's: the script prints which CPU and which GPU made them.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time

import numpy as np
import torch

from eqhrl_ros.core import EQSACLearner, LearnerConfig, heuristic_expert, make_env
from eqhrl_ros.core.algorithm import cpu_threads

ENVS = ('Pendulum-v1', 'LunarLanderContinuous-v3')
MODES = ('sac', 'eqsac')


def _sync(device: str) -> None:
    if device.startswith('cuda'):
        torch.cuda.synchronize()


def _learner(env, mode: str, seed: int, warmup: int, device: str, compiled: bool = False) -> EQSACLearner:
    config = LearnerConfig(
        mode=mode, seed=seed, learning_starts=warmup, advising_budget=10**6, device=device, compile_update=compiled
    )
    return EQSACLearner(int(np.prod(env.observation_space.shape)), env.action_space.low, env.action_space.high, config)


class Loop:
    """One lone learner's Algorithm 1 loop, advanced some env steps at a time."""

    def __init__(self, env_id: str, mode: str, device: str, warmup: int, compiled: bool = False, foreground=False):
        from eqhrl_ros.core.runs.in_process import _Acting

        self.device = device
        self.env = make_env(env_id)
        self.learner = _learner(self.env, mode, 0, warmup, device, compiled and not foreground)
        self.acting = _Acting(self.env, self.learner, heuristic_expert(env_id))
        self.acting.reset(0)
        self.run(warmup)
        if compiled:  # the first update starts the compiler; timing starts once it is done
            self.run(1)
            if foreground:  # in this thread (some torch versions' inductor fails in another one)
                self.learner.start_compiling(background=False)
            self.learner.compiled_update.wait()  # a failure: eager, said in one log line

    def run(self, steps: int) -> None:
        for _ in range(steps):
            obs, action, reward, next_obs, terminated, truncated, advised = self.acting.act()
            if self.learner.step(obs, action, reward, next_obs, terminated, truncated, advised) is not None:
                self.acting.reset()
        _sync(self.device)


def steps_per_second(env_id: str, devices, args) -> dict:
    loops = {
        (mode, device, compiled): Loop(env_id, mode, device, args.warmup, compiled, args.foreground_compile)
        for mode in MODES
        for device in devices
        for compiled in ((False, True) if args.compiled else (False,))
    }
    seconds = dict.fromkeys(loops, 0.0)
    for _ in range(args.rounds):
        for key, loop in loops.items():
            start = time.perf_counter()
            loop.run(args.round_steps)
            seconds[key] += time.perf_counter() - start
    update_ms = {}
    for key, loop in loops.items():
        times = []
        for _ in range(args.updates):
            start = time.perf_counter()
            loop.learner.update()
            _sync(loop.device)
            times.append(time.perf_counter() - start)
        update_ms[key] = statistics.median(times) * 1e3
    figures = {key: (args.rounds * args.round_steps / s, update_ms[key]) for key, s in seconds.items()}
    return figures, loops


def seeds_together(env_id: str, device: str, n: int, args) -> float:
    from eqhrl_ros.core.runs.in_process import SeedRun, StackedSeedRuns

    runs = []
    for seed in range(n):
        env = make_env(env_id)
        runs.append(SeedRun(env, _learner(env, 'eqsac', seed, args.warmup, device), heuristic_expert(env_id), seed))
    together = StackedSeedRuns(runs, episodes=10**9)
    for _ in range(args.warmup):
        together.step()
    _sync(device)
    start = time.perf_counter()
    for _ in range(args.seed_steps):
        together.step()
    _sync(device)
    seconds = time.perf_counter() - start
    together.close()
    return n * args.seed_steps / seconds


def machine(device: str) -> str:
    cpu = platform.processor() or platform.machine()
    try:
        with open('/proc/cpuinfo') as f:
            cpu = next(line.split(':', 1)[1].strip() for line in f if line.startswith('model name'))
    except (OSError, StopIteration):
        pass
    text = f'CPU: {cpu}, {torch.get_num_threads()} torch threads; torch {torch.__version__}'
    if device.startswith('cuda'):
        text += f'; GPU: {torch.cuda.get_device_name()} (CUDA {torch.version.cuda})'
    return text


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--device', default='cpu', help="torch device beside the CPU (cuda, cuda:1); 'cpu' alone")
    parser.add_argument('--envs', nargs='+', default=list(ENVS))
    parser.add_argument('--threads', type=int, default=2, help='torch CPU threads (the 2-core machine: 2)')
    parser.add_argument('--warmup', type=int, default=1000)
    parser.add_argument('--rounds', type=int, default=4)
    parser.add_argument('--round-steps', type=int, default=150)
    parser.add_argument('--updates', type=int, default=200, help='updates alone, timed one by one')
    parser.add_argument('--compiled', action='store_true', help='also each learner with compile_update: true')
    parser.add_argument(
        '--foreground-compile', action='store_true', help='compile in the main thread (before timing either way)'
    )
    parser.add_argument('--curve', nargs='*', type=int, default=[1, 2, 5, 10, 20], help='N seeds together')
    parser.add_argument('--seed-steps', type=int, default=100, help='timed env steps per seed of the curve')
    args = parser.parse_args(argv)
    cpu_threads.fix(args.threads)  # fixed: side by side, no contender's threads count as a crowd
    if args.device != 'cpu' and args.device.startswith('cuda') and not torch.cuda.is_available():
        parser.error(f'--device {args.device}: torch sees no GPU here')
    devices = ['cpu'] if args.device == 'cpu' else ['cpu', args.device]
    print(machine(args.device))
    for env_id in args.envs:
        figures, loops = steps_per_second(env_id, devices, args)
        print(f'\n{env_id}, one lone learner, one update per env step')
        print(f'  {"mode":<6} {"device":<8} {"update":<9} {"steps/s":>8} {"update ms":>10} {"vs cpu eager":>13}')
        for (mode, device, compiled), (rate, ms) in figures.items():
            ratio = rate / figures[(mode, 'cpu', False)][0]
            kind = 'eager'
            if compiled:
                kind = 'compiled' if loops[(mode, device, compiled)].learner.compiled_update.ready else 'failed'
            print(f'  {mode:<6} {device:<8} {kind:<9} {rate:>8.1f} {ms:>10.2f} {ratio:>12.2f}x')
        if args.curve:
            device = devices[-1]
            print(f'{env_id}, EQSAC seeds together on {device}: seed-steps/s')
            base = None
            for n in args.curve:
                rate = seeds_together(env_id, device, n, args)
                base = base or rate / n
                print(f'  N={n:<3} {rate:>8.1f}  ({rate / base:.2f}x one seed)')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
