"""Any env node: spaces from env_info or parameters, success reported by the env,
shared params sections, and the example env node that is not gymnasium."""

import csv
import io
import os
import time
from types import SimpleNamespace

import numpy as np
import pytest
import rclpy
from std_msgs.msg import Float32MultiArray

from eqhrl_interfaces.msg import AdviceRequest as AdviceRequestMsg
from eqhrl_interfaces.msg import EnvInfo
from eqhrl_ros.core.envs.spec import SUCCESS_RULES, EnvSpec
from eqhrl_ros.core.experts.controllers import DoubleIntegratorExpert
from eqhrl_ros.nodes import env_info, messages, start_wait
from eqhrl_ros.nodes.double_integrator_env_node import DoubleIntegrator, DoubleIntegratorEnv
from eqhrl_ros.nodes.expert_node import ExpertNode
from eqhrl_ros.nodes.gym_env_node import GymEnvNode
from eqhrl_ros.nodes.keyboard_teleop_node import KeyboardTeleop
from eqhrl_ros.nodes.learner_node import LearnerNode
from eqhrl_ros.nodes.start_wait import AUTO_PACE_WAIT_S
from eqhrl_ros.nodes.teleop_expert_node import TeleopExpertNode
from eqhrl_ros.parameters import file_section

from ros_helpers import StubExpert, asking_learner_params, observation_publisher, params, small_learner_params


def no_env_id(tmp_path, **extra):
    """The small learner of the other tests, with no gymnasium id."""
    return [p for p in small_learner_params(tmp_path, **extra) if p.name != 'env_id']


def test_the_success_rules_of_the_message_are_the_cores():
    constants = {getattr(EnvInfo, name) for name in dir(EnvInfo) if name.startswith('SUCCESS_')}
    assert constants == set(SUCCESS_RULES)


def test_env_info_round_trips_and_a_self_contradicting_one_is_refused():
    spec = EnvSpec('robot', 4, [-1.0, 0.0], [1.0, 2.0], ('a', 'b', 'c', 'd'), ('u', 'w'), 50, True, 30.0, 'reported')
    back = env_info.spec_from_msg(env_info.env_info_msg(spec))
    assert back == spec and not spec.disagreements(back)
    bad = env_info.env_info_msg(spec)
    bad.action_size = 3
    with pytest.raises(ValueError, match='action_size 3 but 2 action bounds'):
        env_info.spec_from_msg(bad)
    with pytest.raises(ValueError, match='high > low'):
        EnvSpec('robot', 4, [1.0], [1.0])


@pytest.mark.parametrize(
    'label',
    ['\x1b[2Jforce', 'force\nsecond line', 'f' * 65, 'x' * 1_000_000],
    ids=['escape', 'newline', '65', 'megabyte'],
)
def test_a_label_that_is_not_one_short_printable_line_is_refused(label):
    """Labels go to a person's page and terminal: an escape sequence, a second line or a long text
    is refused, in a message of bounded length (not echoed whole)."""
    with pytest.raises(ValueError, match='each label must be printable text on one line') as refused:
        EnvSpec('robot', 2, [-1.0], [1.0], action_labels=(label,))
    assert len(str(refused.value)) < 200 and '\x1b' not in str(refused.value)  # shown escaped
    with pytest.raises(ValueError, match='observation label'):
        EnvSpec('robot', 2, [-1.0], [1.0], observation_labels=('x', label))
    assert EnvSpec('robot', 2, [-1.0], [1.0], ('θ (rad)', 'x<y & "z"'), ('f' * 64,)).action_labels == ('f' * 64,)


@pytest.mark.parametrize('rate_hz', [float('nan'), float('inf'), -20.0])
def test_an_env_info_whose_rate_is_no_number_of_steps_a_second_is_refused(rate_hz):
    """From outside: a real-time env_info with rate_hz NaN or infinite was taken, the learner read
    the episode's seconds left from it as 0, and every request for the wheel ended before a person
    could take it, unsaid."""
    info = env_info.env_info_msg(EnvSpec('robot', 2, [-1.0], [1.0], realtime=True, rate_hz=20.0))
    info.rate_hz = rate_hz
    with pytest.raises(ValueError, match=r'rate_hz must be a finite number of steps a second, >= 0 \(0: not said\)'):
        env_info.spec_from_msg(info)
    assert env_info.spec_from_msg(env_info.env_info_msg(EnvSpec('robot', 2, [-1.0], [1.0], rate_hz=0.0))).rate_hz == 0.0


def test_a_learner_without_env_id_waits_for_env_info_then_learns_from_the_example_env(
    harness, ros_context, tmp_path, caplog
):
    """Started before the env, the learner and the expert wait; the env's env_info configures
    both (the expert picks its PD law by the env's name), and advice is given and counted."""
    expert = harness.add(ExpertNode(context=ros_context))
    learner = harness.add(LearnerNode(context=ros_context, parameter_overrides=no_env_id(tmp_path, max_episodes=3)))
    harness.spin_until(lambda: False, timeout=0.3)
    assert learner.learner is None and expert.backend is None  # nothing to act on yet
    env = harness.add(
        DoubleIntegratorEnv(context=ros_context, parameter_overrides=params(max_episode_steps=30, seed=3))
    )
    assert harness.spin_until(lambda: learner.done, timeout=60)
    assert learner.spec.name == 'double_integrator' and learner.learner.obs_dim == 2
    assert isinstance(expert.backend, DoubleIntegratorExpert)
    totals = learner.learner.advice_total
    assert totals.asked > 0 and totals.given == totals.asked  # the PD expert answered every request
    with open(tmp_path / 'episodes.csv', newline='') as f:
        rows = list(csv.DictReader(f))
    assert [int(r['length']) for r in rows] == [30, 30, 30]
    assert sum(int(r['advice_given']) for r in rows) == totals.given
    assert env.episode == 3


def test_the_env_reports_success_and_the_learner_takes_its_verdict(harness, ros_context, tmp_path):
    learner = harness.add(
        LearnerNode(
            context=ros_context,
            parameter_overrides=no_env_id(
                tmp_path, observation_size=2, action_low=[-1.0], action_high=[1.0], max_episodes=2
            ),
        )
    )
    publisher, probe = observation_publisher(harness)
    for episode, verdict in enumerate((True, False)):
        for step in range(4):
            final = step == 3
            count = len(probe.actions)
            publisher.publish(
                messages.observation_msg([0.1, 0.0], -1.0, False, final, episode, step, final and verdict)
            )
            if not final:
                assert harness.spin_until(lambda: len(probe.actions) > count)
    assert harness.spin_until(lambda: learner.done)
    with open(tmp_path / 'episodes.csv', newline='') as f:
        assert [r['success'] for r in csv.DictReader(f)] == ['1', '0']


def test_spaces_as_parameters_work_with_an_env_that_publishes_no_env_info(harness, ros_context, tmp_path):
    learner = harness.add(
        LearnerNode(
            context=ros_context,
            parameter_overrides=no_env_id(tmp_path, observation_size=2, action_low=[-2.0], action_high=[2.0]),
        )
    )
    assert learner.spec.source == 'parameters' and learner.learner.scaler.high.tolist() == [2.0]
    publisher, probe = observation_publisher(harness)
    publisher.publish(messages.observation_msg([0.3, -0.1], 0.0, False, False, 0, 0))
    assert harness.spin_until(lambda: probe.acted_on() == [(0, 0)])
    action = messages.parse_fields(probe.actions[-1])['action']
    assert -2.0 <= action <= 2.0


@pytest.mark.parametrize(
    'spaces,message',
    [
        (dict(observation_size=2), 'action_low, action_high are missing'),
        (dict(observation_size=2, action_low=[-1.0], action_high=[1.0, 2.0]), 'one per action dimension'),
        (dict(env_id='Pendulum-v1', observation_size=2, action_low=[-2.0], action_high=[2.0]), 'observation size 2'),
    ],
)
def test_incomplete_or_contradictory_spaces_are_refused_at_start_up(ros_context, tmp_path, spaces, message):
    overrides = [p for p in small_learner_params(tmp_path) if p.name not in spaces] + params(**spaces)
    looker = rclpy.create_node('looker', context=ros_context)
    with pytest.raises(ValueError, match=message):
        LearnerNode(context=ros_context, parameter_overrides=overrides)
    # Nothing of the refused node is left on the graph: before, its publisher of action stayed
    # until the garbage collector came, and an env took it for a second node driving it.
    assert looker.count_publishers('/action') == 0 and looker.count_subscribers('/observation') == 0
    looker.destroy_node()


def test_a_learner_configured_for_another_env_refuses_its_env_info(harness, ros_context, tmp_path):
    learner = harness.add(LearnerNode(context=ros_context, parameter_overrides=small_learner_params(tmp_path)))
    harness.add(DoubleIntegratorEnv(context=ros_context))
    assert harness.spin_until(lambda: not ros_context.ok(), timeout=10)
    assert 'observation size 2, not 3; action bounds [[-1.0], [1.0]], not [[-2.0], [2.0]]' in learner.exit_error
    assert 'configured by env_id Pendulum-v1' in learner.exit_error


def test_teleop_expert_takes_the_action_size_from_env_info_and_refuses_a_mapping_of_another_size(harness, ros_context):
    teleop = harness.add(
        TeleopExpertNode(
            context=ros_context,
            parameter_overrides=params(source='array', axes=[0, 1], scales=[1.0, 1.0], offsets=[0.0, 0.0]),
        )
    )
    harness.add(DoubleIntegratorEnv(context=ros_context))
    assert harness.spin_until(lambda: not ros_context.ok(), timeout=10)
    assert "the mapping gives 2 action value(s) (parameter 'scales'), env 'double_integrator' takes 1" in (
        teleop.exit_error
    )


def test_a_person_advises_on_the_example_env_through_teleop_expert(harness, ros_context, tmp_path):
    """teleop_expert and a person's command (here a PD law on the latest observation) against the
    example env with no gymnasium id: advice is given, counted as a person's. The person steers
    all along (answer_mode instant)."""
    teleop = harness.add(
        TeleopExpertNode(
            context=ros_context,
            parameter_overrides=params(
                source='array', axes=[0], scales=[1.0], offsets=[0.0], stale_after_s=5.0, answer_mode='instant'
            ),
        )
    )
    person = harness.add(rclpy.create_node('keyboard_teleop', context=ros_context))
    command_pub = person.create_publisher(Float32MultiArray, 'teleop_command', 10)
    controller = DoubleIntegratorExpert()

    def follow(msg):
        step = messages.parse_observation(msg, 2)
        command_pub.publish(messages.build([('command', controller.action(step.obs))]))

    person.create_subscription(Float32MultiArray, 'observation', follow, 10)
    harness.add(DoubleIntegratorEnv(context=ros_context, parameter_overrides=params(max_episode_steps=30)))
    learner = harness.add(
        LearnerNode(context=ros_context, parameter_overrides=no_env_id(tmp_path, mode='qasac', max_episodes=2))
    )
    assert harness.spin_until(lambda: learner.done, timeout=60)
    assert teleop.env_info.spec.name == 'double_integrator'
    totals = learner.learner.advice_total
    assert totals.given > 0 and totals.human == totals.given


def test_keyboard_teleop_takes_its_dimensions_from_env_info(harness, ros_context):
    read_end, write_end = os.pipe()
    try:
        keyboard = harness.add(KeyboardTeleop(read_end, io.StringIO(), context=ros_context))
        assert len(keyboard.command) == 0  # nothing to command yet: nothing is published
        harness.add(GymEnvNode(context=ros_context, parameter_overrides=params(env_id='LunarLanderContinuous-v3')))
        assert harness.spin_until(lambda: len(keyboard.command) == 2, timeout=10)
        keyboard.on_key('d')
        assert keyboard.command.tolist() == [0.25, 0.0]
    finally:
        os.close(read_end)
        os.close(write_end)


def test_an_expert_with_no_controller_for_the_env_says_so(harness, ros_context):
    expert = harness.add(ExpertNode(context=ros_context))
    info = harness.add(rclpy.create_node('some_env', context=ros_context))
    info.create_publisher(Float32MultiArray, 'observation', 10)  # an env publishes its observations
    publisher = info.create_publisher(EnvInfo, 'env_info', env_info.ENV_INFO_QOS)
    publisher.publish(env_info.env_info_msg(EnvSpec('my_arm', 6, [-1.0] * 3, [1.0] * 3)))
    assert harness.spin_until(lambda: not ros_context.ok(), timeout=10)
    assert "no heuristic expert for 'my_arm'" in expert.exit_error


SHARED = """
gym_env:
  ros__parameters:
    max_episode_steps: 20
expert:
  ros__parameters:
    backend: heuristic
teleop_expert:
  ros__parameters:
    source: array
learner:
  ros__parameters:
    mode: qasac
    output_dir: {output}
keyboard_teleop:
  ros__parameters:
    dimensions: 1
/**:
  ros__parameters:
    env_id: Pendulum-v1
    use_sim_time: false
"""


def make_all(context, tmp_path):
    read_end, write_end = os.pipe()
    nodes = []
    try:
        nodes.append(GymEnvNode(context=context))
        nodes.append(ExpertNode(context=context))
        nodes.append(TeleopExpertNode(context=context))
        nodes.append(KeyboardTeleop(read_end, io.StringIO(), context=context))
        nodes.append(LearnerNode(context=context))
        return list(nodes)
    finally:
        for node in nodes:
            if isinstance(node, LearnerNode):
                node.close()
            node.destroy_node()
        os.close(read_end)
        os.close(write_end)


def init_with(tmp_path, text, *extra):
    path = tmp_path / 'shared.yaml'
    path.write_text(text.format(output=tmp_path / 'run'))
    context = rclpy.Context()
    rclpy.init(context=context, args=['--ros-args', '--params-file', str(path), *extra])
    return context


def test_a_shared_section_last_in_the_file_keeps_the_command_line_in_charge(tmp_path):
    """rcl puts -p values in the '/**' section and applies sections in file order: with the
    shared section last (as in the shipped files), -p overrides a node's own section."""
    context = init_with(tmp_path, SHARED, '-p', 'mode:=sac')
    try:
        learner = LearnerNode(context=context)
        assert learner.config.mode == 'sac' and learner.params['env_id'] == 'Pendulum-v1'
        learner.close()
        learner.destroy_node()
    finally:
        context.try_shutdown()


def test_a_shared_section_loads_into_every_node_and_a_typo_in_a_nodes_own_section_is_refused(tmp_path):
    import yaml

    context = init_with(tmp_path, SHARED)
    try:
        nodes = make_all(context, tmp_path)
        assert [n.get_parameter('env_id').value for n in nodes] == ['Pendulum-v1'] * 5
        assert nodes[-1].config.mode == 'qasac'
    finally:
        context.try_shutdown()
    data = yaml.safe_load(SHARED)
    assert file_section(data, 'learner')['env_id'] == 'Pendulum-v1'
    # eqhrl-experiment reads a file as rcl applies it: sections in file order, the later wins.
    own, shared = {'ros__parameters': {'env_id': 'own'}}, {'ros__parameters': {'env_id': 'shared'}}
    assert file_section({'learner': own, '/**': shared}, 'learner')['env_id'] == 'shared'
    assert file_section({'/**': shared, 'learner': own}, 'learner')['env_id'] == 'own'

    typo = SHARED.replace('    mode: qasac', '    mdoe: qasac')
    shared_typo = SHARED.replace('    use_sim_time: false', '    use_sim_tmie: false')
    for text, refusal in ((typo, "unknown parameter\\(s\\) for node 'learner': mdoe"), (shared_typo, 'use_sim_tmie')):
        context = init_with(tmp_path, text)
        try:
            with pytest.raises(ValueError, match=refusal):
                make_all(context, tmp_path)
        finally:
            context.try_shutdown()
    with pytest.raises(ValueError, match="the shared '/\\*\\*' section holds use_sim_tmie"):
        file_section(yaml.safe_load(shared_typo), 'learner')


def test_the_example_env_is_solved_by_its_expert_and_not_by_chance():
    """The numbers its docstring states: PD about -4 and at rest; random pushing far worse."""
    returns = {'pd': [], 'random': []}
    rests = 0
    for seed in range(20):
        for name in returns:
            system, rng = DoubleIntegrator(seed=seed), np.random.default_rng(seed)
            obs, total = system.reset(), 0.0
            for _ in range(100):
                u = DoubleIntegratorExpert().action(obs)[0] if name == 'pd' else rng.uniform(-1, 1)
                obs, reward = system.step(u)
                total += reward
            returns[name].append(total)
            rests += name == 'pd' and system.at_rest()
    assert -6 < np.mean(returns['pd']) < -2 and rests == 20
    assert np.mean(returns['random']) < -300


def test_a_learner_at_work_logs_and_ignores_a_disagreeing_env_info(harness, ros_context, tmp_path):
    """Any node can publish on env_info: a run in progress is not ended on its word."""
    learner = harness.add(
        LearnerNode(
            context=ros_context,
            parameter_overrides=no_env_id(tmp_path, observation_size=2, action_low=[-1.0], action_high=[1.0]),
        )
    )
    publisher, probe = observation_publisher(harness)
    for step in range(3):
        publisher.publish(messages.observation_msg([0.1, 0.0], -1.0, False, False, 0, step))
        assert harness.spin_until(lambda: len(probe.acted_on()) == step + 1)
    intruder = probe.node.create_publisher(EnvInfo, 'env_info', env_info.ENV_INFO_QOS)
    intruder.publish(env_info.env_info_msg(EnvSpec('fake', 7, [-5.0], [5.0])))
    assert harness.spin_until(lambda: learner.env_info.ignored == 1)
    assert ros_context.ok() and getattr(learner, 'exit_error', None) is None
    publisher.publish(messages.observation_msg([0.1, 0.0], -1.0, False, False, 0, 3))
    assert harness.spin_until(lambda: probe.acted_on()[-1] == (0, 3))
    assert learner.learner.total_steps == 3


def test_a_hostile_env_info_is_refused_with_a_bounded_line(harness, ros_context, tmp_path):
    """A megabyte name and a billion observation values: refused before any network is made,
    in a log line of bounded length."""
    learner = harness.add(LearnerNode(context=ros_context, parameter_overrides=no_env_id(tmp_path)))
    info = harness.add(rclpy.create_node('hostile', context=ros_context))
    info.create_publisher(Float32MultiArray, 'observation', 10)  # it poses as the env
    msg = EnvInfo(
        name='\x1b[2J' + 'x' * 1_000_000, observation_size=10**9, action_size=1, action_low=[-1.0], action_high=[1.0]
    )
    info.create_publisher(EnvInfo, 'env_info', env_info.ENV_INFO_QOS).publish(msg)
    assert harness.spin_until(lambda: not ros_context.ok(), timeout=10)
    assert learner.learner is None
    assert 'observation size must be in [1, 1,000,000], got 1000000000' in learner.exit_error
    assert len(learner.exit_error) < 300 and '\x1b' not in learner.exit_error


def test_an_env_info_from_a_node_that_is_not_the_env_is_held_not_obeyed(harness, ros_context, tmp_path):
    """A stranger latches env_info before the env starts: before, a learner with no spaces took
    its bounds of +-100 and acted outside [-2, 2]; given env_id, it exited with 1 before the run.
    Now the message is held while its publisher publishes no observation, and the real env's
    env_info is taken once the stranger has gone."""
    configured = harness.add(
        LearnerNode(context=ros_context, parameter_overrides=no_env_id(tmp_path / 'a', env_id='Pendulum-v1'))
    )
    waiting = harness.add(
        LearnerNode(context=ros_context, namespace='/b', parameter_overrides=no_env_id(tmp_path / 'b'))
    )
    rogue = rclpy.create_node('rogue', context=ros_context)
    harness.add(rogue)
    fake = env_info.env_info_msg(EnvSpec('Pendulum-v1', 3, [-100.0], [100.0]))
    rogue.create_publisher(EnvInfo, 'env_info', env_info.ENV_INFO_QOS).publish(fake)
    rogue.create_publisher(EnvInfo, '/b/env_info', env_info.ENV_INFO_QOS).publish(fake)
    assert harness.spin_until(lambda: configured.env_info.untrusted >= 1 and waiting.env_info.untrusted >= 1)
    harness.spin_until(lambda: False, timeout=1.5)  # rechecked meanwhile: still the stranger
    assert ros_context.ok() and getattr(configured, 'exit_error', None) is None
    assert waiting.learner is None  # no spaces from a stranger
    harness.nodes.remove(rogue)
    rogue.destroy_node()
    env = harness.add(GymEnvNode(context=ros_context, namespace='/b', parameter_overrides=params(max_episode_steps=20)))
    assert harness.spin_until(lambda: waiting.learner is not None, timeout=20)
    assert waiting.learner.scaler.high.tolist() == [2.0] and env is not None


def test_an_expert_beside_an_env_on_remapped_topics_says_to_remap_its_observation_and_then_takes_it(
    harness, ros_context
):
    """From outside: the env's and the learner's `observation` remapped to the robot's topic, the
    expert's not (it reads no observation). The expert held the env's env_info for ever, saying
    the env "does not publish it" (it did), and every request failed as unavailable."""
    robot = ['--ros-args', '-r', 'observation:=/robot/obs', '-r', 'action:=/robot/cmd']
    harness.add(DoubleIntegratorEnv(context=ros_context, cli_args=robot))
    plain = harness.add(ExpertNode(context=ros_context))
    remapped = harness.add(ExpertNode(context=ros_context, cli_args=[*robot[:3], '-r', '__node:=expert_b']))
    assert harness.spin_until(lambda: remapped.env_info.ready, timeout=10)  # remapped as the hint says: taken
    assert not plain.env_info.ready
    said = plain.env_info.refusal(env_info.env_info_msg(remapped.env_info.spec, publisher='/double_integrator_env'))
    assert said == (
        '/env_info names its publisher /double_integrator_env, which is not the publisher of /observation (if '
        "/double_integrator_env is your env and its observations go elsewhere, remap this node's observation there "
        'too, -r observation:=<that topic>, or name the env: -p env_node:=/double_integrator_env)'
    )
    # A name written without its namespace (the README asks for get_fully_qualified_name()): said so.
    said = remapped.env_info.refusal(env_info.env_info_msg(remapped.env_info.spec, publisher='double_integrator_env'))
    assert said.endswith(
        'which the graph does not show publishing it (a full node name starts with /: get_fully_qualified_name())'
    )


def test_a_learner_holding_a_strangers_env_info_takes_the_real_envs_though_the_stranger_stays(
    harness, ros_context, tmp_path, monkeypatch
):
    """The stranger's latched env_info stays on the graph when the env starts: before, the learner
    held both and waited for ever (0 episodes in 60 s). The env's own names it as its publisher.
    Its first drop is an info line (the README's own env warned so at a normal start), the next a
    warning."""
    monkeypatch.setattr(env_info, 'NAMED_HOLD_S', 0.5)
    monkeypatch.setattr(env_info, 'RESUBSCRIBE_S', 1.0)
    waiting = harness.add(LearnerNode(context=ros_context, parameter_overrides=no_env_id(tmp_path)))
    lines = {'info': [], 'warn': []}
    logger = waiting.get_logger()
    waiting.get_logger = lambda: SimpleNamespace(  # what the node says of it, by level
        info=lambda line, **kw: lines['info'].append(line),
        warn=lambda line, **kw: lines['warn'].append(line),
        error=logger.error,
    )
    rogue = harness.add(rclpy.create_node('rogue', context=ros_context))
    fake = env_info.env_info_msg(EnvSpec('Pendulum-v1', 3, [-100.0], [100.0]), publisher='/gym_env')  # a forged name
    rogue.create_publisher(EnvInfo, 'env_info', env_info.ENV_INFO_QOS).publish(fake)
    assert harness.spin_until(lambda: waiting.env_info.untrusted >= 1)
    # Held: most often the graph only lags a starting env, so an info line, not yet a warning.
    assert any(line.startswith('env_info held, not obeyed yet') for line in lines['info']) and not lines['warn']
    refused = 'env_info not obeyed: /env_info names its publisher /gym_env, which the graph does not show publishing it'
    # Dropped, and still an info line: the node subscribes anew, and a slow graph's env is taken then.
    assert harness.spin_until(lambda: any(line.startswith(refused) for line in lines['info']), timeout=5)
    assert not lines['warn']
    # Dropped again when it came again: now a warning.
    assert harness.spin_until(lambda: lines['warn'], timeout=5)
    assert waiting.learner is None and waiting.env_info.resubscribed >= 1  # no spaces from a stranger
    assert [line.split(';')[0] for line in lines['warn']] == [refused]
    del waiting.get_logger
    harness.add(GymEnvNode(context=ros_context, parameter_overrides=params(max_episode_steps=20)))
    assert harness.spin_until(lambda: waiting.learner is not None, timeout=20)
    assert waiting.learner.scaler.high.tolist() == [2.0]
    assert harness.spin_until(lambda: waiting.learner.total_steps > 0, timeout=20)


@pytest.mark.parametrize(
    'observation,low,problem',
    [
        ([0.5], [-2.0], "observation has 1 values; the env 'Pendulum-v1' has 3"),
        ([0.0, 1.0, 0.0], [-2.0, -2.0], "action_low has 2 values; the env 'Pendulum-v1' has 1"),
        ([0.0, float('nan'), 0.0], [-2.0], 'non-finite'),
    ],
)
def test_an_expert_declines_a_request_of_the_wrong_size_naming_the_sizes(
    harness, ros_context, observation, low, problem
):
    """Before: declined with the backend's own error ('not enough values to unpack (expected 3, got 1)')."""
    from eqhrl_interfaces.srv import Advise

    harness.add(ExpertNode(context=ros_context, parameter_overrides=params(env_id='Pendulum-v1')))
    caller = harness.add(rclpy.create_node('caller', context=ros_context))
    client = caller.create_client(Advise, 'advise')
    assert harness.spin_until(client.service_is_ready)
    future = client.call_async(
        Advise.Request(
            observation=observation, proposed_action=[0.0], action_low=low, action_high=[2.0] * len(low), timeout_s=1.0
        )
    )
    assert harness.spin_until(future.done)
    response = future.result()
    assert not response.advised and problem in response.reason and 'unpack' not in response.reason


@pytest.mark.parametrize('answer_mode', ['window', 'instant'])
def test_experts_decline_action_bounds_that_cannot_be_the_envs(harness, ros_context, answer_mode):
    """Before (ros2 service call, from outside): an expert for Pendulum ([-2, 2]) asked with bounds
    [-0.5, 0.5] answered -2.0, outside them; bounds upside down were answered by every expert, and
    teleop_expert answered NaN bounds with a NaN action (or alerted its person to them)."""
    from eqhrl_interfaces.srv import Advise

    spaces = dict(observation_size=3, action_low=[-2.0], action_high=[2.0])
    harness.add(ExpertNode(context=ros_context, parameter_overrides=params(env_id='Pendulum-v1', **spaces)))
    teleop = params(source='array', axes=[0], scales=[1.0], offsets=[0.0], answer_mode=answer_mode)
    harness.add(TeleopExpertNode(context=ros_context, namespace='/person', parameter_overrides=teleop))
    caller = harness.add(rclpy.create_node('caller', context=ros_context))
    clients = {name: caller.create_client(Advise, name) for name in ('advise', '/person/advise')}

    def ask(name, low, high):
        client = clients[name]
        assert harness.spin_until(client.service_is_ready)
        request = Advise.Request(observation=[1.0, 0.0, 5.0], proposed_action=[0.0], action_low=low, action_high=high)
        future = client.call_async(request)
        assert harness.spin_until(future.done, timeout=2.0)  # at once: no person's window opened
        return future.result()

    narrow, own = ask('advise', [-0.5], [0.5]), ask('advise', [-2.0], [2.0])
    assert not narrow.advised and 'action bounds [[-0.5], [0.5]], not [[-2.0], [2.0]]' in narrow.reason
    assert own.advised and -2.0 <= own.action[0] <= 2.0
    for name in clients:
        upside_down, nan = ask(name, [2.0], [-2.0]), ask(name, [float('nan')], [2.0])
        assert not upside_down.advised and 'low < high' in upside_down.reason, name
        assert not nan.advised and 'non-finite' in nan.reason, name


@pytest.mark.parametrize('configured_by', ['env_info', 'env_id'])
def test_the_envs_own_env_info_dropped_while_the_graph_was_slow_is_taken_when_it_comes_again(
    harness, ros_context, tmp_path, monkeypatch, configured_by
):
    """The env's latched env_info names it, but its observation publisher is not on the graph yet
    (discovery across processes under load): held, then dropped after NAMED_HOLD_S. It is published
    once, so the learner waited for ever (an eqhrl-experiment run hung in CI). Now a node that has
    not heard the env subscribes anew, and the message comes again, and is taken once the env is
    vouched for. Configured by env_id, the learner has its spaces but needs the env's pace
    (advice_protocol auto): before, it never subscribed anew, and with the README's three terminals
    every request of the run was counted unavailable, nothing asked (seen on a busy start)."""
    monkeypatch.setattr(env_info, 'NAMED_HOLD_S', 0.5)
    monkeypatch.setattr(env_info, 'RESUBSCRIBE_S', 1.0)
    overrides = no_env_id(tmp_path) if configured_by == 'env_info' else small_learner_params(tmp_path)
    learner = harness.add(LearnerNode(context=ros_context, parameter_overrides=overrides))
    env = harness.add(rclpy.create_node('slow_env', context=ros_context))
    spec = EnvSpec('Pendulum-v1', 3, [-2.0], [2.0])
    env.create_publisher(EnvInfo, 'env_info', env_info.ENV_INFO_QOS).publish(env_info.env_info_msg(spec, '/slow_env'))
    assert harness.spin_until(lambda: learner.env_info.untrusted >= 1, timeout=10)
    harness.spin_until(lambda: False, timeout=1.5)  # held past its time: dropped
    assert (learner.learner is None) == (configured_by == 'env_info') and learner.protocol == ''
    env.create_publisher(Float32MultiArray, 'observation', 10)  # the env's observations now show
    assert harness.spin_until(lambda: learner.env_info.announced is not None, timeout=10)
    assert learner.env_info.resubscribed >= 1 and learner.learner.scaler.high.tolist() == [2.0]
    assert learner.protocol == 'answer'  # the env said it runs lock-step: one answer per request


def test_auto_waits_on_while_the_envs_env_info_is_judged_then_asks_as_the_env_says(
    harness, ros_context, tmp_path, monkeypatch
):
    """Three robots' nodes started at once on 2 cores (from outside, ros2 run in namespaces): one
    learner held its env's env_info (the graph did not show the env's node yet), dropped it, and
    heard it again 5 s on; at 3 s it had acted, and its first request was counted unavailable,
    nothing asked. Now the first observation waits on while an env_info that came is judged (up to
    AUTO_PACE_JUDGED_S), and is acted on once the env's own is taken: no request goes unasked."""
    monkeypatch.setattr(env_info, 'NAMED_HOLD_S', 0.5)
    monkeypatch.setattr(env_info, 'RESUBSCRIBE_S', 1.0)
    monkeypatch.setattr(start_wait, 'AUTO_PACE_WAIT_S', 1.0)
    learner = harness.add(LearnerNode(context=ros_context, parameter_overrides=asking_learner_params(tmp_path)))
    expert = StubExpert(ros_context)
    try:
        publisher, probe = observation_publisher(harness)
        assert harness.spin_until(lambda: learner.advice.ready(), timeout=10)
        env = harness.add(rclpy.create_node('slow_env', context=ros_context))  # its observations not shown yet
        message = env_info.env_info_msg(EnvSpec('Pendulum-v1', 3, [-2.0], [2.0]), '/slow_env')
        env.create_publisher(EnvInfo, 'env_info', env_info.ENV_INFO_QOS).publish(message)
        assert harness.spin_until(lambda: learner.env_info.untrusted >= 1, timeout=10)
        publisher.publish(messages.observation_msg([1.0, 0.0, 0.0], -1.0, False, False, 0, 0))
        harness.spin_until(lambda: False, timeout=2.5)  # past the pace's wait, a hold and a new subscription
        assert learner.start_wait.state == 'waiting' and probe.acted_on() == []
        shown = env.create_publisher(Float32MultiArray, 'observation', 10)  # the graph catches up
        assert harness.spin_until(lambda: learner.env_info.announced is not None, timeout=10)
        assert harness.spin_until(lambda: (0, 0) in probe.acted_on(), timeout=5) and learner.protocol == 'answer'
        env.destroy_publisher(shown)  # the probe alone plays the env again
        assert harness.spin_until(lambda: not learner.observation_source.refusal(), timeout=10)
        for step in range(1, 40):
            publisher.publish(messages.observation_msg([1.0, 0.0, 0.0], -1.0, False, False, 0, step))
            assert harness.spin_until(lambda: (0, step) in probe.acted_on(), timeout=10)
        assert expert.requests and learner.learner.episode_advice.failed['unavailable'] == 0
    finally:
        expert.close()


def test_an_env_info_vouched_for_when_its_hold_ends_is_taken_not_dropped(harness, ros_context, tmp_path):
    """Seen with an env written from the README: the graph showed the env's observation publisher
    between two looks, and the look at which its hold ended dropped it first, logging a warning that
    its sender 'is not vouched for' while it was. The node took it only on subscribing anew, 5 s on."""
    learner = harness.add(LearnerNode(context=ros_context, parameter_overrides=no_env_id(tmp_path)))
    env = harness.add(rclpy.create_node('own_env', context=ros_context))
    env.create_publisher(Float32MultiArray, 'observation', 10)
    assert harness.spin_until(lambda: learner.env_info._vouched() == {'/own_env'}, timeout=10)
    spec = EnvSpec('Pendulum-v1', 3, [-2.0], [2.0])
    message = env_info.env_info_msg(spec, '/own_env')
    env.create_publisher(EnvInfo, 'env_info', env_info.ENV_INFO_QOS)
    assert harness.spin_until(lambda: '/own_env' in env_info.publishers(learner, learner.env_info.topic), timeout=10)
    # Held when it came (the graph lagged then), and its time is up at this look.
    learner.env_info._held.append((time.monotonic() - env_info.NAMED_HOLD_S - 1.0, message, set()))
    learner.env_info._on_recheck()
    assert learner.learner is not None and learner.learner.scaler.high.tolist() == [2.0]
    assert learner.env_info.announced is not None


def test_auto_asks_nothing_until_the_env_says_its_pace_then_asks_for_the_wheel(harness, ros_context, tmp_path):
    """advice_protocol auto, configured by env_id: an env_id says nothing of real time. Before, such
    a learner asked a real-time env's person for one answer until the env's env_info came (the
    robot had moved on); now it holds the first observation for AUTO_PACE_WAIT_S, then acts, and a
    gate that fires asks nothing, counted as unavailable; once the env says it runs in real time,
    the request is for the wheel, while a person's teleop_expert is there to take it."""
    learner = harness.add(LearnerNode(context=ros_context, parameter_overrides=asking_learner_params(tmp_path)))
    expert = StubExpert(ros_context)  # an answer would be served: only the protocol keeps it from being asked
    try:
        publisher, probe = observation_publisher(harness)
        requests = []
        probe.node.create_subscription(
            AdviceRequestMsg, 'learner/advice_request', requests.append, messages.LATCHED_QOS
        )
        assert harness.spin_until(lambda: learner.advice.ready(), timeout=10)

        def steps(first, count):
            for step in range(first, first + count):
                publisher.publish(messages.observation_msg([1.0, 0.0, 0.0], -1.0, False, False, 0, step))
                assert harness.spin_until(lambda: (0, step) in probe.acted_on(), timeout=10)

        started = time.monotonic()
        steps(0, 40)
        assert time.monotonic() - started >= AUTO_PACE_WAIT_S - 0.1  # the first observation waited
        assert learner.learner.episode_advice.failed['unavailable'] >= 1  # the gates fired (20 % of steps)
        assert requests == [] and expert.requests == []
        spec = EnvSpec('Pendulum-v1', 3, [-2.0], [2.0], realtime=True, rate_hz=20.0, max_episode_steps=1000)
        info = env_info.env_info_msg(spec, publisher=probe.node.get_fully_qualified_name())
        probe.node.create_publisher(EnvInfo, 'env_info', env_info.ENV_INFO_QOS).publish(info)
        assert harness.spin_until(lambda: learner.env_info.announced is not None, timeout=10)
        # No node publishes person_command yet: nobody could take the wheel. Before, the requests
        # were made anyway, each counting person's seconds though no person was there.
        unavailable = learner.learner.episode_advice.failed['unavailable']
        steps(40, 40)
        assert requests == [] and expert.requests == [] and learner.learner.human_time_total_s == 0
        assert learner.learner.episode_advice.failed['unavailable'] > unavailable
        person = harness.add(rclpy.create_node('teleop_expert', context=ros_context))
        person.create_publisher(Float32MultiArray, 'person_command', 10)
        assert harness.spin_until(learner.person_guard.heard_from, timeout=10)
        unavailable = learner.learner.episode_advice.failed['unavailable']
        steps(80, 40)
        assert requests and all(r.wheel for r in requests) and expert.requests == []
        assert learner.learner.episode_advice.failed['unavailable'] == unavailable
    finally:
        expert.close()


def test_auto_holds_the_first_observation_until_the_env_says_its_pace(harness, ros_context, tmp_path):
    """The env's env_info comes a moment after its first observation (it is taken once the graph
    vouches for the env). A learner that acted at once asked nothing, or the wrong way, for its
    first steps (test_person_nodes counted a whole episode of 'unavailable' on CI); it holds the
    observation until env_info says the pace, then acts on it at once, and its first request is
    for the wheel in a real-time env. A real-time env goes on meanwhile: its later observations are
    held too and acted on in order (holding only the latest, the learner joined its first episode at
    step 1, marked interrupted: test_realtime_rate failed so on CI)."""
    learner = harness.add(
        LearnerNode(context=ros_context, parameter_overrides=asking_learner_params(tmp_path, random_ask_rate=1.0))
    )
    person = harness.add(rclpy.create_node('teleop_expert', context=ros_context))  # who could take the wheel
    person.create_publisher(Float32MultiArray, 'person_command', 10)
    publisher, probe = observation_publisher(harness)
    requests = []
    probe.node.create_subscription(AdviceRequestMsg, 'learner/advice_request', requests.append, messages.LATCHED_QOS)
    assert harness.spin_until(learner.person_guard.heard_from, timeout=10)
    for step in range(3):  # the env's ticks before its env_info is heard
        publisher.publish(messages.observation_msg([1.0, 0.0, 0.1 * step], 0.0, False, False, 0, step))
        harness.spin_until(lambda: False, timeout=0.25)
    assert probe.acted_on() == [] and learner.learner.total_steps == 0  # held, not acted on
    spec = EnvSpec('Pendulum-v1', 3, [-2.0], [2.0], realtime=True, rate_hz=20.0, max_episode_steps=1000)
    info = env_info.env_info_msg(spec, publisher=probe.node.get_fully_qualified_name())
    probe.node.create_publisher(EnvInfo, 'env_info', env_info.ENV_INFO_QOS).publish(info)
    heard = time.monotonic()
    assert harness.spin_until(lambda: (0, 0) in probe.acted_on(), timeout=AUTO_PACE_WAIT_S)
    assert time.monotonic() - heard < AUTO_PACE_WAIT_S - 0.5  # on env_info, not at the end of the wait
    assert harness.spin_until(lambda: len(probe.acted_on()) >= 3, timeout=2)
    assert probe.acted_on()[:3] == [(0, 0), (0, 1), (0, 2)]  # each one held, in order: the episode seen whole
    assert learner.tracking.observation_gaps == 0 and learner.learner.episode_step == 2  # two transitions stored
    assert not learner.learner.episode_interrupted
    assert harness.spin_until(lambda: bool(requests), timeout=2)
    assert requests[0].wheel and learner.learner.episode_advice.failed['unavailable'] == 0
