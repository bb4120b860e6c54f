"""Soak: env, learner and expert through ROS for a long run, learner updating.

    .venv/bin/python benchmarks/soak.py --steps 200000            # the full soak
    .venv/bin/python benchmarks/soak.py --steps 20000 --report-every 30

The env and expert nodes run as their own processes (`gym_env`, `expert`); the
learner node runs here, so that its memory and counters can be read directly.
EQSAC with an advising budget longer than the run keeps the advice service busy
all the way. The replay memory is kept small (--replay) so that it fills early:
memory must then stay flat.

Prints, every --report-every seconds: steps, steps per second over the interval,
the learner's RSS, observations lost (gaps in the step sequence) and repeated
(the env re-sent because an action came late), and advice round-trip latency
percentiles. Exits non-zero if RSS grew by more than --max-growth-mb after the
replay memory filled, or if any observation was lost.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def rss_mb() -> float:
    with open('/proc/self/status') as f:
        for line in f:
            if line.startswith('VmRSS:'):
                return int(line.split()[1]) / 1024.0
    return float('nan')


def percentiles(values) -> str:
    if not values:
        return 'no advice yet'
    ms = np.asarray(values) * 1000.0
    p50, p90, p99 = np.percentile(ms, [50, 90, 99])
    return f'advice RTT ms p50 {p50:.2f} p90 {p90:.2f} p99 {p99:.2f} max {ms.max():.2f} (n={len(ms)})'


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--steps', type=int, default=200_000)
    parser.add_argument('--replay', type=int, default=20_000, help='replay capacity (fills early)')
    parser.add_argument('--hidden', type=int, default=64)
    parser.add_argument('--report-every', type=float, default=60.0, help='seconds between lines')
    parser.add_argument('--max-growth-mb', type=float, default=50.0)
    parser.add_argument('--output', default='runs/soak')
    args = parser.parse_args()

    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    os.environ.setdefault('ROS_DOMAIN_ID', str(1 + os.getpid() % 100))
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from eqhrl_ros.nodes.learner_node import LearnerNode

    bin_dir = Path(sys.prefix) / 'bin'
    output = Path(args.output)
    output.mkdir(parents=True, exist_ok=True)
    children = [
        subprocess.Popen(
            [str(bin_dir / 'gym_env'), '--ros-args', '-p', 'max_episode_steps:=200'],
            stdout=(output / 'gym_env.log').open('w'),
            stderr=subprocess.STDOUT,
        ),
        subprocess.Popen([str(bin_dir / 'expert')], stdout=(output / 'expert.log').open('w'), stderr=subprocess.STDOUT),
    ]
    rclpy.init()
    learner = LearnerNode(
        parameter_overrides=[
            Parameter('mode', value='eqsac'),
            Parameter('hidden_sizes', value=[args.hidden, args.hidden]),
            Parameter('batch_size', value=128),
            Parameter('learning_starts', value=1000),
            Parameter('replay_capacity', value=args.replay),
            Parameter('advising_budget', value=10**9),
            Parameter('advice_timeout_s', value=0.5),
            Parameter('output_dir', value=str(output)),
            Parameter('overwrite', value=True),
            Parameter('checkpoint_every_episodes', value=0),
            Parameter('torch_threads', value=1),
        ]
    )
    executor = SingleThreadedExecutor()
    executor.add_node(learner)
    print(
        f'soak: {args.steps} steps of Pendulum-v1 through ROS, EQSAC {args.hidden}x{args.hidden}, '
        f'replay {args.replay}; env and expert in their own processes',
        flush=True,
    )
    print(
        f'{"time s":>7s} {"steps":>8s} {"steps/s":>8s} {"RSS MB":>7s} {"lost":>5s} {"repeat":>6s}  advice', flush=True
    )
    start = last_time = time.monotonic()
    last_steps, rss_full = 0, None
    rss_series = []
    try:
        while learner.learner.total_steps < args.steps:
            executor.spin_once(timeout_sec=0.1)
            now = time.monotonic()
            if now - last_time >= args.report_every:
                steps = learner.learner.total_steps
                rss = rss_mb()
                rss_series.append(rss)
                if rss_full is None and len(learner.learner.replay) >= args.replay:
                    rss_full = rss
                print(
                    f'{now - start:7.0f} {steps:8d} {(steps - last_steps) / (now - last_time):8.1f} '
                    f'{rss:7.1f} {learner.observation_gaps:5d} {learner.repeated_observations:6d}  '
                    f'{percentiles(list(learner.advice.latencies))}',
                    flush=True,
                )
                last_time, last_steps = now, steps
    finally:
        elapsed = time.monotonic() - start
        steps = learner.learner.total_steps
        rss_end = rss_mb()
        latencies = list(learner.advice.latencies)
        gaps, repeats = learner.observation_gaps, learner.repeated_observations
        totals = learner.learner.advice_total
        learner.close()
        learner.destroy_node()
        rclpy.try_shutdown()
        for child in children:
            child.send_signal(signal.SIGINT)
        for child in children:
            try:
                child.wait(timeout=10)
            except subprocess.TimeoutExpired:
                child.kill()

    growth = rss_end - rss_full if rss_full is not None else float('nan')
    print(
        f'\nsummary: {steps} steps in {elapsed:.0f} s ({steps / elapsed:.1f} steps/s); '
        f'{learner.learner.episode} episodes'
    )
    print(
        f'  RSS: end {rss_end:.1f} MB; when the replay memory filled {rss_full or float("nan"):.1f} MB; '
        f'growth after that {growth:+.1f} MB'
    )
    print(f'  observations lost {gaps}, re-sent by the env {repeats}')
    print(
        f'  advice asked {totals.asked}, given {totals.given}, failed {totals.failed_total} '
        f'({", ".join(f"{k} {v}" for k, v in totals.failed.items() if v) or "none"})'
    )
    print(f'  {percentiles(latencies)}')
    failed = gaps > 0 or (rss_full is not None and growth > args.max_growth_mb)
    print('RESULT:', 'FAIL' if failed else 'ok')
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main())
