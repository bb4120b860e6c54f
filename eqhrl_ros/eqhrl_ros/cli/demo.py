"""eqhrl-demo (make demo): EQSAC learns Pendulum-v1 through the three ROS nodes, with the
heuristic expert, then prints a summary and saves a plot of return and advice per episode.
Each run replaces the previous demo in its output folder. With --params, the env node, mode and
env are the file's (eqhrl-train's choice), and the summary and plot name them."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from ..core.algorithm.config import MODE_LABELS
from ..reports.plots import plot_training, read_episodes
from . import train


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog='eqhrl-demo', description=__doc__)
    parser.add_argument('--output', default='runs/demo', help='output folder')
    parser.add_argument('--params', default='demo', help='params file (name or path)')
    args = parser.parse_args(argv)

    status, node = train.train(['--params', args.params, '--output', args.output, '--overwrite'])
    if status != 0:
        return status
    # What ran, as the learner node knew it (a params file may name another env or mode).
    what = f'{MODE_LABELS.get(node.config.mode, node.config.mode)} on {node.spec.name or "the env"}'
    output = Path(args.output)
    data = read_episodes(output / 'episodes.csv')
    returns = data['return']
    k = max(1, len(returns) // 10)
    png = plot_training(output / 'episodes.csv', output / 'demo.png', title=f'{what} through ROS 2')
    print()
    print('=' * 64)
    print(f'{what}: {len(returns)} episodes, {int(data["total_steps"][-1])} steps')
    print(f'  mean return, first {k} episodes: {np.mean(returns[:k]):8.1f}')
    print(f'  mean return, last  {k} episodes: {np.mean(returns[-k:]):8.1f}')
    print(f'  success rate, last {k} episodes: {np.mean(data["success"][-k:]):8.0%}')
    print(
        f'  advice asked {int(data["advice_asked"].sum())}, given {int(data["advice_given"].sum())} '
        f'(in {int((data["advice_asked"] > 0).sum())} episodes)'
    )
    print(f'  plot: {png}')
    print(f'  csv:  {output / "episodes.csv"}; checkpoint and policy in {output}')
    print(drive_with(args.params, output))
    print('=' * 64)
    from ..nodes.spinning import end_process

    end_process(0)  # at once only while a compile_update compile still runs (nodes/spinning.py)
    return 0


def drive_with(params: str, output: Path) -> str:
    """How to drive the env with what the demo learned (policy_driver), in two commands."""
    from ..files.paths import params_file
    from ..files.yaml_files import load_mapping
    from ..nodes.launching import env_node_for

    path = params_file(params)
    # The node programs lie beside this one: .venv/bin, or a colcon install's lib/eqhrl_ros.
    here = Path(sys.argv[0]).parent

    def program(name: str) -> str:
        return str(here / name) if (here / name).exists() else f'ros2 run eqhrl_ros {name}'

    return (
        '  drive with what it learned, no advice, no updates (two terminals):\n'
        f'    {program(env_node_for(load_mapping(path, "params file")))} --ros-args --params-file {path}\n'
        f'    {program("policy_driver")} --ros-args -p policy_path:={output / "policy.pt"} -p max_episodes:=5'
    )


if __name__ == '__main__':
    sys.exit(main())
