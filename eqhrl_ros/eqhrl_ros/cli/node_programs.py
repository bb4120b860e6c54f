"""The nodes' executables (`ros2 run eqhrl_ros <name>`, `.venv/bin/<name>`).

Each checks its own arguments before importing its node (torch, gymnasium: seconds),
so that ``--help`` prints the node's parameters at once and starts nothing. ROS
arguments go after ``--ros-args``, as for every ROS node; anything else before it is
refused.
"""

from __future__ import annotations

import importlib
import signal
import sys
from dataclasses import dataclass

from ..files.yaml_files import load_mapping

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@dataclass(frozen=True)
class NodeProgram:
    module: str  # eqhrl_ros.nodes.<module>, with main(args=None)
    params: tuple  # names of the parameter tables in eqhrl_ros/parameters.py
    summary: str


NODES = {
    'gym_env': NodeProgram(
        'gym_env_node',
        ('GYM_ENV_PARAMS',),
        'A gymnasium env behind the observation and action topics (lock-step or real time).',
    ),
    'learner': NodeProgram(
        'learner_node',
        ('LEARNER_CONFIG_PARAMS', 'LEARNER_NODE_PARAMS'),
        'SAC, QASAC or EQSAC on the observation topic; asks advise when the gates fire.',
    ),
    'actor': NodeProgram(
        'actor_node',
        ('LEARNER_CONFIG_PARAMS', 'ACTOR_NODE_PARAMS'),
        'Acts with the latest weights from a trainer, asks advise when the gates fire, sends its transitions.',
    ),
    'trainer': NodeProgram(
        'trainer_node',
        ('LEARNER_CONFIG_PARAMS', 'TRAINER_PARAMS'),
        'Learns from the transitions of any number of actor nodes and publishes their weights.',
    ),
    'policy_driver': NodeProgram(
        'policy_driver_node',
        ('POLICY_DRIVER_PARAMS',),
        'Drives the env with a policy a learner exported (policy.pt): deterministic, learning and asking nothing.',
    ),
    'expert': NodeProgram(
        'expert_node',
        ('EXPERT_PARAMS',),
        'Serves advise with a built-in controller or a policy file exported by a learner.',
    ),
    'teleop_expert': NodeProgram(
        'teleop_expert_node',
        ('TELEOP_EXPERT_PARAMS',),
        "Serves advise with a person's command (joy, cmd_vel or teleop_command).",
    ),
    'keyboard_teleop': NodeProgram(
        'keyboard_teleop_node',
        ('KEYBOARD_PARAMS',),
        'A terminal teleop for teleop_expert (source: array); needs a terminal.',
    ),
    'advice_console': NodeProgram(
        'advice_console_node',
        ('CONSOLE_PARAMS',),
        "The person's page in a browser: frames, requests, plots; keyboard and gamepad to teleop_expert.",
    ),
    # An example written as a user would write an env node: its parameters are its own PARAMETERS.
    'double_integrator_env': NodeProgram(
        'double_integrator_env_node',
        (),
        "An example env node that is not gymnasium: a point mass to bring to rest (x'' = u).",
    ),
}


# Titles of the README's parameter tables where a node has more than one table.
TABLE_TITLES = {
    'LEARNER_CONFIG_PARAMS': 'learner, actor and trainer: algorithm (core.LearnerConfig)',
    'LEARNER_NODE_PARAMS': 'learner: node',
    'ACTOR_NODE_PARAMS': 'actor: node',
    'TRAINER_PARAMS': 'trainer: node',
}


def node_tables(name: str) -> list:
    """[(title, params)] of a node: what --help prints and the package README's tables hold."""
    from .. import parameters as params

    program = NODES[name]
    tables = [(TABLE_TITLES.get(table, name), getattr(params, table)) for table in program.params]
    if not tables:  # the node's own PARAMETERS: (name, default, description, range)
        module = importlib.import_module(f'eqhrl_ros.nodes.{program.module}')
        own = tuple(params.Param(n, d, text, r) for n, d, text, r in module.PARAMETERS)
        tables = [(f'{name} (the example; its own PARAMETERS)', own)]
    return tables


def help_text(name: str) -> str:
    from .. import parameters as params

    program = NODES[name]
    tables = [table for _, table in node_tables(name)]
    return (
        f'usage: {name} [-h] [--ros-args [-p NAME:=VALUE ...] [--params-file FILE] [-r FROM:=TO ...]]\n\n'
        f'{program.summary}\n\n'
        'ROS parameters (= default [range] (choices); * may change while the node runs):\n'
        f'{params.describe(*tables)}\n\n'
        f'Example: ros2 run eqhrl_ros {name} --ros-args --params-file params/pendulum.yaml'
    )


def run(name: str, argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    own = argv[: argv.index('--ros-args')] if '--ros-args' in argv else argv
    if '-h' in own or '--help' in own:
        print(help_text(name))
        return 0
    if own:
        print(
            f'{name}: unrecognized argument(s): {" ".join(own)} (ROS arguments go after --ros-args; see {name} --help)',
            file=sys.stderr,
        )
        return 2
    # rcl parses params files with a parser of its own that has no limits (a 100,000-deep file
    # hangs it): each one is checked first, as every YAML file of this package is.
    ros_args = argv[argv.index('--ros-args') :] if '--ros-args' in argv else []
    for i, arg in enumerate(ros_args[:-1]):
        if arg == '--params-file':
            try:
                load_mapping(ros_args[i + 1], 'params file')
            except ValueError as error:
                print(f'{name}: {error}', file=sys.stderr)
                return 2
    # A Ctrl-C or SIGTERM while torch and rclpy import: nothing has started that needs stopping,
    # so the program ends quietly once the imports are done. (A KeyboardInterrupt raised inside
    # torch's import is swallowed there, and the node then started as if never stopped.)
    early = []
    previous = {sig: signal.signal(sig, lambda signum, frame: early.append(signum)) for sig in STOP_SIGNALS}
    try:
        module = importlib.import_module(f'eqhrl_ros.nodes.{NODES[name].module}')
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if early:
        return 0
    try:
        module.main()
    except KeyboardInterrupt:  # in the instant between the imports and the node's own handlers
        return 0
    return 0


def gym_env() -> int:
    return run('gym_env')


def learner() -> int:
    return run('learner')


def actor() -> int:
    return run('actor')


def trainer() -> int:
    return run('trainer')


def expert() -> int:
    return run('expert')


def teleop_expert() -> int:
    return run('teleop_expert')


def keyboard_teleop() -> int:
    return run('keyboard_teleop')


def advice_console() -> int:
    return run('advice_console')


def double_integrator_env() -> int:
    return run('double_integrator_env')


def policy_driver() -> int:
    return run('policy_driver')
