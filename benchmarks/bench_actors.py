"""Acting apart from learning: actors and a trainer against the lock-step learner.

    make bench-actors      # or: .venv/bin/python benchmarks/bench_actors.py [--part throughput|realtime|learning]

Every node runs as its own process, as `ros2 run` starts it, in a private ROS domain with
localhost-only discovery. Table 1 sizes (256x256, batch 256), mode EQSAC, one update per
env step (per transition for the trainer), learning_starts 500 so that updates begin early.

1. throughput: env steps per second (lock-step gym_env) with 1, 2 and 4 actors, each with its
   own env process, beside the learner node with its env; updates on. The trainer's updates
   per second meanwhile, and the weights' latency from publish to applied (p50, p99).
2. realtime: a real-time gym_env at 50 Hz: steps taken with the previous action because the
   answer to the current observation came after the tick, learner node against actor+trainer.
   Target: none with the actor (exit 1 otherwise).
3. learning: Pendulum to a smoothed return of -200 (a 10-episode mean) with 2 actors against
   the learner node, in wall-clock seconds and env steps, over --seeds seeds.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
os.environ.setdefault('ROS_DOMAIN_ID', str(1 + os.getpid() % 100))

BIN = Path(sys.prefix) / 'bin'
LINE = re.compile(r'\[(?:INFO|WARN)\] \[(\d+\.\d+)\] \[([\w.]+)\]: (.*)')
EPISODE = re.compile(r'episode\s+(\d+)\s+return\s+(\S+)\s+len\s+(\d+).*?steps (\d+)')


def algorithm(seed: int = 42, learning_starts: int = 500) -> list:
    values = dict(
        env_id='Pendulum-v1',
        mode='eqsac',
        learning_starts=learning_starts,
        advising_budget=30,
        seed=seed,
    )
    return [arg for k, v in values.items() for arg in ('-p', f'{k}:={v}')]


class Graph:
    """Processes started together, stopped together; their logs parsed."""

    def __init__(self, folder: Path):
        self.folder, self.processes = folder, []

    def start(self, executable: str, *args: str, ns: str = '', threads: int = 1):
        log = open(self.folder / f'{executable}-{ns.strip("/") or "root"}-{len(self.processes)}.log', 'w+')
        ros = (
            ['--ros-args', '-p', f'torch_threads:={threads}']
            if executable in ('learner', 'actor', 'trainer')
            else ['--ros-args']
        )
        if ns:
            ros += ['-r', f'__ns:={ns}']
        process = subprocess.Popen([str(BIN / executable), *ros, *args], stdout=log, stderr=subprocess.STDOUT)
        process.log = log
        self.processes.append(process)
        return process

    def stop(self) -> None:
        for p in self.processes:
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
        for p in self.processes:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()

    @staticmethod
    def lines(process) -> list:
        process.log.flush()
        return LINE.findall(Path(process.log.name).read_text())


def episodes(process, node: str) -> list:
    """[(time, episode, return, steps)] from a learner's or trainer's episode lines."""
    out = []
    for t, who, text in Graph.lines(process):
        m = EPISODE.match(text)
        if who == node and m:
            out.append((float(t), int(m.group(1)), float(m.group(2)), int(m.group(4))))
    return out


def wait_until(condition, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.5)
    return False


def steps_per_second(rows: list, after_steps: int) -> float:
    rows = [r for r in rows if r[3] >= after_steps]
    if len(rows) < 2:
        return float('nan')
    return (rows[-1][3] - rows[0][3]) / (rows[-1][0] - rows[0][0])


# ------------------------------------------------------------------ 1. throughput


def run_learner(folder: Path, seconds: float, env_args=(), extra=(), threads: int = 0):
    graph = Graph(folder)
    env = graph.start('gym_env', '-p', 'env_id:=Pendulum-v1', *env_args)
    learner = graph.start('learner', *algorithm(), '-p', f'output_dir:={folder / "learner"}', *extra, threads=threads)
    graph.start('expert', '-p', 'env_id:=Pendulum-v1')
    return graph, env, learner


def run_split(folder: Path, actors: int, env_args=(), extra=(), seed: int = 42, actor_args=()):
    """``extra``: for the trainer and the actors (the algorithm's); ``actor_args``: the actors' only."""
    graph = Graph(folder)
    names = ', '.join(f'/actor{i}/actor' for i in range(actors))
    trainer = graph.start(
        'trainer',
        *algorithm(seed),
        '-p',
        f'output_dir:={folder / "trainer"}',
        '-p',
        'report_period_s:=2.0',
        '-p',
        f'actors:=[{names}]',
        *extra,
    )
    envs, actor_processes = [], []
    for i in range(actors):
        ns = f'/actor{i}'
        envs.append(graph.start('gym_env', '-p', 'env_id:=Pendulum-v1', '-p', f'seed:={seed + i}', *env_args, ns=ns))
        graph.start('expert', '-p', 'env_id:=Pendulum-v1', ns=ns)
        actor_processes.append(graph.start('actor', *algorithm(seed + i), *extra, *actor_args, ns=ns))
    return graph, trainer, envs, actor_processes


def throughput(args) -> dict:
    results = {}
    window = args.seconds
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / 'learner').mkdir()
        graph, _, learner = run_learner(folder / 'learner', window)
        try:
            wait_until(lambda: any(r[3] >= 1500 for r in episodes(learner, 'learner')), 600)
            time.sleep(window)
        finally:
            graph.stop()
        results['learner node'] = (steps_per_second(episodes(learner, 'learner'), 1500), float('nan'), '')
        for n in args.actors:
            sub = folder / f'split{n}'
            sub.mkdir()
            graph, trainer, _, actor_processes = run_split(sub, n)
            try:
                wait_until(lambda t=trainer: any(r[3] >= 1500 for r in episodes(t, 'trainer')), 600)
                time.sleep(window)
            finally:
                graph.stop()
            rates = [
                float(m.group(1))
                for t, who, text in Graph.lines(trainer)
                if who == 'trainer' and (m := re.search(r' updates \(([\d.]+)/s\)', text))
            ]
            latency = []
            for p in actor_processes:
                m = [re.search(r'latency p50 ([\d.]+) ms, p99 ([\d.]+) ms', text) for _, _, text in Graph.lines(p)]
                latency += [(float(x.group(1)), float(x.group(2))) for x in m if x]
            lat = (
                f'p50 {np.median([a for a, _ in latency]):.1f} ms, p99 {max(b for _, b in latency):.1f} ms'
                if latency
                else ''
            )
            results[f'{n} actor(s) + trainer'] = (
                steps_per_second(episodes(trainer, 'trainer'), 1500),
                float(np.median(rates[len(rates) // 2 :])) if rates else float('nan'),
                lat,
            )
    base = results['learner node'][0]
    print(f'\n1. Env steps/s with updates on (Pendulum, Table 1 sizes, {window:.0f} s after step 1500)')
    print(f'{"":28s} {"steps/s":>9s} {"vs learner":>10s} {"trainer updates/s":>18s}  weights latency')
    for name, (rate, updates, lat) in results.items():
        print(f'{name:28s} {rate:9.1f} {rate / base:10.2f} {updates:18.1f}  {lat}')
    return results


# ------------------------------------------------------------------ 2. real time


def late_steps(env_process, skip_episodes: int) -> tuple[int, int]:
    """(late steps, steps) over the env's episodes after the first ``skip_episodes``."""
    late = steps = 0
    for _, _who, text in Graph.lines(env_process):
        m = re.match(r'episode (\d+): (\d+) steps, (\d+) with the previous action', text)
        if m and int(m.group(1)) >= skip_episodes:
            steps += int(m.group(2))
            late += int(m.group(3))
    return late, steps


def realtime(args) -> bool:
    env_args = ('-p', 'realtime:=true', '-p', 'rate_hz:=50.0', '-p', 'max_episode_steps:=200')
    extra = ('-p', 'learning_starts:=200')
    advice = ('-p', 'advice_timeout_s:=0.015')  # the learner's and the actors'
    episodes_wanted = 1 + args.realtime_episodes  # the first has no updates before step 200
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for name in ('learner node', 'actor + trainer'):
            sub = folder / name.replace(' ', '_').replace('+', '')
            sub.mkdir()
            if name == 'learner node':
                graph, env, _ = run_learner(sub, 0, env_args, (*extra, *advice))
            else:
                graph, trainer, envs, _ = run_split(sub, 1, env_args, extra, actor_args=advice)
                env = envs[0]
            try:
                wait_until(lambda e=env: late_steps(e, 0)[1] >= 200 * (episodes_wanted + 1), 60 + 5 * episodes_wanted)
            finally:
                graph.stop()
            results[name] = late_steps(env, 1)
            if name != 'learner node':
                updates = [
                    int(m.group(1))
                    for _, who, text in Graph.lines(trainer)
                    if (m := re.search(r', (\d+) updates \(', text))
                ]
                print(f'(the trainer made {updates[-1] if updates else 0} updates meanwhile)')
                assert updates and updates[-1] > 0, 'the trainer made no updates: the comparison would mean nothing'
    print('\n2. A real-time env at 50 Hz with updates on (Pendulum, 200-step episodes, from episode 1)')
    for name, (late, steps) in results.items():
        print(f'{name:28s} {late:5d} of {steps:5d} steps with the previous action ({100 * late / max(steps, 1):.1f} %)')
    ok = results['actor + trainer'][1] > 0 and results['actor + trainer'][0] == 0
    print(f'target: none with the actor ... {"met" if ok else "MISSED"}')
    return ok


# ------------------------------------------------------------------ 3. learning


def smoothed_reach(rows: list, threshold: float = -200.0, window: int = 10):
    """(seconds, env steps) when the mean return of the last ``window`` episodes first reached
    ``threshold``, from the first episode line; None if never."""
    rows = sorted(rows, key=lambda r: r[1])
    returns = [r[2] for r in rows]
    for i in range(window - 1, len(rows)):
        if np.mean(returns[i - window + 1 : i + 1]) >= threshold:
            return rows[i][0] - rows[0][0], rows[i][3]
    return None


def learning(args) -> None:
    print(
        f'\n3. Pendulum to a smoothed return of -200 (10-episode mean), {len(args.seeds)} seeds, '
        f'up to {args.max_minutes} min each'
    )
    print(f'{"":20s} {"seed":>4s} {"seconds":>8s} {"env steps":>9s}')
    # Paced: each actor waits for newer weights after 25 steps on the same ones; with weights
    # every 50 updates and 2 actors, about one update per env step, as in Algorithm 1.
    configs = {
        'learner node': None,
        '2 actors + trainer': (),
        '2 actors, paced': ('-p', 'weights_wait_steps:=25'),
    }
    configs = {name: configs[name] for name in args.configs}
    for seed in args.seeds:
        for name, actor_args in configs.items():
            with tempfile.TemporaryDirectory() as tmp:
                folder = Path(tmp)
                extra = ('-p', f'seed:={seed}', '-p', 'learning_starts:=1000')
                if actor_args is None:
                    graph, _, process = run_learner(folder, 0, ('-p', f'seed:={seed}'), extra)
                    node = 'learner'
                else:
                    split_extra = ('-p', 'learning_starts:=1000')
                    graph, process, _, _ = run_split(folder, 2, (), split_extra, seed=seed, actor_args=actor_args)
                    node = 'trainer'
                try:
                    wait_until(
                        lambda p=process, n=node: smoothed_reach(episodes(p, n)) is not None, 60 * args.max_minutes
                    )
                finally:
                    graph.stop()
                reached = smoothed_reach(episodes(process, node))
                shown = (
                    f'{reached[0]:8.0f} {reached[1]:9d}'
                    if reached
                    else f'{"not in " + str(args.max_minutes) + " min":>18s}'
                )
                print(f'{name:20s} {seed:4d} {shown}', flush=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--part', choices=('throughput', 'realtime', 'learning', 'all'), default='all')
    parser.add_argument('--actors', type=int, nargs='+', default=[1, 2, 4])
    parser.add_argument('--seconds', type=float, default=30.0, help='measuring window of each throughput run')
    parser.add_argument('--realtime-episodes', type=int, default=3)
    parser.add_argument('--seeds', type=int, nargs='+', default=[0, 1, 2])
    parser.add_argument('--max-minutes', type=float, default=15.0)
    parser.add_argument(
        '--configs',
        nargs='+',
        default=['learner node', '2 actors + trainer', '2 actors, paced'],
        help='which runs of the learning part',
    )
    args = parser.parse_args()
    print(f'{os.cpu_count()} CPUs; every node its own process; ROS_DOMAIN_ID {os.environ["ROS_DOMAIN_ID"]}')
    ok = True
    if args.part in ('throughput', 'all'):
        throughput(args)
    if args.part in ('realtime', 'all'):
        ok = realtime(args) and ok
    if args.part in ('learning', 'all'):
        learning(args)
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
