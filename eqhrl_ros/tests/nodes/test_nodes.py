"""The env, learner and expert nodes, spun by rclpy executors in the test process."""

import ast
import csv
import dataclasses
import time
from types import SimpleNamespace

import numpy as np
import pytest
import rclpy
import rclpy.executors
import yaml
from std_msgs.msg import Float32MultiArray

from eqhrl_ros.core import EQSACLearner, LearnerConfig
from eqhrl_ros.core.data.summary import EpisodeSummary
from eqhrl_ros.core.experts.policy import PolicyExpert, export_policy
from eqhrl_ros.nodes import messages
from eqhrl_ros.nodes.expert_node import ExpertNode
from eqhrl_ros.nodes.gym_env_node import GymEnvNode
from eqhrl_ros.nodes.learner_node import LearnerNode
from eqhrl_ros.nodes.spinning import start_up_errors

from ros_helpers import PARAMS_DIR, Probe, StubExpert, params, run_learner, small_learner_params

# ------------------------------------------------------------------ env node


def test_env_node_layout_step_reset_and_rejections(harness, ros_context):
    probe = Probe(harness)
    env = harness.add(
        GymEnvNode(context=ros_context, parameter_overrides=params(max_episode_steps=3, republish_period_s=0.2))
    )
    # The first observation is re-sent until someone acts, so a late subscriber gets it.
    assert harness.spin_until(lambda: len(probe.observations) >= 1)
    first = probe.observations[-1]
    assert [(d.label, d.size) for d in first.layout.dim] == [
        ('obs', 3),
        ('reward', 1),
        ('terminated', 1),
        ('truncated', 1),
        ('episode', 1),
        ('step', 1),
    ]
    step0 = messages.parse_observation(first, 3)
    assert (step0.episode, step0.step, step0.done) == (0, 0, False)

    probe.observations.clear()
    probe.action_pub.publish(messages.action_msg([50.0], 0, 0))  # beyond Pendulum's torque bound
    assert harness.spin_until(lambda: any(messages.parse_observation(m, 3).step == 1 for m in probe.observations))
    assert env._previous_action.tolist() == [2.0]  # stepped clipped to the bounds it announced

    for bad in ([0.1, 0.2], [float('nan')]):
        probe.action_pub.publish(messages.action_msg(bad))
    assert harness.spin_until(lambda: env.rejected_actions == 2)
    assert env.step_index == 1

    probe.action_pub.publish(messages.action_msg([0.0], 0, 0))  # stale tag: ignored
    assert harness.spin_until(lambda: env.stale_actions == 1)
    assert env.step_index == 1

    probe.observations.clear()
    for step in (1, 2):
        probe.action_pub.publish(messages.action_msg([0.0], 0, step))
        assert harness.spin_until(lambda: env.step_index == step + 1 or env.episode == 1)
    assert harness.spin_until(lambda: any(messages.parse_observation(m, 3).episode == 1 for m in probe.observations))
    parsed = [messages.parse_observation(m, 3) for m in probe.observations]
    last_of_episode = [p for p in parsed if p.episode == 0 and p.step == 3][0]
    assert last_of_episode.truncated and not last_of_episode.terminated
    assert any(p.episode == 1 and p.step == 0 for p in parsed)


@pytest.mark.parametrize('harness', ['single', 'events'], indirect=True)
@pytest.mark.parametrize('joins', ['before_spinning', 'while_spinning'])
def test_a_late_subscriber_gets_the_observation_when_it_connects(harness, ros_context, joins):
    # Re-sending only every republish period cost start-up a whole period; the env
    # re-sends as soon as a subscriber connects. 'before_spinning' is eqhrl-train's
    # order (all nodes made, then spun), where the EventsExecutor's matched event
    # reports no change in the count.
    env = harness.add(GymEnvNode(context=ros_context, parameter_overrides=params(republish_period_s=60.0)))
    if joins == 'while_spinning':
        harness.spin_until(lambda: False, timeout=0.3)  # the first observation went out to nobody
    start = time.monotonic()
    probe = Probe(harness)
    assert harness.spin_until(lambda: len(probe.observations) >= 1, timeout=5)
    assert time.monotonic() - start < 5 and env.step_index == 0
    assert messages.parse_observation(probe.observations[0], 3).step == 0


def test_executor_kinds():
    from rclpy.executors import MultiThreadedExecutor, SingleThreadedExecutor

    from eqhrl_ros.nodes.spinning import make_executor

    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        assert isinstance(make_executor('single', context=context), SingleThreadedExecutor)
        assert isinstance(make_executor('multi', context=context), MultiThreadedExecutor)
        assert type(make_executor('events', context=context)).__name__ == 'EventsExecutor'
        with pytest.raises(ValueError, match='not one of'):
            make_executor('fast', context=context)
    finally:
        rclpy.try_shutdown(context=context)


# ------------------------------------------------------------------ learner with stub experts


def test_learner_asks_exactly_when_gates_fire_and_only_inside_budget(harness, ros_context, tmp_path):
    expert = StubExpert(ros_context)
    try:
        learner, probe = run_learner(harness, ros_context, tmp_path, episodes=4)
    finally:
        expert.close()
    assert harness.spin_until(lambda: len(probe.stats) == 4)
    fired = [(g.episode, g.step) for g in probe.gates if g.fire]
    assert fired, 'the gates never fired in the budget episodes'
    assert [(r[0], r[1]) for r in expert.requests] == fired
    assert all(episode < 2 for episode, _ in fired)  # advising_budget = 2
    assert all(np.isfinite(r[3]) for r in expert.requests)  # eqsac sends E(s)
    totals = learner.learner.advice_total
    assert totals.asked == totals.given == len(fired)
    assert len(learner.learner.advice_replay) == len(fired)


def test_sac_mode_never_calls_the_service(harness, ros_context, tmp_path):
    expert = StubExpert(ros_context)
    try:
        learner, _ = run_learner(harness, ros_context, tmp_path, episodes=2, mode='sac')
    finally:
        expert.close()
    assert expert.requests == [] and learner.learner.advice_total.asked == 0
    # What eqhrl-report reads of a single run: noted with the start.
    start = yaml.safe_load((tmp_path / 'provenance.yaml').read_text())['starts'][-1]
    assert (start['env'], start['mode'], start['seed']) == ('Pendulum-v1', 'sac', 42)


@pytest.mark.parametrize(
    'answer,delay,kind', [('decline', 0.0, 'declined'), ('advise', 0.6, 'timeout'), (None, 0.0, 'unavailable')]
)
@pytest.mark.parametrize('harness', ['single', 'events'], indirect=True)
@pytest.mark.slow
def test_declining_slow_or_absent_expert_leaves_training_going(harness, ros_context, tmp_path, answer, delay, kind):
    expert = StubExpert(ros_context, answer, delay) if answer else None
    try:
        # A slow expert's requests end at the learner's timeout: 0.1 s each, not 0.3 (the suite's time).
        wait = dict(advice_timeout_s=0.1) if kind == 'timeout' else {}
        learner, probe = run_learner(harness, ros_context, tmp_path, episodes=3, mode='qasac', **wait)
    finally:
        if expert:
            expert.close()
    totals = learner.learner.advice_total
    assert learner.learner.episode == 3 and learner.learner.total_steps == 75
    assert totals.asked > 0 and totals.given == 0
    counted = totals.declined if kind == 'declined' else totals.failed[kind]
    assert counted == totals.asked
    assert len(learner.learner.advice_replay) == 0


# ------------------------------------------------------------------ all three nodes


def read_csv(path):
    with open(path, newline='') as f:
        return list(csv.DictReader(f))


@pytest.mark.parametrize('harness', ['single', 'events'], indirect=True)
def test_three_nodes_run_and_resume_from_checkpoint(harness, ros_context, tmp_path):
    harness.add(ExpertNode(context=ros_context, parameter_overrides=params(env_id='Pendulum-v1')))
    learner, probe = run_learner(harness, ros_context, tmp_path, episodes=3)
    assert harness.spin_until(lambda: len(probe.stats) == 3)
    rows = read_csv(tmp_path / 'episodes.csv')
    assert [int(r['episode']) for r in rows] == [0, 1, 2]
    # learner/episode_stats (EpisodeStats) carries each row's numbers, field by field.
    fields = [f.name for f in dataclasses.fields(EpisodeSummary)]
    assert len(fields) == len(EpisodeSummary.CSV_FIELDS)
    for row, stat in zip(rows, probe.stats, strict=True):
        assert stat.length == 25
        for field, column in zip(fields, EpisodeSummary.CSV_FIELDS):
            assert float(getattr(stat, field)) == pytest.approx(float(row[column]), rel=1e-5, abs=1e-6), field
    assert sum(int(r['advice_given']) for r in rows) > 0  # the heuristic expert answered
    assert (tmp_path / 'checkpoint.pt').exists() and (tmp_path / 'policy.pt').exists()
    steps_before = learner.learner.total_steps
    for node in list(harness.nodes):
        if isinstance(node, LearnerNode):
            harness.executor.remove_node(node)
            harness.nodes.remove(node)
            node.close()
            node.destroy_node()

    resumed = harness.add(
        LearnerNode(
            context=ros_context, parameter_overrides=small_learner_params(tmp_path, max_episodes=5, resume=True)
        )
    )
    assert resumed.learner.episode == 3 and resumed.learner.total_steps == steps_before
    assert harness.spin_until(lambda: resumed.done, timeout=60)
    assert [int(r['episode']) for r in read_csv(tmp_path / 'episodes.csv')] == [0, 1, 2, 3, 4]


# ------------------------------------------------------------------ parameters


def end_nodes(nodes, context) -> None:
    """Nodes made in a context of a test's own: closed (a learner saves), destroyed, the context shut down."""
    for node in nodes:
        if isinstance(node, LearnerNode):
            node.close()
        node.destroy_node()
    context.try_shutdown()


@pytest.mark.parametrize('name', ['pendulum', 'lunar_lander', 'demo'])
def test_each_params_file_loads_into_all_three_nodes(name, tmp_path):
    context = rclpy.Context()
    rclpy.init(context=context, args=['--ros-args', '--params-file', str(PARAMS_DIR / f'{name}.yaml')])
    nodes = []
    try:
        nodes.append(GymEnvNode(context=context))
        nodes.append(ExpertNode(context=context))
        nodes.append(LearnerNode(context=context, parameter_overrides=params(output_dir=str(tmp_path))))
        env_id = nodes[0].params['env_id']
        assert nodes[2].params['env_id'] == env_id == nodes[1].params['env_id']
        assert nodes[2].config.advising_budget == {'pendulum': 30, 'lunar_lander': 300, 'demo': 20}[name]
    finally:
        end_nodes(nodes, context)


def test_every_parameter_reads_through_the_nodes_services_and_a_dump_starts_the_node_again(harness, tmp_path):
    """`ros2 param dump`, from outside: `ros__parameters: {}` for every shipped node. One parameter
    declared typed but unset (action_low, the spaces coming from env_id) made rclpy's get_parameters
    answer nothing for the whole node, and `ros2 param get` of it failed. Now such a parameter is
    declared only when given; every listed one reads, and the dump starts the same node again."""
    from rclpy.parameter import parameter_value_to_python
    from rclpy.parameter_client import AsyncParameterClient

    def made(context, extra=()):
        env = GymEnvNode(context=context)
        return [env, ExpertNode(context=context), LearnerNode(context=context, parameter_overrides=list(extra))]

    first = rclpy.Context()
    rclpy.init(context=first, args=['--ros-args', '--params-file', str(PARAMS_DIR / 'pendulum.yaml')])
    dumped = {}
    try:
        nodes = made(first, params(output_dir=str(tmp_path / 'run')))
        reader = rclpy.create_node('dumper', context=first)
        executor = rclpy.executors.SingleThreadedExecutor(context=first)
        for node in [*nodes, reader]:
            executor.add_node(node)

        def answer(future):
            deadline = time.monotonic() + 10
            while not future.done() and time.monotonic() < deadline:
                executor.spin_once(timeout_sec=0.05)
            return future.result()

        for node in nodes:
            client = AsyncParameterClient(reader, node.get_fully_qualified_name())
            names = answer(client.list_parameters()).result.names
            values = answer(client.get_parameters(list(names))).values
            assert len(values) == len(names) > 10 and 'action_low' not in names, node.get_name()
            dumped[node.get_fully_qualified_name()] = {
                'ros__parameters': {n: parameter_value_to_python(v) for n, v in zip(names, values)}
            }
    finally:
        end_nodes(nodes, first)
    assert dumped['/gym_env']['ros__parameters']['env_id'] == 'Pendulum-v1'
    dump = tmp_path / 'dump.yaml'
    dump.write_text(yaml.safe_dump(dumped))
    again = rclpy.Context()
    rclpy.init(context=again, args=['--ros-args', '--params-file', str(dump)])
    try:
        nodes = made(again, params(output_dir=str(tmp_path / 'again')))  # the first run's folder holds a run
        learner = dumped['/learner']['ros__parameters']
        assert nodes[2].config.advising_budget == learner['advising_budget'] and learner['env_id'] == 'Pendulum-v1'
    finally:
        end_nodes(nodes, again)


def test_a_params_files_section_that_misses_a_namespaced_node_is_said_and_read_as_rcl_reads_it(ros_context, tmp_path):
    """From outside: `ros2 run eqhrl_ros gym_env --ros-args --params-file teleop_pendulum.yaml -r
    __ns:=/robot1` ran lock-step with the defaults: rcl gives a section `gym_env:` to /gym_env only,
    and nothing said so (the learner beside it waited 0.3 s for a person, not the file's 5 s)."""
    from eqhrl_ros.nodes.launching import env_node_for
    from eqhrl_ros.nodes.params import warn_unapplied_sections
    from eqhrl_ros.parameters import file_section, section_applies

    assert section_applies('learner', '/learner') and not section_applies('learner', '/robot1/learner')
    assert section_applies('/**/learner', '/robot1/learner') and section_applies('/**/learner', '/learner')
    assert section_applies('/*/learner', '/robot1/learner') and not section_applies('/*/learner', '/learner')
    assert section_applies('/**', '/a/b/c') and not section_applies('/robot2/learner', '/robot1/learner')
    wildcard = {'/**/gym_env': {'ros__parameters': {'realtime': True}}, '/**': {'ros__parameters': {'env_id': 'X'}}}
    assert file_section(wildcard, 'gym_env') == {'realtime': True, 'env_id': 'X'}
    assert env_node_for({'/**/double_integrator_env': {'ros__parameters': {}}}) == 'double_integrator_env'
    teleop = str(PARAMS_DIR / 'teleop_pendulum.yaml')
    node = rclpy.create_node('gym_env', namespace='/robot1', context=ros_context)
    try:
        said = warn_unapplied_sections(node, ['gym_env', '--ros-args', '--params-file', teleop, '-r', '__ns:=/robot1'])
        assert "its section gym_env is not this node's (/robot1/gym_env)" in said and '/**/gym_env:' in said
    finally:
        node.destroy_node()
    # A trainer given a shipped file: its settings are in learner:, which rcl gives to /learner only
    # (before, `ros2 run eqhrl_ros trainer --ros-args --params-file pendulum.yaml` ran on Table 1's defaults).
    node = rclpy.create_node('trainer', context=ros_context)
    pendulum = str(PARAMS_DIR / 'pendulum.yaml')
    try:
        said = warn_unapplied_sections(node, ['x', '--ros-args', '--params-file', pendulum], settings_of='learner')
        assert 'its section learner is for a node named learner' in said and 'actors.launch.py' in said
        assert warn_unapplied_sections(node, ['x', '--ros-args', '--params-file', pendulum]) == ''
    finally:
        node.destroy_node()
    robots = tmp_path / 'robots.yaml'  # one file for two robots: each node has its own section
    robots.write_text(
        '/robot1/learner:\n  ros__parameters: {seed: 1}\n/robot2/learner:\n  ros__parameters: {seed: 2}\n'
    )
    for name, namespace, path in (('gym_env', '/', teleop), ('learner', '/robot1', str(robots))):
        node = rclpy.create_node(name, namespace=namespace, context=ros_context)
        try:
            assert warn_unapplied_sections(node, ['x', '--ros-args', '--params-file', path]) == ''
        finally:
            node.destroy_node()


def test_a_params_file_in_rcls_nested_form_is_read_as_rcl_reads_it(ros_context, tmp_path):
    """From outside: rcl reads a namespace that holds its nodes (`robot1: {learner: {ros__parameters:
    …}}`); the package's readers saw no section there, so the launch files, which hand each node its
    sections, ran such a file's nodes on their defaults, without a word. rcl itself is the oracle."""
    from eqhrl_ros.nodes.launching import env_node_for
    from eqhrl_ros.parameters import BUILT_IN, file_section

    nested = tmp_path / 'nested.yaml'
    nested.write_text(
        'robot1:\n  learner:\n    ros__parameters: {batch_size: 64}\n'
        '  double_integrator_env:\n    ros__parameters: {seed: 3}\n'
        'fleet:\n  robot2:\n    learner:\n      ros__parameters: {batch_size: 32}\n'
        "'/**':\n  ros__parameters: {env_id: Pendulum-v1}\n"
    )
    data = yaml.safe_load(nested.read_text())
    for namespace in ('/robot1', '/fleet/robot2', '/'):
        context = rclpy.Context()
        rclpy.init(args=['--ros-args', '--params-file', str(nested)], context=context)
        try:
            node = rclpy.create_node(
                'learner', namespace=namespace, context=context, automatically_declare_parameters_from_overrides=True
            )
            rcl = {k: p.value for k, p in node.get_parameters_by_prefix('').items() if k not in BUILT_IN}
            node.destroy_node()
        finally:
            rclpy.shutdown(context=context)
        assert file_section(data, 'learner', namespace) == rcl, namespace
    assert file_section(data, 'learner', '/robot1') == {'batch_size': 64, 'env_id': 'Pendulum-v1'}
    assert env_node_for(data) == 'gym_env'  # robot1's env section is no root node's
    assert env_node_for({'/**': {'double_integrator_env': {'ros__parameters': {}}}}) == 'double_integrator_env'


@pytest.mark.parametrize(
    'override,message',
    [
        (dict(gamma=1.5), 'gamma'),
        (dict(mode='ddpg'), 'mode'),
        (dict(batch_size='big'), 'batch_size'),
        (dict(advice_timeuot_s=1.0), 'advice_timeuot_s'),
    ],
)
def test_bad_parameters_are_refused_at_start_up_naming_the_key(ros_context, tmp_path, override, message):
    with pytest.raises(start_up_errors(), match=message):
        LearnerNode(context=ros_context, parameter_overrides=small_learner_params(tmp_path, **override))


def test_a_path_parameter_that_starts_with_a_tilde_is_in_the_home_folder(harness, ros_context, tmp_path, monkeypatch):
    """From outside: `ros2 run eqhrl_ros learner --ros-args -p output_dir:=~/runs/p` (no shell expands
    a ~ inside an argument, nor does ROS) made a folder named ~ in the working directory, and the
    expert's `policy_path:=~/policy.pt` was not found."""
    home = tmp_path / 'home'
    monkeypatch.setenv('HOME', str(home))
    monkeypatch.chdir(tmp_path)
    home.mkdir()
    export_policy(EQSACLearner(3, [-2.0], [2.0], LearnerConfig(hidden=(16, 16), seed=3)), home / 'policy.pt')
    expert = harness.add(
        ExpertNode(context=ros_context, parameter_overrides=params(backend='policy', policy_path='~/policy.pt'))
    )
    learner = harness.add(
        LearnerNode(context=ros_context, parameter_overrides=small_learner_params(tmp_path, output_dir='~/runs/p'))
    )
    assert learner.params['output_dir'] == str(home / 'runs' / 'p')
    with pytest.raises(start_up_errors(), match=f'prior: {home}/runs/old: no such file or folder'):
        LearnerNode(context=ros_context, parameter_overrides=small_learner_params(tmp_path, prior=['~/runs/old']))
    harness.add(GymEnvNode(context=ros_context, parameter_overrides=params(max_episode_steps=20)))
    assert harness.spin_until(lambda: expert.backend is not None, timeout=10)
    assert isinstance(expert.backend, PolicyExpert)
    assert not (tmp_path / '~').exists()


def test_run_time_parameters_are_range_checked_applied_and_said(harness, ros_context, tmp_path):
    """Any node may set a run-time parameter (rclpy's services say nothing of the caller): before, a
    change was applied without a word; now the node logs it with the value it replaced."""
    said = []
    logger = rclpy.logging.get_logger('learner')
    quiet = SimpleNamespace(info=said.append, warn=logger.warn, warning=logger.warning, error=logger.error)
    original = LearnerNode.get_logger
    LearnerNode.get_logger = lambda self: quiet  # from its first line: declaring says nothing
    try:
        learner = harness.add(LearnerNode(context=ros_context, parameter_overrides=small_learner_params(tmp_path)))
    finally:
        LearnerNode.get_logger = original
    assert not [line for line in said if line.startswith('parameter ')], said
    said.clear()
    learner.get_logger = lambda: quiet
    before = learner.get_parameter('advising_budget').value
    results = learner.set_parameters(params(advising_budget=-1))
    assert not results[0].successful
    assert learner.set_parameters(params(advising_budget=7))[0].successful
    assert learner.learner.gates.advising_budget == 7
    assert said == [f'parameter advising_budget set to 7 (was {before})']
    assert not learner.set_parameters(params(seed=3))[0].successful  # read-only while running
    # A change that a later check refuses is never applied: checks run on-set, changes post-set.
    from rcl_interfaces.msg import SetParametersResult

    learner.add_on_set_parameters_callback(lambda changes: SetParametersResult(successful=False, reason='veto'))
    assert not learner.set_parameters(params(advising_budget=9))[0].successful
    assert learner.learner.gates.advising_budget == 7 and learner.learner.config.advising_budget == 7
    assert len(said) == 1  # a refused change is not said to be made
    del learner.get_logger


def test_realtime_env_steps_at_its_rate_holding_the_last_action(harness, ros_context):
    probe = Probe(harness)
    env = harness.add(
        GymEnvNode(context=ros_context, parameter_overrides=params(realtime=True, rate_hz=50.0, max_episode_steps=1000))
    )
    assert harness.spin_until(lambda: env.step_index >= 5)  # no action needed to step
    probe.action_pub.publish(messages.action_msg([2.0]))
    assert harness.spin_until(lambda: float(env._held_action[0]) == 2.0)
    start_step, start = env.step_index, time.monotonic()
    assert harness.spin_until(lambda: env.step_index >= start_step + 10)
    rate = (env.step_index - start_step) / (time.monotonic() - start)
    assert 10.0 < rate < 80.0, rate  # 50 Hz asked; wide bounds for a loaded machine


def test_launch_file_is_valid_python_naming_the_executables():
    source = (PARAMS_DIR.parent / 'launch' / 'train.launch.py').read_text()
    compile(source, 'train.launch.py', 'exec')
    assert "executable='learner'" in source
    assert 'executable=env_node' in source and 'executable=EXPERT_NODES[expert]' in source
    assert "executable='advice_console'" in source  # with expert:=teleop
    # Its experts are eqhrl-train's; the env node is chosen by the same function (launching.py).
    from eqhrl_ros.cli.train import EXPERT_NODES

    constants = {
        node.targets[0].id: ast.literal_eval(node.value)
        for node in ast.parse(source).body
        if isinstance(node, ast.Assign) and isinstance(node.targets[0], ast.Name)
    }
    assert tuple(constants['EXPERT_NODES']) == EXPERT_NODES and 'env_node_for(' in source
    assert {v for v in constants['EXPERT_NODES'].values() if v} == {'expert', 'teleop_expert'}


def test_the_env_node_is_the_one_the_params_file_has_a_section_for():
    """Before: `eqhrl-train --params double_integrator` and `ros2 launch eqhrl_ros train.launch.py
    env:=double_integrator` started gym_env, and the learner, told no env_id, trained on Pendulum."""
    from eqhrl_ros.files.yaml_files import load_mapping
    from eqhrl_ros.nodes.launching import env_node_for

    names = ('pendulum', 'double_integrator')
    chosen = {name: env_node_for(load_mapping(PARAMS_DIR / f'{name}.yaml')) for name in names}
    assert chosen == {'pendulum': 'gym_env', 'double_integrator': 'double_integrator_env'}
    assert env_node_for({'learner': {}}) == 'gym_env'  # a file with no env section: gym_env, as before
    assert env_node_for({'/double_integrator_env': {}}, 'none') == 'none'  # named: as named
    with pytest.raises(ValueError, match='a section for each of gym_env and double_integrator_env'):
        env_node_for({'gym_env': {}, 'double_integrator_env': {}})
    with pytest.raises(ValueError, match="'mujoco' is not one of"):
        env_node_for({}, 'mujoco')


def test_realtime_env_with_a_slow_expert_keeps_every_transition(harness, ros_context, tmp_path):
    """While a (human-slow) expert decides, a real-time env keeps stepping with the held
    action: those steps are stored as transitions, none is lost, and advice still lands."""
    expert = StubExpert(ros_context, 'advise', delay=0.15)
    try:
        harness.add(
            GymEnvNode(
                context=ros_context, parameter_overrides=params(realtime=True, rate_hz=60.0, max_episode_steps=40)
            )
        )
        learner = harness.add(
            LearnerNode(
                context=ros_context,
                parameter_overrides=small_learner_params(
                    tmp_path,
                    mode='qasac',
                    advising_budget=100,
                    max_episodes=3,
                    advice_timeout_s=1.0,
                    advice_protocol='answer',  # one action per request, while the real-time env goes on
                ),
            )
        )
        assert harness.spin_until(lambda: learner.done, timeout=60)
    finally:
        expert.close()
    totals = learner.learner.advice_total
    assert totals.given > 0
    # Only a request still open when its episode ends times out (1 s timeout, 0.15 s answers).
    assert totals.failed['timeout'] <= 3
    assert learner.observation_gaps == 0
    # A real-time env starts its clock when its first subscriber connects: every episode,
    # the first included, is seen whole and every step is stored.
    assert [s.length for s in learner.summaries] == [40, 40, 40]
    assert not any(s.interrupted for s in learner.summaries)
    assert len(learner.learner.replay) == learner.learner.total_steps == 120


@pytest.mark.parametrize('env_class', ['gym_env', 'double_integrator_env'])
def test_an_env_takes_no_action_while_two_nodes_publish_action(harness, ros_context, env_class):
    """Before: a second learner, or a stranger's `ros2 topic pub /action`, stepped the env as the
    learner did (an untagged action steps a lock-step env at once): anyone on the graph drove it.
    (In a namespace of its own: a node of an earlier test may still show on the domain's /action.)"""
    from eqhrl_ros.nodes.double_integrator_env_node import DoubleIntegratorEnv

    make = GymEnvNode if env_class == 'gym_env' else DoubleIntegratorEnv
    ns = f'/two_{env_class}'
    env = harness.add(make(context=ros_context, namespace=ns, parameter_overrides=params(republish_period_s=0.2)))
    driver, stranger = (harness.add(rclpy.create_node(n, namespace=ns, context=ros_context)) for n in ('d', 's'))
    drive = driver.create_publisher(Float32MultiArray, 'action', 10)
    assert harness.spin_until(lambda: drive.get_subscription_count() > 0)
    drive.publish(messages.action_msg([0.5]))
    assert harness.spin_until(lambda: env.step_index == 1)
    forge = stranger.create_publisher(Float32MultiArray, 'action', 10)
    assert harness.spin_until(lambda: driver.count_publishers(f'{ns}/action') == 2)
    harness.spin_until(lambda: False, timeout=0.6)  # past the env's look at the graph (0.5 s)
    for publisher in (drive, forge, drive):
        publisher.publish(messages.action_msg([0.5]))
    assert harness.spin_until(lambda: env.refused_actions == 3) and env.step_index == 1
    stranger.destroy_publisher(forge)
    assert harness.spin_until(lambda: driver.count_publishers(f'{ns}/action') == 1)
    harness.spin_until(lambda: False, timeout=0.6)
    drive.publish(messages.action_msg([0.5]))
    assert harness.spin_until(lambda: env.step_index == 2)


def test_a_learner_takes_no_observation_while_two_nodes_publish_observation(harness, ros_context, tmp_path):
    """Before: a stranger's observations (`ros2 topic pub /observation ...`) were acted on and
    stored as the env's transitions, with whatever reward they claimed. Now, while a second node
    publishes observation, the learner takes none (and says so); the run goes on once it leaves."""
    ns = '/two_envs'  # a namespace of its own: a node of an earlier test may still show on the domain
    harness.add(GymEnvNode(context=ros_context, namespace=ns, parameter_overrides=params(republish_period_s=0.2)))
    learner = harness.add(
        LearnerNode(context=ros_context, namespace=ns, parameter_overrides=small_learner_params(tmp_path))
    )
    assert harness.spin_until(lambda: learner.learner is not None and learner.learner.total_steps > 5, timeout=30)
    stranger = harness.add(rclpy.create_node('stranger', namespace=ns, context=ros_context))
    fake = stranger.create_publisher(Float32MultiArray, 'observation', 10)
    assert harness.spin_until(lambda: learner.count_publishers(f'{ns}/observation') == 2)
    harness.spin_until(lambda: False, timeout=0.6)  # past the learner's look at the graph (0.5 s)
    steps = learner.learner.total_steps
    fake.publish(messages.observation_msg([0.0, 1.0, 0.0], 1000.0, False, False, 7, 1))
    assert harness.spin_until(lambda: learner.observation_source.refused >= 2)  # the fake and the env's re-send
    assert learner.learner.total_steps == steps
    stranger.destroy_publisher(fake)
    assert harness.spin_until(lambda: learner.learner.total_steps > steps + 5, timeout=30)
