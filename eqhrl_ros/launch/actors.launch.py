"""Acting apart from learning: N actors, each with its own env and expert, and one trainer.

ros2 launch eqhrl_ros actors.launch.py env:=pendulum actors:=2
ros2 launch eqhrl_ros actors.launch.py env:=pendulum actors:=2 trainer:=false   (actors only: the
    trainer runs on another machine in the same ROS domain)
ros2 launch eqhrl_ros actors.launch.py env:=pendulum actors:=0                   (the trainer only)

Actor i runs in namespace /<actor_prefix><actor_offset + i>: e.g. /actor0/gym_env, /actor0/expert,
/actor0/actor. actor_prefix defaults to `actor` where this launch starts the trainer too (one
machine), and to `<hostname>_actor` where it does not (a robot machine: two robots launched
alike never share a name). actor_offset shifts the indices and the seeds alike.
All actors send to /transitions and take /weights (transitions_topic:=, weights_topic:= remap
both sides, for several trainers in one domain; included by a launch file under a namespace,
/<namespace>/transitions and /<namespace>/weights, and the actors are /<namespace>/actor0/actor,
...); resume:=true continues the trainer's run,
overwrite:=true replaces it, output_dir:= moves it (default: the params file's learner output_dir);
dds_profile:=lossy_link gives every node the Fast DDS profile for hosts on a lossy link;
use_sim_time:=true puts every node on /clock's time.
The trainer takes transitions only from actors it knows: those started here, the full names in
trainer_actors:= (actors on other machines), or any that signs with key_file:=. A node that exits
with an error (a trainer refusing to start) stops the launch, which exits non-zero.
env_node:=none starts no env node: your own runs in each actor's namespace (/actor0/...).
One params file configures everything:
its learner: section gives the algorithm to the actors and the trainer (and each the keys of
its own table); gym_env: (or double_integrator_env:, which starts the example env instead) and
expert: go to every actor's env and expert; /**: to all. Actor i
runs with seed + i (its env's start states and its action noise differ from the others'). With
camera: in the learner: section (and the camera in gym_env:), the actors read it and the
trainer is given no env_id: it takes its spaces and camera from the actors' first batch.
"""

import os
import re
import socket

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from eqhrl_ros.files.paths import params_file as shipped_params_file
from eqhrl_ros.files.yaml_files import load_mapping
from eqhrl_ros.nodes.launching import (
    count,
    dds_profile_env,
    env_node_for,
    fail_launch_on_error,
    flag,
    in_namespace,
    namespace_of,
    shared_arguments,
    sim_time,
    warn_undeclared,
)
from eqhrl_ros.parameters import (
    ACTOR_NODE_PARAMS,
    SPACE_PARAMS,
    TRAINER_PARAMS,
    flat_sections,
    learner_section_for,
    section_applies,
)

# What a trainer is told of the env; camera actors' trainer takes it (and the camera) from their batches.
ENV_NAMES = ('env_id', *(p.name for p in SPACE_PARAMS))


def _section(data: dict, name: str, pushed: str = '') -> dict:
    """The parameters of the file's sections for node ``name`` in the namespace this launch was
    included in (`name:`, `/name:`, `/**/name:`; under a pushed `/robot1`, also `/robot1/name:`),
    or of `/**` itself; the launch passes them to its namespaced nodes."""
    data = flat_sections(data)  # the nested form too, as rcl reads it
    keys = [k for k in data if k == name or (name != '/**' and str(k).rstrip('/').split('/')[-1] == name)]
    merged = {}
    for key in keys:
        if key == name or section_applies(str(key), f'{pushed}/{name}'):
            merged.update((data.get(key) or {}).get('ros__parameters') or {})
    return merged


def _prefix(given: str, with_trainer: bool) -> str:
    """The actors' namespace prefix: as given, or one no other machine launched alike can have."""
    if given:
        return given
    if with_trainer:
        return 'actor'
    host = re.sub(r'[^a-z0-9_]', '_', socket.gethostname().lower()).strip('_') or 'host'
    return f'{"h" + host if host[0].isdigit() else host}_actor'


def _nodes(context, declared):
    warn_undeclared(context.argv, declared, own_file=__file__)
    env = LaunchConfiguration('env').perform(context)
    # params_file:=~/mine.yaml: no shell expands a ~ inside an argument
    params_file = os.path.expanduser(LaunchConfiguration('params_file').perform(context)) or str(
        shipped_params_file(env)
    )
    data = load_mapping(params_file, 'params file')  # refused in one line, as the nodes refuse it
    # Included under another launch file's PushRosNamespace (one fleet per robot group): the actors'
    # full names and the default topics are in it (before, the trainer refused every batch of
    # /robot1/actor0/actor, which was not its /actor0/actor), and so are the file's sections.
    pushed = namespace_of(context)
    shared = _section(data, '/**')
    learner = _section(data, 'learner', pushed)
    actors = count('actors', LaunchConfiguration('actors').perform(context))
    with_trainer = 'true' if flag('trainer', LaunchConfiguration('trainer').perform(context)) else 'false'
    with_expert = 'true' if flag('expert', LaunchConfiguration('expert').perform(context)) else 'false'

    offset = count('actor_offset', LaunchConfiguration('actor_offset').perform(context))
    run = {name: flag(name, LaunchConfiguration(name).perform(context)) for name in ('resume', 'overwrite')}
    output_dir = LaunchConfiguration('output_dir').perform(context)
    prefix = _prefix(LaunchConfiguration('actor_prefix').perform(context), with_trainer == 'true')
    key = {'key_file': LaunchConfiguration('key_file').perform(context)}  # the deployment's shared secret
    # Fast DDS for a lossy link between hosts (docs/performance.md, "Weights over a lossy link").
    dds = dds_profile_env(LaunchConfiguration('dds_profile').perform(context), get_package_share_directory('eqhrl_ros'))
    clock = sim_time(context)  # use_sim_time:=, on every node
    remaps = [
        (f'/{topic}', in_namespace(LaunchConfiguration(f'{topic}_topic').perform(context), f'/{topic}', pushed))
        for topic in ('transitions', 'weights')
    ]

    def node(executable: str, parameters: dict, **options):
        """One of the package's nodes, named as its executable, with the launch's DDS profile."""
        return Node(
            package='eqhrl_ros',
            executable=executable,
            name=executable,
            parameters=[{**parameters, **clock}],
            additional_env=dds,
            **options,
        )

    nodes = []
    if with_trainer == 'true':
        trainer = {**shared, **learner_section_for(learner, TRAINER_PARAMS), **key}
        if learner.get('camera'):  # actors that see: the trainer learns the camera from their first batch
            trainer = {name: value for name, value in trainer.items() if name not in ENV_NAMES}
        # Whom the trainer hears: the actors named, else those started here (with a key_file, also
        # any actor that signs with it). Neither, and no key: it refuses to start, and says why.
        named = [a.strip() for a in LaunchConfiguration('trainer_actors').perform(context).split(',') if a.strip()]
        here = [f'{pushed}/{prefix}{i}/actor' for i in range(offset, offset + actors)]
        if named or here:
            trainer['actors'] = named or here
        trainer.update({name: True for name, given in run.items() if given})
        if output_dir:
            trainer['output_dir'] = output_dir
        nodes.append(node('trainer', trainer, remappings=remaps, output='screen'))
    # env_node:= names it; else the file's gym_env: or double_integrator_env: section says which
    env_node = env_node_for(data, LaunchConfiguration('env_node').perform(context))
    env_params = {**shared, **_section(data, env_node, pushed)}
    actor_params = {**shared, **learner_section_for(learner, ACTOR_NODE_PARAMS)}
    for i in range(offset, offset + actors):
        ns = f'{prefix}{i}'
        env_i = {**env_params, 'seed': int(env_params.get('seed', 42)) + i}
        actor_i = {**actor_params, 'seed': int(actor_params.get('seed', 42)) + i, **key}
        if env_node != 'none':  # none: your own env node, started apart in the actor's namespace
            nodes.append(node(env_node, env_i, namespace=ns))
        if with_expert == 'true':
            expert = {**shared, **_section(data, 'expert', pushed), **key}  # answers only requests signed with it
            nodes.append(node('expert', expert, namespace=ns))
        nodes.append(node('actor', actor_i, namespace=ns, remappings=remaps, output='screen'))
    # A node that refuses to start (or fails later) stops the launch, which then exits non-zero.
    return [*nodes, *(fail_launch_on_error(node) for node in nodes)]


def generate_launch_description():
    arguments = [
        *shared_arguments('trainer'),
        DeclareLaunchArgument('actors', default_value='2', description='actors to start, each with env and expert'),
        DeclareLaunchArgument('trainer', default_value='true', description='start the trainer here'),
        DeclareLaunchArgument(
            'expert', default_value='true', description="start each actor's expert (false: your own, per actor)"
        ),
        DeclareLaunchArgument(
            'actor_prefix',
            default_value='',
            description="actors' namespace prefix (empty: actor with the trainer here, <hostname>_actor without)",
        ),
        DeclareLaunchArgument(
            'actor_offset', default_value='0', description='index of the first actor here (its seed follows)'
        ),
        DeclareLaunchArgument(
            'trainer_actors',
            default_value='',
            description='actors the trainer takes transitions from, comma-separated full names '
            '(/host_a_actor0/actor,...; default: those started here; with key_file, any that signs)',
        ),
        DeclareLaunchArgument('transitions_topic', default_value='/transitions', description='remap /transitions'),
        DeclareLaunchArgument('weights_topic', default_value='/weights', description='remap /weights'),
        DeclareLaunchArgument(
            'dds_profile',
            default_value='',
            description='Fast DDS profile for every node: lossy_link (hosts on Wi-Fi or a lossy link: '
            'share/eqhrl_ros/config/fastdds_lossy_link.xml), an XML path, or empty (the environment as it is)',
        ),
    ]
    declared = [argument.name for argument in arguments]
    return LaunchDescription([*arguments, OpaqueFunction(function=_nodes, kwargs={'declared': declared})])
