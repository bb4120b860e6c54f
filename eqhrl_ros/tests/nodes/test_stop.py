"""The person's stop (std_msgs/Bool on `stop`, latched) and the action rate limit, on the env nodes
that ship, and the console's STOP in a real browser."""

import numpy as np
import pytest
import rclpy
from std_msgs.msg import Bool

from eqhrl_ros.nodes import messages
from eqhrl_ros.nodes.double_integrator_env_node import DoubleIntegratorEnv
from eqhrl_ros.nodes.gym_env_node import GymEnvNode

from ros_helpers import Probe, params


def stopper(harness):
    node = harness.add(rclpy.create_node('person_stop', context=harness.context))
    return node.create_publisher(Bool, messages.STOP_TOPIC, messages.STOP_QOS)


def test_a_stopped_lock_step_env_takes_no_step_and_goes_on_from_the_same_state(harness, ros_context):
    env = harness.add(GymEnvNode(context=ros_context, parameter_overrides=params(max_episode_steps=50)))
    probe = Probe(harness)
    stop = stopper(harness)
    assert harness.spin_until(lambda: probe.action_pub.get_subscription_count() > 0 and probe.observations)

    def act(value=0.5):
        fields = messages.read_fields(probe.observations[-1])
        probe.action_pub.publish(messages.action_msg([value], int(fields['episode'][0]), int(fields['step'][0])))

    def step_and_see():
        before = env.steps_taken
        act()
        assert harness.spin_until(lambda: env.steps_taken == before + 1)
        assert harness.spin_until(lambda: messages.read_fields(probe.observations[-1])['step'][0] == env.step_index)

    for _ in range(3):
        step_and_see()
    stop.publish(Bool(data=True))
    assert harness.spin_until(lambda: env.stopped)
    frozen, state = env.steps_taken, env.env.unwrapped.state.copy()
    for _ in range(5):
        act()
        harness.spin_until(lambda: False, timeout=0.1)
    assert env.steps_taken == frozen and env.stopped_actions >= 5
    assert np.array_equal(env.env.unwrapped.state, state)  # the robot held
    stop.publish(Bool(data=False))
    assert harness.spin_until(lambda: not env.stopped)
    step_and_see()  # the same episode, one step on
    assert env.steps_taken == frozen + 1 and env.step_index == 4


def test_a_stopped_real_time_env_holds_until_released(harness, ros_context):
    env = harness.add(
        GymEnvNode(
            context=ros_context, parameter_overrides=params(realtime=True, rate_hz=50.0, max_episode_steps=10**6)
        )
    )
    Probe(harness)  # a subscriber: the real-time clock starts
    stop = stopper(harness)
    assert harness.spin_until(lambda: env.steps_taken > 10, timeout=10)
    stop.publish(Bool(data=True))
    assert harness.spin_until(lambda: env.stopped)
    frozen = env.steps_taken
    harness.spin_until(lambda: False, timeout=0.5)
    assert env.steps_taken == frozen
    stop.publish(Bool(data=False))
    assert harness.spin_until(lambda: env.steps_taken > frozen + 5, timeout=10)


def test_a_late_env_starts_stopped_the_stop_is_latched(harness, ros_context):
    stop = stopper(harness)
    stop.publish(Bool(data=True))
    env = harness.add(GymEnvNode(context=ros_context, parameter_overrides=params()))
    assert harness.spin_until(lambda: env.stopped, timeout=10)


def test_max_action_change_limits_each_step(harness, ros_context):
    env = harness.add(
        GymEnvNode(context=ros_context, parameter_overrides=params(max_episode_steps=50, max_action_change=0.5))
    )
    probe = Probe(harness)
    assert harness.spin_until(lambda: probe.action_pub.get_subscription_count() > 0 and probe.observations)
    applied = []
    for value in (2.0, 2.0, -2.0, -2.0):
        assert harness.spin_until(lambda: messages.read_fields(probe.observations[-1])['step'][0] == env.step_index)
        fields = messages.read_fields(probe.observations[-1])
        before = env.steps_taken
        probe.action_pub.publish(messages.action_msg([value], int(fields['episode'][0]), int(fields['step'][0])))
        assert harness.spin_until(lambda: env.steps_taken == before + 1)
        applied.append(float(env._previous_action[0]))
    assert applied == pytest.approx([0.5, 1.0, 0.5, 0.0])


def test_the_double_integrator_holds_while_stopped(harness, ros_context):
    env = harness.add(DoubleIntegratorEnv(context=ros_context, parameter_overrides=params(realtime=True, rate_hz=50.0)))
    Probe(harness)
    stop = stopper(harness)
    assert harness.spin_until(lambda: env.step_index > 5 or env.episode > 0, timeout=10)
    stop.publish(Bool(data=True))
    assert harness.spin_until(lambda: env.stopped)
    held = (env.episode, env.step_index, env.system.x, env.system.v)
    harness.spin_until(lambda: False, timeout=0.4)
    assert (env.episode, env.step_index, env.system.x, env.system.v) == held
    stop.publish(Bool(data=False))
    assert harness.spin_until(lambda: (env.episode, env.step_index) != held[:2], timeout=10)


def test_one_stop_reaches_an_env_in_an_actors_namespace(harness, ros_context):
    env = harness.add(GymEnvNode(context=ros_context, namespace='/actor3', parameter_overrides=params()))
    stop = stopper(harness)  # in the root namespace, as the console is
    stop.publish(Bool(data=True))
    assert harness.spin_until(lambda: env.stopped, timeout=10)


def test_a_stop_pauses_the_learners_episode_and_its_record_says_how_long(harness, ros_context, tmp_path):
    """The learner does not take a stop for a stall: the same episode goes on once released, and its
    row in episodes.csv (and EpisodeStats) counts the stop and the seconds it held."""
    import csv

    from eqhrl_ros.nodes.learner_node import LearnerNode

    from ros_helpers import small_learner_params

    env = harness.add(GymEnvNode(context=ros_context, parameter_overrides=params(max_episode_steps=60)))
    learner = harness.add(
        LearnerNode(
            context=ros_context,
            parameter_overrides=small_learner_params(
                tmp_path, mode='sac', max_episodes=2, stall_timeout_s=0.3, learning_starts=10**6
            ),
        )
    )
    stop = stopper(harness)
    assert harness.spin_until(lambda: env.steps_taken >= 20, timeout=20)
    stop.publish(Bool(data=True))
    assert harness.spin_until(lambda: env.stopped and learner.tracking.stopped_since is not None)
    harness.spin_until(lambda: False, timeout=1.0)  # past stall_timeout_s: still no stall
    assert learner.stalls == 0 and learner.learner.episode == 0
    stop.publish(Bool(data=False))
    assert harness.spin_until(lambda: len(learner.summaries) >= 1, timeout=20)
    first = learner.summaries[0]
    assert first.episode == 0 and first.length == 60 and not first.interrupted
    assert first.stops == 1 and 1.0 <= first.stopped_s < 5.0
    assert harness.spin_until(lambda: len(learner.summaries) >= 2, timeout=20)
    assert learner.summaries[1].stops == 0 and learner.summaries[1].stopped_s == 0.0
    with (tmp_path / 'episodes.csv').open(newline='') as f:
        rows = list(csv.DictReader(f))
    assert rows[0]['stops'] == '1' and float(rows[0]['stopped_s']) >= 1.0


@pytest.mark.parametrize('env_node', ['gym_env', 'double_integrator_env'])
def test_a_strangers_release_beside_the_persons_stop_moves_nothing(harness, ros_context, env_node):
    """Before, any node's false on /stop released the person's STOP: a stranger beside the page set
    the robot going. A stop from anyone still holds at once; a release is taken only while one node
    alone publishes /stop."""
    node_class = GymEnvNode if env_node == 'gym_env' else DoubleIntegratorEnv
    env = harness.add(node_class(context=ros_context, namespace='/held'))
    stop = stopper(harness)
    stranger = harness.add(rclpy.create_node('stranger', context=ros_context))
    stop.publish(Bool(data=True))
    assert harness.spin_until(lambda: env.stopped)
    release = stranger.create_publisher(Bool, messages.STOP_TOPIC, messages.STOP_QOS)
    assert harness.spin_until(lambda: len(env.get_publishers_info_by_topic('/stop')) == 2, timeout=10)
    harness.spin_until(lambda: False, timeout=0.6)  # past the graph cache
    release.publish(Bool(data=False))
    harness.spin_until(lambda: False, timeout=1.0)
    assert env.stopped
    harness.nodes.remove(stranger)
    stranger.destroy_node()
    assert harness.spin_until(lambda: len(env.get_publishers_info_by_topic('/stop')) == 1, timeout=10)
    harness.spin_until(lambda: False, timeout=0.6)
    stop.publish(Bool(data=False))  # the person's own release, alone on /stop
    assert harness.spin_until(lambda: not env.stopped)
