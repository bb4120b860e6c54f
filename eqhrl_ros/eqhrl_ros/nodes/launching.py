"""What the package's launch files share: a node that exits with an error ends the launch with one.

`ros2 launch` exits 0 when a node it started exits with an error (a trainer that refuses a bad
parameter, a learner whose checkpoint is corrupt), so a script or a service manager would take
a run that never began for one that ended well. An exception raised by an event handler makes
the launch shut everything down and exit non-zero, with the reason in its log.
"""

from __future__ import annotations

import sys


def refusal_reason(process_name: str, returncode) -> str:
    """Why the launch stops, or '' when ``returncode`` is a normal end (0) or a signal (negative:
    the launch's own SIGINT or SIGTERM at shutdown)."""
    if returncode is None or returncode <= 0:
        return ''
    return f'{process_name} exited with code {returncode} (its log above says why): stopping the launch'


def fail_launch_on_error(node):
    """An action to add beside ``node`` in a launch description: when the node's process exits
    with an error, the launch stops and `ros2 launch` exits non-zero."""
    from launch.actions import RegisterEventHandler
    from launch.event_handlers import OnProcessExit

    def on_exit(event, context):
        reason = refusal_reason(getattr(event, 'process_name', '?'), event.returncode)
        if reason:
            raise RuntimeError(reason)

    return RegisterEventHandler(OnProcessExit(target_action=node, on_exit=on_exit))


def shared_arguments(whose: str) -> list:
    """The launch arguments both launch files take, declared once: the params file (``env`` by
    name, or ``params_file``), and the run's folder for the node that saves (``whose``: 'learner' or
    'trainer'): ``output_dir``, ``resume``, ``overwrite`` (before, given to the launch, these went
    unheard, and a second launch was refused the folder of the first); the env node to start
    (``env_node``, for each actor in actors.launch.py), ``use_sim_time`` for every node, and
    ``key_file`` for every node that signs or checks what it sends and receives."""
    from launch.actions import DeclareLaunchArgument

    from ..files.paths import shipped

    each, where = (' for each actor', " in each actor's namespace") if whose == 'trainer' else ('', '')
    env_node = (
        f'env node to start{each}: {", ".join(ENV_NODES)} (none: your own, started apart{where}); '
        'default: the one the params file has a section for, else gym_env'
    )
    return [
        DeclareLaunchArgument(
            'env', default_value='pendulum', description=f'params file name: {", ".join(shipped("params"))}'
        ),
        DeclareLaunchArgument('params_file', default_value='', description='a params file path (overrides env)'),
        DeclareLaunchArgument(
            'output_dir', default_value='', description=f"the {whose}'s output folder (default: the params file's)"
        ),
        DeclareLaunchArgument(
            'resume', default_value='false', description=f"continue the {whose}'s run (after Ctrl-C)"
        ),
        DeclareLaunchArgument('overwrite', default_value='false', description=f"replace the {whose}'s run"),
        DeclareLaunchArgument('env_node', default_value='', description=env_node),
        DeclareLaunchArgument(
            'use_sim_time',
            default_value='',
            description='true: every node takes its ROS time from /clock (a simulator); false: from the '
            "system; empty: as the params file or an including launch file's SetParameter says",
        ),
        DeclareLaunchArgument(
            'key_file',
            default_value='',
            description="the deployment's shared key (a file), given to every node started here but the env: "
            'each signs what it sends and refuses what comes unsigned (README, Security)',
        ),
    ]


def sim_time(context) -> dict:
    """What ``use_sim_time:=`` sets on every node the launch starts: {} when not given, so that
    the params file (or an including file's SetParameter) decides. Given, it outranks both, as the
    launch's own output_dir:= and mode:= do."""
    from launch.substitutions import LaunchConfiguration

    value = LaunchConfiguration('use_sim_time').perform(context)
    return {'use_sim_time': flag('use_sim_time', value)} if value else {}


def count(name: str, value: str) -> int:
    """A launch argument ``name:=value`` that counts something (0 or more); ValueError naming it
    otherwise (before, `actors:=abc` said only "invalid literal for int() with base 10")."""
    try:
        number = int(value)
    except ValueError:
        number = -1
    if number < 0:
        raise ValueError(f'{name}:={value} is not a whole number, 0 or more')
    return number


def flag(name: str, value: str) -> bool:
    """A true/false launch argument ``name:=value``; ValueError naming it otherwise."""
    if value.lower() not in ('true', 'false'):
        raise ValueError(f'{name}:={value} is not true or false')
    return value.lower() == 'true'


def undeclared(argv, declared) -> list:
    """The names of the ``name:=value`` arguments in ``argv`` (ros2 launch's command line) that the
    launch file does not declare: ros2 launch ignores them without a word."""
    return sorted({a.split(':=', 1)[0] for a in argv or () if ':=' in a} - set(declared))


def named_on_command_line(own_file, argv=None) -> bool:
    """Whether the launch file ``own_file`` is the one `ros2 launch` was given (True too where launch
    runs in-process, not from ros2 launch): False when it is included by another launch file,
    whose command line it sees."""
    from pathlib import Path

    argv = sys.argv if argv is None else argv
    if 'launch' not in argv[1:3]:
        return True
    words = [a for a in argv[argv.index('launch') + 1 :] if not a.startswith('-') and ':=' not in a]
    return Path(own_file).name in {Path(word).name for word in words}


def warn_undeclared(argv, declared, own_file='') -> str:
    """A warning in the launch's log for each argument given that the file does not take (before,
    `output_dir:=` and `overwrite:=` went unheard, and the learner refused the folder of the last
    run). None where ``own_file`` is included by another launch file: the command line's arguments
    are that file's (before, each was called ignored). Returns the line ('' when none)."""
    unknown = undeclared(argv, declared)
    if not unknown or (own_file and not named_on_command_line(own_file)):
        return ''
    from launch.logging import get_logger

    line = (
        f'ignored: {", ".join(name + ":=" for name in unknown)} (this launch file takes {", ".join(declared)}; '
        'any other parameter of a node goes in the params file: params_file:=)'
    )
    get_logger('launch').warning(line)
    return line


def namespace_of(context) -> str:
    """The namespace a launch file including this one pushed (PushRosNamespace), as /robot1, or ''."""
    namespace = context.launch_configurations.get('ros_namespace', '').strip('/')
    return f'/{namespace}' if namespace else ''


def in_namespace(topic: str, default: str, pushed: str) -> str:
    """A launch argument's topic: the default moved into the pushed namespace, one given kept."""
    return pushed + default if topic == default and pushed else topic


def node_parameters(data: dict, name: str, namespace: str) -> list:
    """What a launch file passes as ``parameters`` to its node ``name``: the params file's sections
    for the node as one mapping, read as rcl reads them; in a namespace that a launch file
    including this one pushed (PushRosNamespace), its bare `name:` section included.

    Never the file itself. rcl reads `learner:` as /learner: included under /robot1, every node
    ran on its defaults. And rcl applies a node's own section after every `/**` value, in the
    order each name first came: under an including file's SetParameter (launch_ros puts it first,
    as `-p`, in `/**`), the file's `learner:` section beat the launch's own output_dir:= and mode:=,
    which launch_ros passes in `/**` too (2026-12-05)."""
    from ..parameters import file_section

    return [file_section(data, name, namespace)]


# dds_profile:= of the launch files: a name shipped in share/eqhrl_ros/config, or an XML path.
DDS_PROFILES = {'lossy_link': 'fastdds_lossy_link.xml'}
DDS_PROFILE_VARIABLE = 'FASTRTPS_DEFAULT_PROFILES_FILE'  # what Fast DDS 2.x (ROS 2 Jazzy) reads


def dds_profile_env(value: str, share_dir) -> dict:
    """The environment that gives every node a Fast DDS profile: {} for '' (the environment as it
    is), the shipped profile for a name of DDS_PROFILES, else ``value`` as a path to an XML file."""
    from pathlib import Path

    if not value:
        return {}
    path = Path(share_dir) / 'config' / DDS_PROFILES[value] if value in DDS_PROFILES else Path(value)
    if not path.is_file():
        names = ', '.join(DDS_PROFILES)
        raise ValueError(f'dds_profile:={value} is neither one of {names} nor an XML file')
    return {DDS_PROFILE_VARIABLE: str(path)}


# The env nodes eqhrl-train and train.launch.py start (none: your own env node, started apart).
ENV_NODES = ('gym_env', 'double_integrator_env', 'none')


def env_node_for(params: dict, given: str = '') -> str:
    """Which env node to start with the parsed params file ``params``: ``given`` when set; else the
    shipped env node the file has a section for (params/double_integrator.yaml starts the example
    env, with no flag to forget); gym_env when it has neither. ValueError for a name not in
    ENV_NODES, and for a file with a section for both (which one is meant cannot be told)."""
    if given:
        if given not in ENV_NODES:
            raise ValueError(f'env node {given!r} is not one of {", ".join(ENV_NODES)}')
        return given
    from ..parameters import flat_sections, section_applies

    params = flat_sections(params)  # the nested form too, as rcl reads it

    def named(key: str, name: str) -> bool:  # a section for that node: `name:`, `/name:`, `/**/name:`
        return key.rstrip('/').split('/')[-1] == name and section_applies(key, f'/{name}')

    sections = [name for name in ENV_NODES[:-1] if any(named(str(key), name) for key in params)]
    if len(sections) > 1:
        raise ValueError(
            f'the params file has a section for each of {" and ".join(sections)}: say which env node to start '
            '(env_node:= for ros2 launch, --env-node for eqhrl-train)'
        )
    return sections[0] if sections else 'gym_env'
