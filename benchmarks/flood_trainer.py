"""Flood the trainer's /transitions from a name it does not hear: its memory, during and after.

    make bench-flood          # also runs this
    .venv/bin/python benchmarks/flood_trainer.py [--batches 200] [--transitions 100000]

A trainer process (told its one actor by name, /a0/actor) runs in a private ROS domain; this
script publishes --batches well-formed TransitionBatch messages of --transitions Pendulum
transitions each (100,000: 3.2 MB a message, 640 MB in all) from a node named /stranger, as
fast as reliable delivery lets it, and samples the trainer's resident memory (/proc) every
0.1 s: before, the peak, and 10 s after. Exits non-zero when the peak grew by more than the
inbox limit (inbox_limit_mb, 256 MB) and 44 MB more, or when 10 s after it is still more than
50 MB up.
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

BIN = Path(sys.executable).parent


def rss_mb(pid: int) -> float:
    with open(f'/proc/{pid}/status') as f:
        return next(int(line.split()[1]) / 1024 for line in f if line.startswith('VmRSS:'))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--batches', type=int, default=200)
    parser.add_argument('--transitions', type=int, default=100_000)
    args = parser.parse_args()
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ['ROS_DOMAIN_ID'] = str(1 + os.getpid() % 100)
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from eqhrl_interfaces.msg import TransitionBatch
    from eqhrl_ros.nodes import trainer_msgs

    out = tempfile.mkdtemp(prefix='flood_trainer_')
    log = open(Path(out) / 'trainer.log', 'w+')
    trainer = subprocess.Popen(
        [str(BIN / 'trainer'), '--ros-args', '-p', 'env_id:=Pendulum-v1', '-p', f'output_dir:={out}',
         '-p', 'actors:=[/a0/actor]', '-p', 'report_period_s:=1.0'],
        stdout=log, stderr=subprocess.STDOUT,
    )  # fmt: skip
    rclpy.init()
    node = rclpy.create_node('stranger')
    pub = node.create_publisher(TransitionBatch, trainer_msgs.TRANSITIONS_TOPIC, trainer_msgs.TRANSITIONS_QOS)
    n = args.transitions
    msg = TransitionBatch(
        actor='/stranger/actor', observation_size=3, action_low=[-2.0], action_high=[2.0],
        observations=[0.0] * 3 * n, next_observations=[0.0] * 3 * n, actions=[0.0] * n, rewards=[0.0] * n,
        terminated=[False] * n, advised=[False] * n,
    )  # fmt: skip
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    samples, stop = [], threading.Event()

    def sample():
        while not stop.is_set():
            samples.append(rss_mb(trainer.pid))
            time.sleep(0.1)

    try:
        deadline = time.monotonic() + 60
        while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        time.sleep(3.0)  # the trainer settles after discovery
        before = rss_mb(trainer.pid)
        sampler = threading.Thread(target=sample, daemon=True)
        sampler.start()
        start = time.monotonic()
        for sequence in range(args.batches):
            msg.sequence = sequence
            pub.publish(msg)
            executor.spin_once(timeout_sec=0)
        flood_s = time.monotonic() - start
        time.sleep(10.0)
        stop.set()
        sampler.join()
        after = rss_mb(trainer.pid)
    finally:
        trainer.terminate()
        trainer.wait(timeout=30)
        node.destroy_node()
        rclpy.shutdown()
    peak = max(samples)
    mb = args.batches * n * 32 / 1e6
    refused = log.seek(0) or log.read().count('refused')
    print(
        f'flood of {args.batches} batches x {n} transitions ({mb:.0f} MB) in {flood_s:.1f} s from an unlisted name: '
        f'trainer RSS {before:.0f} MB before, peak {peak:.0f} MB (+{peak - before:.0f}), '
        f'{after:.0f} MB 10 s after (+{after - before:.0f}); {refused} refusal log lines (throttled)'
    )
    ok = peak - before <= 256 + 44 and after - before <= 50
    print('ok' if ok else 'FAILED: the flood cost more than the inbox limit, or its memory was not given back')
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
