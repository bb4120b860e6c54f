"""The real `ros2` CLI and `ros2 launch` over the colcon install, as a user with a ROS 2 Jazzy
install runs them: both launch files, `ros2 run`, `ros2 topic echo/hz`, `ros2 param set/get`,
`ros2 service call`, and Ctrl-C as a terminal sends it (to the launch and every node at once).

launch, launch_ros and ros2cli are not on PyPI: the session's ros2_env fixture (conftest.py)
skips these tests, in one line, where they are not installed."""

import csv
import os
import shutil
import signal
import subprocess
import time

import pytest

from eqhrl_ros.core.algorithm.config import MODES

from process_helpers import settled, wait_for

pytestmark = pytest.mark.slow


class Launched:
    """A command in a process group of its own, as a terminal's foreground job: Ctrl-C reaches
    the command and all it started."""

    def __init__(self, args, cwd, env, name='launch'):
        # The command appends to its log (O_APPEND) and the test reads it through a handle of its
        # own: reading through the command's handle moved their shared offset back to the start,
        # and the command's next lines overwrote its first ones.
        self.path = cwd / f'{name}-{time.monotonic_ns()}.log'
        self.log = open(self.path, 'a')
        self.process = subprocess.Popen(
            args, cwd=cwd, env=env, stdout=self.log, stderr=subprocess.STDOUT, text=True, start_new_session=True
        )

    def text(self) -> str:
        return self.path.read_text(errors='replace')

    @property
    def ended(self) -> bool:
        return self.process.poll() is not None

    def signal(self, sig) -> None:
        try:
            os.killpg(self.process.pid, sig)
        except ProcessLookupError:
            pass

    def ctrl_c(self, timeout=60) -> int:
        self.signal(signal.SIGINT)
        try:
            return self.process.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.signal(signal.SIGKILL)
            self.process.wait()
            raise AssertionError(f'still running {timeout} s after Ctrl-C:\n{self.text()[-3000:]}') from None

    def close(self) -> None:
        if self.process.poll() is None:
            self.signal(signal.SIGKILL)
            self.process.wait()
        self.final_text = self.text()
        self.log.close()


def rows(path):
    if not path.exists():
        return []
    with path.open(newline='') as f:
        return list(csv.DictReader(f))


def ros2(env, *args, timeout=60) -> str:
    result = subprocess.run(['ros2', *args], env=env, capture_output=True, text=True, timeout=timeout)
    assert result.returncode == 0, f'ros2 {" ".join(args)}: {result.stdout[-2000:]}{result.stderr[-2000:]}'
    return result.stdout


def test_actors_launch_on_one_host_trains_and_its_ctrl_c_loses_no_episode(ros2_env, tmp_path):
    """`ros2 launch eqhrl_ros actors.launch.py` (launch_ros writes each node's parameters to a
    temporary file with yaml.dump: lists as !!python/tuple, which the nodes refused before), then
    a Ctrl-C to the whole group: every episode the actor finished is in the record once."""
    launch = Launched(['ros2', 'launch', 'eqhrl_ros', 'actors.launch.py', 'env:=demo', 'actors:=1'], tmp_path, ros2_env)
    out = tmp_path / 'runs' / 'demo' / 'episodes.csv'
    try:
        assert wait_for(lambda: len(rows(out)) >= 4 or launch.ended, 180) and not launch.ended, launch.text()[-4000:]
        assert launch.ctrl_c() == 0, launch.text()[-4000:]
    finally:
        launch.close()
    text = launch.text()
    finished = text.count('] [actor0.actor]: episode ')
    assert finished >= 4 and len(rows(out)) == finished, (finished, len(rows(out)), text[-3000:])
    assert [r['actor'] for r in rows(out)] == ['/actor0/actor'] * finished
    assert ', 0 not stored by the trainer, ' in text, text[-3000:]
    assert 'Traceback' not in text and 'python/tuple' not in text, text[-3000:]
    for node in ('trainer-1', 'gym_env-2', 'expert-3', 'actor-4'):
        assert f'[INFO] [{node}]: process has finished cleanly' in text, text[-3000:]


LAUNCH_NODES = """
import sys
from launch import LaunchContext
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.launch_description_sources import get_launch_description_from_python_launch_file
from launch_ros.actions import Node

description = get_launch_description_from_python_launch_file(sys.argv[1])
context = LaunchContext()
given = dict(argument.split(':=', 1) for argument in sys.argv[2:])
for entity in description.entities:
    if isinstance(entity, DeclareLaunchArgument):
        default = entity.default_value[0].perform(context) if entity.default_value else ''
        context.launch_configurations[entity.name] = given.get(entity.name, default)
actions = [a for e in description.entities if isinstance(e, OpaqueFunction) for a in e.execute(context)]
print(' '.join(a.node_executable for a in actions if isinstance(a, Node)))
"""


LAUNCH_PARAMETERS = LAUNCH_NODES.replace(
    'context = LaunchContext()', 'context = LaunchContext(argv=sys.argv[2:])'
).replace(
    "print(' '.join(a.node_executable for a in actions if isinstance(a, Node)))",
    """from launch_ros.utilities import evaluate_parameters
for a in actions:
    if isinstance(a, Node) and a.node_executable in ('learner', 'trainer'):
        dicts = [p for p in evaluate_parameters(context, a._Node__parameters) if isinstance(p, dict)]
        given = {k: v for p in dicts for k, v in p.items()}
        run = sorted((k, v) for k, v in given.items() if k in ('output_dir', 'resume', 'overwrite'))
        print(a.node_executable, run)""",
)


@pytest.mark.parametrize('launch_file,node', [('train.launch.py', 'learner'), ('actors.launch.py', 'trainer')])
def test_the_launch_files_take_the_runs_folder_resume_and_overwrite_and_warn_of_what_they_do_not_take(
    ros2_env, colcon_install, launch_file, node
):
    """From outside: a second `ros2 launch eqhrl_ros train.launch.py env:=pendulum` was refused (the
    folder holds a run: 'resume it (resume:=true ...) or replace it (overwrite:=true ...)'), and
    resume:=true, overwrite:=true and output_dir:= given to the launch went unheard, without a word."""
    path = colcon_install / 'eqhrl_ros' / 'share' / 'eqhrl_ros' / 'launch' / launch_file

    def evaluated(*arguments):
        command = ['python3', '-c', LAUNCH_PARAMETERS, str(path), 'env:=demo', 'actors:=1', *arguments]
        return subprocess.run(command, env=ros2_env, capture_output=True, text=True, timeout=60)

    result = evaluated('output_dir:=/tmp/elsewhere', 'resume:=true', 'ouput_dir:=/tmp/typo')
    line = next((x for x in result.stdout.splitlines() if x.startswith(f'{node} [')), '')
    assert result.returncode == 0 and "('output_dir', '/tmp/elsewhere')" in line, result.stdout + result.stderr[-2000:]
    assert "('resume', True)" in line and 'overwrite' not in line, line
    said = result.stdout + result.stderr  # launch's log: a warning line
    assert 'ouput_dir:= (this launch file takes env, params_file' in said, said[-2000:]
    if launch_file == 'train.launch.py':  # actors:= is the other file's: said for this one
        assert 'ignored: actors:=, ouput_dir:=' in said, said[-2000:]
    assert "('overwrite', True)]" in evaluated('overwrite:=true').stdout
    refused = evaluated('resume:=maybe')
    assert refused.returncode != 0 and 'resume:=maybe is not true or false' in refused.stderr
    if launch_file == 'actors.launch.py':  # before: "invalid literal for int() with base 10: 'abc'"
        refused = evaluated('actor_offset:=abc')
        assert refused.returncode != 0 and 'actor_offset:=abc is not a whole number, 0 or more' in refused.stderr


LAUNCH_IN_NAMESPACE = """
import sys
from launch import LaunchContext
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.launch_description_sources import get_launch_description_from_python_launch_file
from launch_ros.actions import Node
from launch.utilities import perform_substitutions
from launch_ros.utilities import evaluate_parameters

path, command_line, given = sys.argv[1], sys.argv[2].split(), dict(a.split(':=', 1) for a in sys.argv[3:])
sys.argv = ['ros2', 'launch', *command_line]  # what ros2 launch was given: the including file
description = get_launch_description_from_python_launch_file(path)
context = LaunchContext(argv=[a for a in command_line if ':=' in a])
context.launch_configurations['ros_namespace'] = '/robot1'  # the including file's PushRosNamespace
for entity in description.entities:
    if isinstance(entity, DeclareLaunchArgument):
        default = entity.default_value[0].perform(context) if entity.default_value else ''
        context.launch_configurations[entity.name] = given.get(entity.name, default)
actions = [a for e in description.entities if isinstance(e, OpaqueFunction) for a in e.execute(context)]
for a in actions:
    if isinstance(a, Node):
        dicts = [p for p in evaluate_parameters(context, a._Node__parameters) if isinstance(p, dict)]
        remaps = [tuple(perform_substitutions(context, x) for x in rule) for rule in a._Node__remappings]
        print(a.node_executable, sorted((k, v) for p in dicts for k, v in p.items()), remaps)
"""


def test_the_launch_files_included_under_a_namespace_give_their_nodes_their_sections_names_and_topics(
    ros2_env, colcon_install, tmp_path
):
    """From outside: train.launch.py included by a launch file of several robots, each under its
    PushRosNamespace. rcl reads the file's `learner:` as /learner, so /robot1/learner and the others
    ran on their defaults (each node warned so), and the including file's own arguments were each
    said to be ignored."""
    path = colcon_install / 'eqhrl_ros' / 'share' / 'eqhrl_ros' / 'launch' / 'train.launch.py'
    params = tmp_path / 'mine.yaml'
    params.write_text(
        "'/**':\n  ros__parameters: {use_sim_time: false}\n"
        'double_integrator_env:\n  ros__parameters: {max_episode_steps: 33}\n'
        'expert:\n  ros__parameters: {backend: heuristic}\n'
        'learner:\n  ros__parameters: {mode: qasac, learning_starts: 123}\n'
        '/robot2/learner:\n  ros__parameters: {learning_starts: 999}\n'
        '/robot1/learner:\n  ros__parameters: {batch_size: 64}\n'
    )

    def evaluated(command_line, launch_file='train.launch.py', *arguments):
        command = [
            *('python3', '-c', LAUNCH_IN_NAMESPACE, str(path.with_name(launch_file)), command_line),
            *(f'params_file:={params}', *arguments),
        ]
        result = subprocess.run(command, env=ros2_env, capture_output=True, text=True, timeout=60)
        assert result.returncode == 0, result.stdout + result.stderr[-2000:]
        return result

    result = evaluated('/tmp/robots.launch.py fleet:=b')
    lines = dict(line.split(' ', 1) for line in result.stdout.splitlines())
    shared = "('use_sim_time', False)"
    assert lines['double_integrator_env'] == f"[('max_episode_steps', 33), {shared}] []", lines
    assert lines['learner'] == f"[('batch_size', 64), ('learning_starts', 123), ('mode', 'qasac'), {shared}] []", lines
    assert lines['expert'] == f"[('backend', 'heuristic'), {shared}] []", lines
    assert 'ignored' not in result.stderr + result.stdout  # fleet:= is the including file's
    assert 'ignored: fleet:=' in (lambda r: r.stdout + r.stderr)(evaluated('eqhrl_ros train.launch.py fleet:=b'))
    # key_file:= reaches every node that signs or checks (the learner's requests, the expert's answers).
    keyed = evaluated('/tmp/robots.launch.py', 'train.launch.py', 'key_file:=/keys/deployment.key')
    lines = dict(line.split(' ', 1) for line in keyed.stdout.splitlines())
    assert all("('key_file', '/keys/deployment.key')" in lines[n] for n in ('learner', 'expert')), lines
    assert 'key_file' not in lines['double_integrator_env'], lines
    # actors.launch.py: before, its trainer took batches only from /actor0/actor and refused every
    # one of /robot1/actor0/actor; and every fleet so included shared /transitions and /weights.
    result = evaluated('/tmp/robots.launch.py', 'actors.launch.py', 'actors:=1')
    lines = dict(line.split(' ', 1) for line in result.stdout.splitlines())
    topics = "[('/transitions', '/robot1/transitions'), ('/weights', '/robot1/weights')]"
    assert "('actors', ('/robot1/actor0/actor',))" in lines['trainer'] and lines['trainer'].endswith(topics), lines
    assert lines['actor'].endswith(topics) and "('learning_starts', 123)" in lines['actor'], lines
    # The robot's own section too (before, only train.launch.py read it), and not another robot's.
    assert all("('batch_size', 64)" in lines[n] and '999' not in lines[n] for n in ('actor', 'trainer')), lines
    given = evaluated('/tmp/robots.launch.py', 'actors.launch.py', 'actors:=1', 'transitions_topic:=/fleet/t')
    assert "('/transitions', '/fleet/t'), ('/weights', '/robot1/weights')" in given.stdout, given.stdout


LAUNCH_AS_RCL_READS = """
import sys
import rclpy
from rclpy.context import Context
from launch import LaunchContext
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.launch_description_sources import get_launch_description_from_python_launch_file
from launch_ros.actions import Node

path, set_parameter, namespace, names = sys.argv[1:5]
given = dict(a.split(':=', 1) for a in sys.argv[5:])
context = LaunchContext(argv=sys.argv[5:])
first = []
if set_parameter != '-':  # an including file's SetParameter: launch_ros passes it first, as -p
    name, value = set_parameter.split('=')
    context.launch_configurations['global_params'] = [(name, value == 'true')]
    first = ['-p', f'{name}:={value}']
if namespace != '/':  # the including file's PushRosNamespace (none: a node's mappings go in `/**`)
    context.launch_configurations['ros_namespace'] = namespace
description = get_launch_description_from_python_launch_file(path)
for entity in description.entities:
    if isinstance(entity, DeclareLaunchArgument):
        default = entity.default_value[0].perform(context) if entity.default_value else ''
        context.launch_configurations[entity.name] = given.get(entity.name, default)
actions = [a for e in description.entities if isinstance(e, OpaqueFunction) for a in e.execute(context)]
for node in (a for a in actions if isinstance(a, Node)):
    node._perform_substitutions(context)
    arguments = list(first)
    for value, is_file in node._Node__expanded_parameter_arguments:
        arguments += ['--params-file', value] if is_file else ['-p', value]
    ros = Context()
    rclpy.init(args=['--ros-args', *arguments], context=ros)  # rcl reads them as the node would
    where = node.expanded_node_namespace if node.expanded_node_namespace.startswith('/') else '/'
    made = rclpy.create_node(
        node.node_executable, namespace=where, context=ros, automatically_declare_parameters_from_overrides=True
    )
    values = [(n, made.get_parameter(n).value) for n in names.split(',') if made.has_parameter(n)]
    print('NODE', node.node_executable, where, sorted(values))
    made.destroy_node()
    rclpy.shutdown(context=ros)
"""


def read_as_rcl(ros2_env, path, set_parameter, namespace, names, *arguments) -> list:
    """Each node the launch file at ``path`` starts, as `NODE <executable> <namespace> <values>` of
    the parameters ``names``: what rcl reads from what the launch passes the node."""
    command = ['python3', '-c', LAUNCH_AS_RCL_READS, str(path), set_parameter, namespace, names, *arguments]
    result = subprocess.run(command, env=ros2_env, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stdout + result.stderr[-2000:]
    return [line.split(' ', 1)[1] for line in result.stdout.splitlines() if line.startswith('NODE ')]


def test_the_launchs_own_arguments_win_under_an_including_files_set_parameter(ros2_env, colcon_install):
    """From outside: my launch file set use_sim_time for all (launch_ros's SetParameter, as with a
    simulator) and included train.launch.py with output_dir and mode. The learner ran eqsac and saved
    in the params file's runs/pendulum: rcl applies the file's `learner:` section after every `/**`
    value, and SetParameter's came first. rcl itself reads what the launch passes here."""
    path = colcon_install / 'eqhrl_ros' / 'share' / 'eqhrl_ros' / 'launch' / 'train.launch.py'
    expected = "[('mode', 'sac'), ('output_dir', '/tmp/mine'), ('use_sim_time', True)]"
    for namespace in ('/', '/robot1'):
        given = ('output_dir:=/tmp/mine', 'mode:=sac')
        nodes = read_as_rcl(ros2_env, path, 'use_sim_time=true', namespace, 'mode,output_dir,use_sim_time', *given)
        assert f'learner {namespace} {expected}' in nodes, nodes


@pytest.mark.parametrize('launch_file', ['train.launch.py', 'actors.launch.py'])
def test_use_sim_time_given_to_the_launch_puts_every_node_on_it(ros2_env, colcon_install, launch_file):
    """From outside, as with a simulator: `ros2 launch eqhrl_ros train.launch.py use_sim_time:=true`
    was said to be ignored, and every node ran on the system's time. Given, it outranks an
    including file's SetParameter, as output_dir:= does; not given, that SetParameter decides.
    rcl itself reads what the launch passes each node."""
    path = colcon_install / 'eqhrl_ros' / 'share' / 'eqhrl_ros' / 'launch' / launch_file

    def read(set_parameter, *arguments):
        nodes = read_as_rcl(ros2_env, path, set_parameter, '/', 'use_sim_time', 'env:=demo', 'actors:=1', *arguments)
        return [(line.split()[0], line.split()[-1]) for line in nodes]

    nodes = (
        ['gym_env', 'expert', 'learner']
        if launch_file == 'train.launch.py'
        else ['trainer', 'gym_env', 'expert', 'actor']
    )
    assert read('-', 'use_sim_time:=true') == [(node, 'True)]') for node in nodes]
    assert read('use_sim_time=true', 'use_sim_time:=false') == [(node, 'False)]') for node in nodes]
    assert read('use_sim_time=true') == [(node, 'True)]') for node in nodes]


@pytest.mark.parametrize(
    'launch_file,arguments,nodes',
    [
        ('train.launch.py', ['env:=double_integrator'], 'double_integrator_env expert learner'),
        ('train.launch.py', ['env:=double_integrator', 'env_node:=none'], 'expert learner'),
        ('train.launch.py', ['env:=pendulum'], 'gym_env expert learner'),
        ('actors.launch.py', ['env:=double_integrator', 'actors:=1'], 'trainer double_integrator_env expert actor'),
        # Before: env_node:= was ignored here, so a fleet of one's own robots got a simulator each too.
        (
            'actors.launch.py',
            ['env:=double_integrator', 'actors:=2', 'env_node:=none'],
            'trainer expert actor expert actor',
        ),
        (
            'actors.launch.py',
            ['env:=demo', 'actors:=1', 'env_node:=double_integrator_env'],
            'trainer double_integrator_env expert actor',
        ),
    ],
)
def test_the_launch_files_start_the_env_node_of_the_params_file(
    ros2_env, colcon_install, launch_file, arguments, nodes
):
    """The nodes each launch file would start, its description evaluated by launch itself. Before,
    env:=double_integrator started gym_env (Pendulum) unless env_node:= said otherwise."""
    path = colcon_install / 'eqhrl_ros' / 'share' / 'eqhrl_ros' / 'launch' / launch_file
    result = subprocess.run(
        ['python3', '-c', LAUNCH_NODES, str(path), *arguments], env=ros2_env, capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0 and result.stdout.split() == nodes.split(), result.stdout + result.stderr[-2000:]


def test_the_launch_files_name_their_choices_and_refuse_others_naming_them(ros2_env, colcon_install):
    """Before: the env argument's description named 4 of the 6 shipped params files (not the
    teleop ones the README launches), mode's named 3 of the 10 modes, and env:=<a typo> said only
    that a file could not be read."""
    share = colcon_install / 'eqhrl_ros' / 'share' / 'eqhrl_ros'
    names = sorted(p.stem for p in (share / 'params').glob('*.yaml'))
    assert 'teleop_pendulum' in names
    shown = ros2(ros2_env, 'launch', 'eqhrl_ros', 'train.launch.py', '--show-args')
    assert f'params file name: {", ".join(names)}' in shown, shown
    assert f'one of {", ".join(MODES)}' in shown, shown
    path = share / 'launch' / 'train.launch.py'
    for argument, refusal in [
        ('env:=bogus', f"no params file 'bogus'; give a path or one of {names}"),
        ('mode:=bogus', f'mode:=bogus is not one of {", ".join(MODES)}'),
    ]:
        command = ['python3', '-c', LAUNCH_NODES, str(path), argument]
        result = subprocess.run(command, env=ros2_env, capture_output=True, text=True, timeout=60)
        assert result.returncode != 0 and refusal in result.stderr, result.stderr[-2000:]


def test_train_launch_and_the_readmes_ros2_commands(ros2_env, tmp_path):
    launch = Launched(['ros2', 'launch', 'eqhrl_ros', 'train.launch.py', 'env:=demo'], tmp_path, ros2_env)
    out = tmp_path / 'runs' / 'demo' / 'episodes.csv'
    try:
        assert wait_for(lambda: len(rows(out)) >= 1 or launch.ended, 180) and not launch.ended, launch.text()[-4000:]
        # The ros2 daemon, started by the first command, learns the graph over a few seconds.
        nodes = lambda: set(ros2(ros2_env, 'node', 'list').split())  # noqa: E731
        assert wait_for(lambda: {'/learner', '/gym_env', '/expert'} <= nodes(), 30), nodes()
        diagnostics = ros2(ros2_env, 'topic', 'echo', '--once', '/diagnostics', 'diagnostic_msgs/msg/DiagnosticArray')
        assert 'name:' in diagnostics and 'level:' in diagnostics, diagnostics
        hz_log = tmp_path / 'hz.txt'
        with hz_log.open('w') as hz_out:
            hz = subprocess.Popen(['ros2', 'topic', 'hz', '/observation'], env=ros2_env, stdout=hz_out, stderr=hz_out)
            try:
                assert wait_for(lambda: 'average rate:' in hz_log.read_text(), 60), hz_log.read_text()
            finally:
                hz.send_signal(signal.SIGINT)
                hz.wait(timeout=30)
        assert 'successful' in ros2(ros2_env, 'param', 'set', '/learner', 'advising_budget', '7')
        assert 'Integer value is: 7' in ros2(ros2_env, 'param', 'get', '/learner', 'advising_budget')
        refused = subprocess.run(
            ['ros2', 'param', 'set', '/learner', 'advising_budget', '-3'],
            env=ros2_env,
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert 'Setting parameter failed' in refused.stdout + refused.stderr, refused
        request = (
            '{observation: [1.0, 0.0, 0.0], proposed_action: [0.0], action_low: [-2.0], action_high: [2.0], '
            'timeout_s: 1.0}'
        )
        answer = ros2(ros2_env, 'service', 'call', '/advise', 'eqhrl_interfaces/srv/Advise', request)
        assert 'advised=True' in answer and 'action=' in answer, answer
        helped = ros2(ros2_env, 'run', 'eqhrl_ros', 'learner', '--help')
        assert helped.startswith('usage: learner') and 'advising_budget' in helped
        episodes = len(rows(out))
        assert launch.ctrl_c() == 0, launch.text()[-4000:]
    finally:
        launch.close()
        subprocess.run(['ros2', 'daemon', 'stop'], env=ros2_env, capture_output=True, timeout=60)
    text = launch.text()
    assert 'Traceback' not in text, text[-3000:]
    # The learner saved at exit: its record holds the episodes it had when stopped, or more.
    assert settled(lambda: len(rows(out)), 0.5, 5) >= episodes


PARAMS = """
gym_env:
  ros__parameters: {max_episode_steps: 30}
learner:
  ros__parameters:
    mode: eqsac
    hidden_sizes: [16, 16]
    batch_size: 16
    learning_starts: 100
    queue_length: 3
    advising_budget: 2
    checkpoint_every_episodes: 5
    output_dir: OUT
    report_period_s: 2.0
/**:
  ros__parameters: {env_id: Pendulum-v1}
"""


@pytest.fixture
def three_hosts():
    """A trainer host and two robot hosts: network namespaces on a bridge in a switch namespace,
    with addresses inside them only. Needs root; deleted after the test."""
    if os.geteuid() != 0 or shutil.which('ip') is None:
        pytest.skip('network namespaces need root and iproute2 (ip netns)')
    tag = os.getpid() % 10000
    switch, names = f'eqs_sw{tag}', ('trainer', 'robot_a', 'robot_b')
    hosts = {name: f'eqs_{name}{tag}' for name in names}
    addresses = {name: f'10.239.{tag % 200}.{i + 1}' for i, name in enumerate(names)}
    links = {name: f'eq{name[-1]}{tag}' for name in names}

    def ip(*args):
        subprocess.run(['ip', *args], capture_output=True, text=True, check=True, timeout=20)

    try:
        ip('netns', 'add', switch)
        ip('-n', switch, 'link', 'add', 'br0', 'type', 'bridge')
        ip('-n', switch, 'link', 'set', 'br0', 'up')
        for name, ns in hosts.items():
            ip('netns', 'add', ns)
            ip('link', 'add', links[name], 'type', 'veth', 'peer', 'name', f's{links[name]}')
            ip('link', 'set', links[name], 'netns', ns)
            ip('link', 'set', f's{links[name]}', 'netns', switch)
            ip('-n', switch, 'link', 'set', f's{links[name]}', 'master', 'br0')
            ip('-n', switch, 'link', 'set', f's{links[name]}', 'up')
            ip('-n', ns, 'addr', 'add', f'{addresses[name]}/24', 'dev', links[name])
            ip('-n', ns, 'link', 'set', links[name], 'up')
            ip('-n', ns, 'link', 'set', 'lo', 'up')
        yield hosts, addresses, links, ip
    finally:
        for ns in [*hosts.values(), switch]:
            subprocess.run(['ip', 'netns', 'del', ns], capture_output=True, timeout=20)


def test_actors_launch_across_three_hosts_through_a_cut_a_trainer_kill_and_a_robots_ctrl_c(
    ros2_env, three_hosts, tmp_path
):
    """The README's recipe on three hosts: a trainer host told its robots by name, two robot
    hosts each launching one actor. Robot A's link is cut for 5 s; the trainer host is killed
    (-9) and launched again with resume:=true; then robot A's launch gets a Ctrl-C. Every
    episode robot A finished is in the record exactly once, and so are robot B's."""
    hosts, addresses, links, ip = three_hosts
    out = tmp_path / 'out'
    params_file = tmp_path / 'params.yaml'
    params_file.write_text(PARAMS.replace('OUT', str(out)))
    actors = '/robot_a_actor0/actor,/robot_b_actor1/actor'  # robot B's index is 1 (actor_offset:=1)

    def launch(host, *arguments):
        peers = ';'.join(a for name, a in addresses.items() if name != host)
        env = dict(ros2_env, ROS_AUTOMATIC_DISCOVERY_RANGE='SUBNET', ROS_STATIC_PEERS=peers)
        command = ['ip', 'netns', 'exec', hosts[host], 'ros2', 'launch', 'eqhrl_ros', 'actors.launch.py']
        return Launched([*command, f'params_file:={params_file}', *arguments], tmp_path, env, host)

    def recorded(actor):
        return [r['actor'] for r in rows(out / 'episodes.csv')].count(actor)

    trainer_args = ('actors:=0', f'trainer_actors:={actors}')
    launched = [launch('trainer', *trainer_args)]
    for i, robot in enumerate(('robot_a', 'robot_b')):
        args = ('actors:=1', 'trainer:=false', f'actor_prefix:={robot}_actor', f'actor_offset:={i}')
        launched.append(launch(robot, *args))
    trainer, robot_a, robot_b = launched
    a, b = '/robot_a_actor0/actor', '/robot_b_actor1/actor'
    try:
        assert wait_for(lambda: recorded(a) >= 3 and recorded(b) >= 3, 240), trainer.text()[-3000:]
        ip('-n', hosts['robot_a'], 'link', 'set', links['robot_a'], 'down')
        time.sleep(5)
        ip('-n', hosts['robot_a'], 'link', 'set', links['robot_a'], 'up')
        before = recorded(a)
        assert wait_for(lambda: recorded(a) > before + 2, 120), trainer.text()[-3000:]
        trainer.signal(signal.SIGKILL)  # the trainer host dies: launch and trainer at once
        trainer.process.wait(timeout=30)
        launched.append(launch('trainer', *trainer_args, 'resume:=true'))
        trainer = launched[-1]
        assert wait_for(lambda: 'resumed from' in trainer.text(), 120), trainer.text()[-3000:]
        before = recorded(a), recorded(b)
        assert wait_for(lambda: recorded(a) > before[0] + 2 and recorded(b) > before[1] + 2, 180)
        # Robot A has sent the new trainer what it kept (the record is within a few episodes of
        # its log): the Ctrl-C comes in ordinary running, not in the middle of that catch-up,
        # which a bounded exit wait may not finish on 2 busy cores (the README says so).
        logged = lambda: robot_a.text().count('] [robot_a_actor0.actor]: episode ')  # noqa: E731
        assert wait_for(lambda: recorded(a) >= logged() - 5, 120), (recorded(a), logged())
        assert robot_a.ctrl_c() == 0, robot_a.text()[-3000:]
        finished_a = robot_a.text().count('] [robot_a_actor0.actor]: episode ')
        assert settled(lambda: recorded(a), 3.0, 60) == finished_a, (recorded(a), finished_a)
        assert robot_b.ctrl_c() == 0, robot_b.text()[-3000:]
        finished_b = robot_b.text().count('] [robot_b_actor1.actor]: episode ')
        assert settled(lambda: recorded(b), 3.0, 60) == finished_b, (recorded(b), finished_b)
        assert trainer.ctrl_c() == 0, trainer.text()[-3000:]
    finally:
        for process in launched:
            process.close()
    episodes = [int(r['episode']) for r in rows(out / 'episodes.csv')]
    assert episodes == list(range(len(episodes)))  # one record, indexed over both robots, no gap
    for robot in (robot_a, robot_b):
        assert ', 0 not stored by the trainer, ' in robot.text(), robot.text()[-2000:]
    print(trainer.text().splitlines()[-1])
