"""What the ROS wiring costs: env steps/s through the topics, advice round trips, start-up.

    make bench-ros        # or: .venv/bin/python benchmarks/bench_ros.py [--steps 3000]

1. Topics, updates off: gym_env, learner (SAC, no updates) and expert as nodes in one
   process and one executor (as eqhrl-train runs them); env steps per second, the
   median of several windows.
2. Updates on: the same learner updating every step (Table 1 sizes, batch 256),
   against the in-process loop of benchmarks/bench_learner.py, interleaved in rounds.
3. Advice round trip, learner -> expert -> learner: EQSAC with gates that always
   fire, the expert node in the same process, then in its own process.
4. Start-up: `eqhrl-train` from the command to the first env step, as its env node
   logs it.

Prints each figure with its target; exits with 1 if one is missed.
Runs in a private ROS domain with localhost-only discovery. The targets were set
for the EventsExecutor, which `make bench-ros` passes (--executor events); the
nodes' default is the SingleThreadedExecutor, bounded under floods
and slower through the topics (see the package README).
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
os.environ.setdefault('ROS_DOMAIN_ID', str(1 + os.getpid() % 100))

import numpy as np  # noqa: E402
import rclpy  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from eqhrl_ros.core.algorithm import cpu_threads
from eqhrl_ros.nodes.expert_node import ExpertNode  # noqa: E402
from eqhrl_ros.nodes.gym_env_node import GymEnvNode  # noqa: E402
from eqhrl_ros.nodes.learner_node import LearnerNode  # noqa: E402
from eqhrl_ros.nodes.spinning import make_executor  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from bench_learner import OursLoop  # noqa: E402

BIN = Path(sys.prefix) / 'bin'
EXECUTOR = None  # --executor: None is make_executor's default (single)
ENV_ID = 'Pendulum-v1'


class Wiring:
    """gym_env, learner and (optionally) expert nodes, spun by one executor here."""

    def __init__(self, output: Path, learner_params: dict, expert: str = 'inprocess'):
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.children = []
        if expert == 'process':
            self.children.append(
                subprocess.Popen([str(BIN / 'expert')], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            )
        env = GymEnvNode(
            context=self.context,
            parameter_overrides=[
                Parameter('env_id', value=ENV_ID),
                Parameter('max_episode_steps', value=200),
                Parameter('seed', value=0),
            ],
        )
        nodes = [env]
        if expert == 'inprocess':
            nodes.append(ExpertNode(context=self.context))
        params = {
            'env_id': ENV_ID,
            'output_dir': str(output),
            'checkpoint_every_episodes': 0,
            'seed': 0,
            **learner_params,
        }
        self.learner = LearnerNode(
            context=self.context, parameter_overrides=[Parameter(k, value=v) for k, v in params.items()]
        )
        nodes.append(self.learner)
        self.nodes = nodes
        self.executor = make_executor(EXECUTOR, context=self.context)
        for node in nodes:
            self.executor.add_node(node)
        if expert == 'process':
            # Nothing steps before the executor spins. Wait until the learner's own client
            # sees the expert process's service (a probe client seeing it is not enough:
            # each client discovers it on its own), else the first steps count as 'unavailable'.
            if not self.learner.advice.client.wait_for_service(timeout_sec=30.0):
                self.close()
                raise RuntimeError("the expert process did not offer 'advise' within 30 s")

    def run(self, steps: int) -> float:
        """Spin until the learner has stored ``steps`` more transitions; returns seconds."""
        target = self.learner.learner.total_steps + steps
        start = time.perf_counter()
        while self.learner.learner.total_steps < target:
            self.executor.spin_once(timeout_sec=1.0)
        return time.perf_counter() - start

    def close(self) -> None:
        self.learner.close()
        for node in self.nodes:
            self.executor.remove_node(node)
            node.destroy_node()
        self.executor.shutdown()
        rclpy.try_shutdown(context=self.context)
        for child in self.children:
            child.terminate()
            child.wait(timeout=10)


def percentiles_ms(seconds) -> tuple[float, float]:
    ms = np.asarray(seconds) * 1000.0
    return float(np.percentile(ms, 50)), float(np.percentile(ms, 99))


def topics_without_updates(output: Path, steps: int, windows: int) -> list[float]:
    """Steps/s in each of ``windows`` consecutive windows of ``steps`` steps."""
    wiring = Wiring(output, {'mode': 'sac', 'updates_per_step': 0}, expert='inprocess')
    try:
        wiring.run(200)  # discovery and first episode, not timed
        return [steps / wiring.run(steps) for _ in range(windows)]
    finally:
        wiring.close()


def with_updates(output: Path, rounds: int, round_steps: int, warmup: int) -> tuple[float, float]:
    """(through ROS, in-process) steps/s, SAC updating every step, interleaved rounds."""
    wiring = Wiring(output, {'mode': 'sac', 'learning_starts': warmup}, expert='none')
    loop = OursLoop(ENV_ID, 'sac', warmup)
    try:
        wiring.run(warmup + round_steps)  # fill the replay memory; first updates, not timed
        ros_s = loop_s = 0.0
        for i in range(rounds):
            # Alternate who goes first, so that a machine slowing down within a round
            # does not always fall on the same one.
            if i % 2 == 0:
                ros_s += wiring.run(round_steps)
            start = time.perf_counter()
            loop.run(round_steps)
            loop_s += time.perf_counter() - start
            if i % 2 == 1:
                ros_s += wiring.run(round_steps)
        return rounds * round_steps / ros_s, rounds * round_steps / loop_s
    finally:
        wiring.close()
        loop.env.close()


def advice_round_trips(output: Path, steps: int, expert: str) -> tuple[float, float, int]:
    # Fixed thresholds that every state passes: the gates fire at every step.
    wiring = Wiring(
        output,
        {
            'mode': 'eqsac',
            'updates_per_step': 0,
            'advising_budget': 10**9,
            'threshold_kind': 'fixed',
            'fixed_d_threshold': 0.0,
            'fixed_e_threshold': 1e9,
            'advice_timeout_s': 2.0,
        },
        expert=expert,
    )
    try:
        wiring.run(200)
        wiring.learner.advice.latencies.clear()
        wiring.run(steps)
        latencies = list(wiring.learner.advice.latencies)
        return (*percentiles_ms(latencies), len(latencies))
    finally:
        wiring.close()


def start_up(output: Path, runs: int) -> list[float]:
    """Seconds from the command to the first env step, as the env node logs it."""
    times = []
    for i in range(runs):
        result = subprocess.run(
            [
                str(BIN / 'eqhrl-train'),
                '--params',
                'demo',
                '--episodes',
                '1',
                '--max-steps',
                '5',
                '--output',
                str(output / f'start_{i}'),
            ],
            capture_output=True,
            text=True,
            timeout=120,
        )
        found = re.search(r'first env step ([0-9.]+) s after the process started', result.stderr + result.stdout)
        if result.returncode != 0 or not found:
            raise RuntimeError(f'eqhrl-train failed (exit {result.returncode}):\n{result.stderr[-2000:]}')
        times.append(float(found.group(1)))
    return times


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--steps', type=int, default=1000, help='timed steps per window, updates off')
    parser.add_argument('--windows', type=int, default=5, help='timed windows, updates off')
    parser.add_argument('--advice-steps', type=int, default=2000)
    parser.add_argument('--rounds', type=int, default=16)
    parser.add_argument('--round-steps', type=int, default=100)
    parser.add_argument('--warmup', type=int, default=500)
    parser.add_argument('--start-runs', type=int, default=3)
    parser.add_argument('--threads', type=int, default=2)
    parser.add_argument(
        '--executor',
        choices=('events', 'single', 'multi'),
        default=None,
        help='executor of the in-process wiring (start-up always uses the default)',
    )
    args = parser.parse_args()
    global EXECUTOR
    EXECUTOR = args.executor
    cpu_threads.fix(args.threads)  # fixed: side by side, no contender's threads count as a crowd
    results = []  # (what, figure, target text, met)

    def report(what: str, figure: str, target: str, met: bool) -> None:
        results.append(met)
        print(f'{what:52s} {figure:>28s}   target {target:12s} {"" if met else "MISSED"}', flush=True)

    with tempfile.TemporaryDirectory(prefix='bench_ros_') as tmp:
        out = Path(tmp)
        print(
            f'{ENV_ID}, torch {args.threads} threads, ROS_DOMAIN_ID {os.environ["ROS_DOMAIN_ID"]}, '
            f'{os.environ.get("RMW_IMPLEMENTATION", "default RMW")}'
        )
        # The median of several windows: a burst of load from the machine's other tenants
        # falls into one window instead of the whole figure; the range is printed too.
        rates = topics_without_updates(out / 'topics', args.steps, args.windows)
        rate = float(np.median(rates))
        report(
            f'through ROS, updates off (steps/s, median of {len(rates)} windows)',
            f'{rate:.0f} ({min(rates):.0f}-{max(rates):.0f})',
            '>= 2000',
            rate >= 2000,
        )

        ros, loop = with_updates(out / 'updates', args.rounds, args.round_steps, args.warmup)
        report(
            'through ROS, SAC updating (steps/s, vs in-process)',
            f'{ros:.1f} vs {loop:.1f} = {ros / loop:.2f}x',
            '>= 0.9x',
            ros / loop >= 0.9,
        )

        for where in ('inprocess', 'process'):
            p50, p99, n = advice_round_trips(out / f'advice_{where}', args.advice_steps, where)
            label = 'same process' if where == 'inprocess' else 'expert in its own process'
            report(
                f'advice round trip, {label} (ms, n={n})',
                f'p50 {p50:.2f}  p99 {p99:.2f}',
                '<1 / <5',
                p50 < 1.0 and p99 < 5.0,
            )

        times = start_up(out, args.start_runs)
        report(
            f'start-up to first env step (s, {len(times)} runs)',
            'median %.2f  max %.2f' % (float(np.median(times)), max(times)),
            '< 3',
            max(times) < 3.0,
        )

    missed = results.count(False)
    print('all targets met' if not missed else f'{missed} target(s) missed')
    return 1 if missed else 0


if __name__ == '__main__':
    sys.exit(main())
