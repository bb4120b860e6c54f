"""eqhrl-train: env, expert and learner nodes in one process, for machines without ros2 launch.

    eqhrl-train --params pendulum --output runs/pendulum_eqsac [--mode qasac] [--episodes 50]
    eqhrl-train --params teleop_pendulum --expert-node teleop     (a person advises)
    eqhrl-train --params double_integrator --output runs/di    (the example env: its section in the file)
    eqhrl-train --params my.yaml --env-node none    (your own env node, started apart)

The nodes are the same classes `ros2 run` starts. Here each group (the env, the
expert or the person's nodes, the learner) has its own executor and thread, so the
learner's updates never delay a real-time env. With --expert-node teleop the person's
page (advice_console) starts too, unless --no-console. Ctrl-C saves a checkpoint;
--resume continues from it. An output folder that holds a run is refused unless
--resume or --overwrite is given.

Discovery: with the built-in expert the run is private to this process (ROS
discovery off), so two runs on one machine never exchange messages. A person's
expert (--expert-node teleop), your own expert or env node (none) must reach the nodes
from outside, so those runs use this machine's discovery (localhost). --discovery chooses.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

from ..core.algorithm.config import ADVICE_PROTOCOLS, MODES
from ..nodes.launching import ENV_NODES, env_node_for
from ..nodes.spinning import EXECUTORS
from .arguments import at_least, config_value

DISCOVERY = ('off', 'localhost', 'subnet')
EXPERT_NODES = ('expert', 'teleop', 'none')  # the launch file's expert:= takes the same names


class StartUpRefused(Exception):
    """A node refused the configuration (one line for the user, exit code 1)."""


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog='eqhrl-train', description=__doc__.split('\n')[0], formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    parser.add_argument(
        '--params', default='pendulum', help='params file: a path, or a name from share/eqhrl_ros/params'
    )
    parser.add_argument('--output', default=None, help='output folder (overrides learner output_dir)')
    parser.add_argument('--mode', choices=MODES, help='overrides learner mode')
    parser.add_argument('--episodes', type=at_least(0), help='overrides learner max_episodes (0: no limit)')
    parser.add_argument('--seed', type=config_value('seed'), help='overrides the env and learner seeds')
    parser.add_argument('--max-steps', type=at_least(1), help='overrides gym_env max_episode_steps')
    parser.add_argument('--budget', type=config_value('advising_budget'), help='overrides learner advising_budget')
    parser.add_argument(
        '--budget-s',
        type=config_value('advising_budget_s', float),
        help="overrides learner advising_budget_s (the person's seconds; 0: no limit)",
    )
    parser.add_argument(
        '--advice-protocol',
        choices=ADVICE_PROTOCOLS,
        help='overrides learner advice_protocol (auto: the wheel in a real-time env, one answer in lock-step)',
    )
    run_folder = parser.add_mutually_exclusive_group()
    run_folder.add_argument('--resume', action='store_true', help='continue from <output>/checkpoint.pt')
    run_folder.add_argument('--overwrite', action='store_true', help='replace a run already in the output folder')
    parser.add_argument('--record', action='store_true', help="write <output>/record.mcap (the learner's record: true)")
    parser.add_argument(
        '--prior',
        nargs='+',
        metavar='RUN_OR_MCAP',
        help="earlier runs (folders or .mcap files) whose advice seeds D and D_advising (the learner's prior)",
    )
    parser.add_argument(
        '--expert-node',
        choices=EXPERT_NODES,
        default='expert',
        help='which expert to start: the built-in/policy expert, the teleop expert '
        '(a person advises, e.g. with keyboard_teleop), or none',
    )
    parser.add_argument(
        '--no-console',
        action='store_true',
        help='with --expert-node teleop: do not start advice_console (the browser page for the person)',
    )
    parser.add_argument(
        '--env-node',
        choices=ENV_NODES,
        default=None,
        help='which env node to start: gym_env (a gymnasium env), double_integrator_env (the example '
        'env that is not gymnasium), or none (your own env node, started apart; the learner takes '
        'the spaces from its env_info or from the spaces parameters); default: the one the params '
        'file has a section for, else gym_env',
    )
    parser.add_argument(
        '--executor',
        choices=EXECUTORS,
        default=None,
        help='rclpy executor for each group of nodes (default: $EQHRL_EXECUTOR, else single)',
    )
    parser.add_argument(
        '--discovery',
        choices=DISCOVERY,
        default=None,
        help='who can reach these nodes: off (this process only; the default when the env and the '
        'expert are both in it), localhost (this machine; the default with --expert-node teleop or none, '
        'or --env-node none) or subnet (ROS_AUTOMATIC_DISCOVERY_RANGE)',
    )
    args = parser.parse_args(argv)
    if args.discovery is None:
        args.discovery = 'off' if args.expert_node == 'expert' and args.env_node != 'none' else 'localhost'
    return args


def learner_overrides(args) -> list:
    from rclpy.parameter import Parameter

    overrides = [Parameter('shutdown_when_done', value=True)]
    if args.output:
        overrides.append(Parameter('output_dir', value=str(args.output)))
    if args.mode:
        overrides.append(Parameter('mode', value=args.mode))
    if args.episodes is not None:
        overrides.append(Parameter('max_episodes', value=args.episodes))
    if args.seed is not None:
        overrides.append(Parameter('seed', value=args.seed))
    if args.budget is not None:
        overrides.append(Parameter('advising_budget', value=args.budget))
    if args.budget_s is not None:
        overrides.append(Parameter('advising_budget_s', value=args.budget_s))
    if args.advice_protocol:
        overrides.append(Parameter('advice_protocol', value=args.advice_protocol))
    if args.resume:
        overrides.append(Parameter('resume', value=True))
    if args.overwrite:
        overrides.append(Parameter('overwrite', value=True))
    if args.record:
        overrides.append(Parameter('record', value=True))
    if args.prior:
        overrides.append(Parameter('prior', value=[str(p) for p in args.prior]))
    return overrides


def make_nodes(args, nodes: list) -> tuple[list, object]:
    """The run's nodes, appended to ``nodes`` as they are made (so that a failure half-way still
    destroys those made): ([env group, expert group, learner group], the learner node)."""
    from rclpy.parameter import Parameter

    from ..nodes.expert_node import ExpertNode
    from ..nodes.gym_env_node import GymEnvNode
    from ..nodes.learner_node import LearnerNode
    from ..nodes.teleop_expert_node import TeleopExpertNode

    groups = []  # nodes spun together by one executor: env, experts, learner
    env_overrides = [Parameter('seed', value=args.seed)] if args.seed is not None else []
    if args.max_steps is not None:
        env_overrides.append(Parameter('max_episode_steps', value=args.max_steps))
    if args.env_node == 'gym_env':
        nodes.append(GymEnvNode(parameter_overrides=env_overrides))
    elif args.env_node == 'double_integrator_env':
        from ..nodes.double_integrator_env_node import DoubleIntegratorEnv

        nodes.append(DoubleIntegratorEnv(parameter_overrides=env_overrides))
    groups.append(list(nodes))
    if args.expert_node == 'expert':
        nodes.append(ExpertNode())
    elif args.expert_node == 'teleop':
        nodes.append(TeleopExpertNode())
        if not args.no_console:
            from ..nodes.advice_console_node import AdviceConsole

            nodes.append(AdviceConsole())
    groups.append(nodes[len(groups[0]) :])
    learner = LearnerNode(parameter_overrides=learner_overrides(args))
    nodes.append(learner)
    groups.append([learner])
    return groups, learner


def run(args):
    """Start, spin and stop the nodes; returns the learner node (None if it never started).

    Raises a start-up error (one line for the user) or ExitError (the last save failed).
    """
    # Set before the ROS context exists: rcl reads the discovery range when it is created.
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = args.discovery.upper()
    import rclpy

    from ..files.paths import params_file
    from ..files.yaml_files import load_mapping
    from ..nodes import spinning
    from ..nodes.run_files import save_and_close

    try:
        path = params_file(args.params)
        # rcl's own parser has no limits on size or depth
        args.env_node = env_node_for(load_mapping(path, 'params file'), args.env_node or '')
    except (FileNotFoundError, ValueError) as error:
        raise StartUpRefused(str(error)) from error
    stop = spinning.init(['--ros-args', '--params-file', str(path)], 'eqhrl-train')
    nodes = []
    learner = None
    try:
        try:
            groups, learner = make_nodes(args, nodes)
        except spinning.start_up_errors() as error:
            raise StartUpRefused(str(error)) from error
        executors = []
        for group in [[learner], *(g for g in groups[:-1] if g)]:  # the learner's in the main thread
            executor = spinning.make_executor(
                args.executor, coroutines=any(spinning.needs_coroutines(node) for node in group)
            )
            for node in group:
                executor.add_node(node)
            executors.append(executor)
        learner.get_logger().info(
            f'discovery: {args.discovery}'
            + (' (no node outside this process can reach this run; see --discovery)' if args.discovery == 'off' else '')
        )
        start = time.monotonic()
        # Returns at max_episodes (the learner shuts the context down) or on a signal.
        spinning.spin_apart(executors, stop)
        refused = [node.exit_error for node in nodes if getattr(node, 'exit_error', None)]
        if refused:
            raise StartUpRefused(refused[0])  # e.g. the env's env_info disagrees with a node
        if not learner.done:
            print('\ninterrupted: saving a checkpoint', file=sys.stderr)
        learner.wall_time_s = time.monotonic() - start
        return learner
    finally:
        try:
            if learner is not None:
                save_and_close(learner)
        finally:
            for node in nodes:
                node.destroy_node()
            rclpy.try_shutdown()
            stop.finished()


def train(argv=None) -> tuple[int, object]:
    """eqhrl-train's work, for the programs built on it (eqhrl-demo): its exit status, and the
    learner node that ran (None when it did not)."""
    args = parse_args(argv)
    from ..nodes.spinning import ExitError

    try:
        learner = run(args)
    except ExitError as error:
        print(f'eqhrl-train: {error}', file=sys.stderr)
        return 1, None
    except StartUpRefused as error:
        print(f'eqhrl-train: refused to start: {error}', file=sys.stderr)
        return 1, None
    episodes = learner.learner.episode if learner.learner is not None else 0
    print(f'done: {episodes} episodes in {learner.wall_time_s:.0f} s, results in {learner.output_dir}')
    return 0, learner


def main(argv=None) -> int:
    status, _ = train(argv)
    from ..nodes.spinning import end_process

    end_process(status)  # at once only while a compile_update compile still runs (see there)
    return status


if __name__ == '__main__':
    sys.exit(main())
