"""Start env, expert and learner with one params file.

ros2 launch eqhrl_ros train.launch.py env:=pendulum
ros2 launch eqhrl_ros train.launch.py env:=lunar_lander mode:=qasac
ros2 launch eqhrl_ros train.launch.py params_file:=/path/to/my.yaml
ros2 launch eqhrl_ros train.launch.py env:=double_integrator   (the example env: its section in the file)
ros2 launch eqhrl_ros train.launch.py params_file:=/path/to/my.yaml env_node:=none   (your own env node)
    env_node:= defaults to the env node the params file has a section for (gym_env: or
    double_integrator_env:), gym_env when it has neither
ros2 launch eqhrl_ros train.launch.py env:=teleop_pendulum expert:=teleop   (a person advises)
    with expert:=teleop the person's page starts too (advice_console, http://127.0.0.1:8080/);
    console:=false leaves it out (keyboard_teleop or a joystick instead)
ros2 launch eqhrl_ros train.launch.py env:=pendulum resume:=true   (after Ctrl-C: go on with the run)
    output_dir:= (default: the params file's), resume:=true, overwrite:=true go to the learner
ros2 launch eqhrl_ros train.launch.py env:=pendulum use_sim_time:=true   (every node on /clock's time)
ros2 launch eqhrl_ros train.launch.py env:=pendulum key_file:=$HOME/eqhrl.key   (advice signed with the key)
Included by your launch file under a PushRosNamespace (one group per robot), each node gets the
params file's sections for it, a bare learner: section included (rcl alone would give it to
/learner only).
"""

import os

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from eqhrl_ros.core.algorithm.config import MODES
from eqhrl_ros.files.paths import params_file as shipped_params_file
from eqhrl_ros.files.yaml_files import load_mapping
from eqhrl_ros.nodes.launching import (
    env_node_for,
    fail_launch_on_error,
    flag,
    namespace_of,
    node_parameters,
    shared_arguments,
    sim_time,
    warn_undeclared,
)

# expert:=... -> the executable it starts (none: your own expert, started apart).
EXPERT_NODES = {'expert': 'expert', 'teleop': 'teleop_expert', 'none': None}


def _nodes(context, declared):
    warn_undeclared(context.argv, declared, own_file=__file__)
    env = LaunchConfiguration('env').perform(context)
    # params_file:=~/mine.yaml: no shell expands a ~ inside an argument
    params_file = os.path.expanduser(LaunchConfiguration('params_file').perform(context)) or str(
        shipped_params_file(env)
    )
    mode = LaunchConfiguration('mode').perform(context)
    if mode and mode not in MODES:
        raise ValueError(f'mode:={mode} is not one of {", ".join(MODES)}')
    data = load_mapping(params_file, 'params file')
    env_node = env_node_for(data, LaunchConfiguration('env_node').perform(context))
    # Included under another launch file's PushRosNamespace: each node gets its sections as a mapping.
    namespace = namespace_of(context)
    clock = sim_time(context)  # use_sim_time:=, on every node

    key_file = LaunchConfiguration('key_file').perform(context)  # the deployment's shared secret

    def parameters(name):
        keyed = [{'key_file': key_file}] if key_file and name != env_node else []
        return [*node_parameters(data, name, namespace), *([clock] if clock else []), *keyed]

    expert = LaunchConfiguration('expert').perform(context)
    if expert not in EXPERT_NODES:
        raise ValueError(f'expert:={expert} is not one of {", ".join(EXPERT_NODES)}')
    console = 'true' if flag('console', LaunchConfiguration('console').perform(context)) else 'false'
    run = {name: flag(name, LaunchConfiguration(name).perform(context)) for name in ('resume', 'overwrite')}
    output_dir = LaunchConfiguration('output_dir').perform(context)
    given = {'mode': mode, 'output_dir': output_dir, **run}  # what the launch's arguments set on the learner
    learner_params = [*parameters('learner'), {name: value for name, value in given.items() if value}]
    experts = (
        [
            Node(
                package='eqhrl_ros',
                executable=EXPERT_NODES[expert],
                name=EXPERT_NODES[expert],
                parameters=parameters(EXPERT_NODES[expert]),
                output='screen',
            )
        ]
        if EXPERT_NODES[expert]
        else []
    )
    if expert == 'teleop' and console == 'true':  # the person's page in a browser
        experts.append(
            Node(
                package='eqhrl_ros',
                executable='advice_console',
                name='advice_console',
                parameters=parameters('advice_console'),
                output='screen',
            )
        )
    env = (
        [
            Node(
                package='eqhrl_ros',
                executable=env_node,
                name=env_node,
                parameters=parameters(env_node),
                output='screen',
            )
        ]
        if env_node != 'none'
        else []  # your own env node, started apart: the others take the spaces from its env_info
    )
    nodes = [
        *env,
        *experts,
        Node(
            package='eqhrl_ros',
            executable='learner',
            name='learner',
            parameters=learner_params,
            output='screen',
            emulate_tty=True,
        ),
    ]
    # A node that refuses to start (or fails later) stops the launch, which then exits non-zero.
    return [*nodes, *(fail_launch_on_error(node) for node in nodes)]


def generate_launch_description():
    arguments = [
        *shared_arguments('learner'),
        DeclareLaunchArgument(
            'mode',
            default_value='',
            description=f'the learning mode, one of {", ".join(MODES)} (overrides the params file)',
        ),
        DeclareLaunchArgument(
            'expert',
            default_value='expert',
            description='who advises: expert (the built-in controller or a policy), teleop (a person, '
            'through teleop_expert; start keyboard_teleop or a joystick apart), or none (your own)',
        ),
        DeclareLaunchArgument(
            'console',
            default_value='true',
            description="with expert:=teleop: start advice_console, the person's page in a browser",
        ),
    ]
    declared = [argument.name for argument in arguments]
    return LaunchDescription([*arguments, OpaqueFunction(function=_nodes, kwargs={'declared': declared})])
