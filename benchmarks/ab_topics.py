"""Steps/s through the topics (updates off), this tree against another, interleaved.

    .venv/bin/python benchmarks/ab_topics.py --before /tmp/base [--pairs 6]

``--before`` is another checkout of this repository (e.g. ``git worktree add /tmp/base
<commit>``). Each pair runs ``bench_ros.py``'s updates-off measurement once on each tree,
each in a fresh process importing that tree's package, the order alternating between
pairs so that a machine slowing down does not always fall on the same side. Prints each
side's windows, each pair's ratio (after / before, medians of its windows) and the median
and geometric mean of the ratios. No target: evidence for a change to the ROS path.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
from pathlib import Path

THIS_TREE = Path(__file__).resolve().parents[1]

MEASURE = r"""
import json, sys, tempfile
from pathlib import Path
tree = sys.argv[1]
sys.path.insert(0, tree + '/benchmarks')
import bench_ros
import eqhrl_ros.nodes.messages
assert eqhrl_ros.nodes.messages.__file__.startswith(tree), 'imported the wrong tree'
print('WINDOWS', json.dumps(bench_ros.topics_without_updates(Path(tempfile.mkdtemp()),
                                                             int(sys.argv[2]), int(sys.argv[3]))))
"""


def windows(tree: Path, steps: int, count: int) -> list[float]:
    env = {**os.environ, 'PYTHONPATH': str(tree / 'eqhrl_ros')}
    env.pop('ROS_DOMAIN_ID', None)  # bench_ros picks a private one per process
    done = subprocess.run(
        [sys.executable, '-c', MEASURE, str(tree), str(steps), str(count)],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
    lines = [line for line in done.stdout.splitlines() if line.startswith('WINDOWS ')]
    if done.returncode != 0 or not lines:
        raise RuntimeError(f'measurement on {tree} failed:\n{done.stderr[-3000:]}')
    return json.loads(lines[-1].split(' ', 1)[1])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--before', type=Path, required=True, help='another checkout of this repository')
    parser.add_argument('--pairs', type=int, default=6)
    parser.add_argument('--steps', type=int, default=2000, help='steps per window')
    parser.add_argument('--windows', type=int, default=3, help='windows per process')
    args = parser.parse_args()
    trees = {'before': args.before.resolve(), 'after': THIS_TREE}
    ratios = []
    for pair in range(args.pairs):
        order = ['before', 'after'] if pair % 2 == 0 else ['after', 'before']
        medians = {}
        for side in order:
            figures = windows(trees[side], args.steps, args.windows)
            medians[side] = statistics.median(figures)
            print(f'pair {pair} {side:6s} ' + ' '.join(f'{x:6.0f}' for x in figures), flush=True)
        ratios.append(medians['after'] / medians['before'])
        print(f'pair {pair} ratio {ratios[-1]:.2f}', flush=True)
    geometric = math.exp(statistics.fmean(math.log(r) for r in ratios))
    print(
        f'after / before: median {statistics.median(ratios):.2f}, geometric mean {geometric:.2f}, '
        f'range {min(ratios):.2f}-{max(ratios):.2f} over {len(ratios)} pairs'
    )
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
