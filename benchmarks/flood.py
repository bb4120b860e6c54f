"""Flood: a hostile publisher floods `observation` (or `action`) with invalid messages.

    .venv/bin/python benchmarks/flood.py                        # 60 s flood on the learner
    .venv/bin/python benchmarks/flood.py --target env --seconds 20
    EQHRL_EXECUTOR=events .venv/bin/python benchmarks/flood.py  # the nodes on another executor

`gym_env`, `expert` and `learner` run as their own processes (executables as a user
starts them) in a private ROS domain; the learner updates at every step. This script
publishes serialized messages of the wrong size as fast as it can on the target's
input topic for --seconds, and meanwhile watches:

- the target's resident memory (/proc/<pid>/status) before, at the end of and after
  the flood;
- training: actions per second on `action` (learner target) or observations per
  second on `observation` (env target), before, during and after;
- recovery: seconds from the end of the flood until training stays at half the rate
  measured before it (every later 0.5 s window at least that fast);
- log lines the target wrote during the flood (rejections must be throttled).

Exits non-zero when the target's memory grew by more than --max-growth-mb
(20 MB for a 60 s flood) or it did not recover within --max-recovery-s (3 s).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path


def rss_mb(pid: int) -> float:
    with open(f'/proc/{pid}/status') as f:
        for line in f:
            if line.startswith('VmRSS:'):
                return int(line.split()[1]) / 1024.0
    return float('nan')


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--target', choices=('learner', 'env'), default='learner')
    parser.add_argument('--seconds', type=float, default=60.0, help='length of the flood')
    parser.add_argument('--warmup', type=float, default=8.0, help='seconds of training before the flood')
    parser.add_argument('--after', type=float, default=8.0, help='seconds watched after the flood')
    parser.add_argument('--max-growth-mb', type=float, default=20.0)
    parser.add_argument('--max-recovery-s', type=float, default=3.0)
    args = parser.parse_args()

    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    os.environ['ROS_DOMAIN_ID'] = str(1 + os.getpid() % 100)
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Float32MultiArray

    bin_dir = Path(sys.prefix) / 'bin'
    out = Path(tempfile.mkdtemp(prefix='eqhrl_flood_'))
    learner_args = [
        '--ros-args',
        '-p',
        'hidden_sizes:=[64,64]',
        '-p',
        'batch_size:=64',
        '-p',
        'learning_starts:=200',
        '-p',
        'advising_budget:=1000000',
        '-p',
        f'output_dir:={out / "run"}',
        '-p',
        'checkpoint_every_episodes:=0',
        '-p',
        'torch_threads:=1',
    ]
    logs = {name: (out / f'{name}.log').open('w+') for name in ('gym_env', 'expert', 'learner')}
    commands = {'gym_env': ['--ros-args', '-p', 'max_episode_steps:=200'], 'expert': [], 'learner': learner_args}
    children = {
        name: subprocess.Popen([str(bin_dir / name), *argv], stdout=logs[name], stderr=subprocess.STDOUT)
        for name, argv in commands.items()
    }
    target = children['learner' if args.target == 'learner' else 'gym_env']
    target_log = logs['learner' if args.target == 'learner' else 'gym_env']

    rclpy.init()
    node = rclpy.create_node('flood')
    flood_topic, watch_topic = ('observation', 'action') if args.target == 'learner' else ('action', 'observation')
    arrivals: list[float] = []
    node.create_subscription(
        Float32MultiArray, watch_topic, lambda _msg: arrivals.append(time.monotonic()), 100, raw=True
    )
    publisher = node.create_publisher(Float32MultiArray, flood_topic, 10)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    spinning = threading.Event()
    spinning.set()

    def spin():
        while spinning.is_set():
            executor.spin_once(timeout_sec=0.05)

    thread = threading.Thread(target=spin, daemon=True)
    thread.start()

    def rate(t0, t1):
        return sum(t0 <= t < t1 for t in list(arrivals)) / max(t1 - t0, 1e-9)

    status = 0
    try:
        deadline = time.monotonic() + 90
        while len(arrivals) < 50 and time.monotonic() < deadline:
            time.sleep(0.2)
        if len(arrivals) < 50:
            print('training did not start; see', out)
            return 2
        time.sleep(args.warmup)
        now = time.monotonic()
        before = rate(now - args.warmup / 2, now)
        rss_before = rss_mb(target.pid)
        log_before = os.path.getsize(target_log.name)

        bad = serialize_message(Float32MultiArray(data=[0.5] * 2))  # the wrong size on both topics
        sent, start = 0, time.monotonic()
        while time.monotonic() - start < args.seconds:
            for _ in range(200):
                publisher.publish(bad)
            sent += 200
        flood_end = time.monotonic()
        rss_end = rss_mb(target.pid)
        with open(target_log.name, 'rb') as f:
            f.seek(log_before)
            log_lines = f.read().count(b'\n')
        during = rate(start, flood_end)

        time.sleep(args.after)
        rss_after = rss_mb(target.pid)
        # Recovery: from the end of the flood until the rate stays at half the rate before
        # (the end of the last 0.5 s window below it); infinite if still below at the end.
        recovery, t = 0.0, flood_end
        while t + 0.5 <= flood_end + args.after + 1e-9:
            if rate(t, t + 0.5) < before / 2:
                recovery = t + 0.5 - flood_end
            t += 0.1
        if recovery >= args.after - 0.5:
            recovery = float('inf')
        after = rate(flood_end + args.after / 2, flood_end + args.after)
        growth = max(rss_end, rss_after) - rss_before
        print(
            f'target {args.target} (executor {os.environ.get("EQHRL_EXECUTOR", "default")}): '
            f'{sent:,} invalid messages in {flood_end - start:.1f} s ({sent / (flood_end - start):,.0f}/s)'
        )
        print(f'  {watch_topic} per s: before {before:.1f}, during {during:.1f}, after {after:.1f}')
        print(
            f'  RSS MB: before {rss_before:.1f}, end of flood {rss_end:.1f}, '
            f'{args.after:g} s after {rss_after:.1f} (growth {growth:+.1f}, limit {args.max_growth_mb:g})'
        )
        print(f'  recovery: {recovery:.1f} s after the flood (limit {args.max_recovery_s:g})')
        print(f'  log lines written during the flood: {log_lines}')
        if growth > args.max_growth_mb or recovery > args.max_recovery_s:
            print('  MISSED')
            status = 1
    finally:
        spinning.clear()
        thread.join(timeout=2)
        for child in children.values():
            child.send_signal(2)
        for child in children.values():
            try:
                child.wait(timeout=20)
            except subprocess.TimeoutExpired:
                child.kill()
        node.destroy_node()
        rclpy.try_shutdown()
    return status


if __name__ == '__main__':
    sys.exit(main())
