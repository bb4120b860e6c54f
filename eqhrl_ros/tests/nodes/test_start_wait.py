"""The learner's first observation waits for an expert to serve 'advise' (nodes/start_wait.py),
and the expert node serves it only once it knows the env.

Nodes started together find each other over seconds; a lock-step env runs as fast as the learner
acts, so without the wait the advising budget's first episodes went by with every request failed
as unavailable (a CI run of test_any_env_processes once lost all 10 so)."""

import time

import pytest
import rclpy
from std_msgs.msg import Float32MultiArray

from eqhrl_interfaces.msg import EnvInfo
from eqhrl_ros.core.envs.spec import EnvSpec
from eqhrl_ros.nodes import env_info, messages
from eqhrl_ros.nodes.expert_node import ExpertNode
from eqhrl_ros.nodes.learner_node import LearnerNode

from ros_helpers import StubExpert, small_learner_params

# Every step asks (mode random at rate 1), one answer per request, no updates.
ASKING = dict(mode='random', random_ask_rate=1.0, advice_protocol='answer', learning_starts=10**6)


def first_observation(harness):
    """Publish the env's first observation once (a lock-step env then waits for the action);
    returns the probe node's action list and the time it was sent."""
    node = harness.add(rclpy.create_node('env_probe', context=harness.context))
    actions = []
    node.create_subscription(Float32MultiArray, 'action', actions.append, 10)
    publisher = node.create_publisher(Float32MultiArray, 'observation', 10)
    assert harness.spin_until(lambda: publisher.get_subscription_count() > 0)
    publisher.publish(messages.observation_msg([1.0, 0.0, 0.0], 0.0, False, False, 0, 0))
    return actions, time.monotonic()


def test_the_first_observation_waits_for_an_expert_and_the_first_request_goes_to_it(harness, ros_context, tmp_path):
    learner = harness.add(
        LearnerNode(
            context=ros_context, parameter_overrides=small_learner_params(tmp_path, expert_wait_s=10.0, **ASKING)
        )
    )
    actions, _ = first_observation(harness)
    harness.spin_until(lambda: bool(actions), timeout=1.0)
    assert actions == [] and learner.learner.total_steps == 0  # held: no expert yet
    expert = StubExpert(ros_context)
    try:
        came = time.monotonic()
        assert harness.spin_until(lambda: bool(actions), timeout=8.0)
        assert time.monotonic() - came < 5.0  # on the expert's coming, not at the end of the wait
        assert expert.requests[:1] and expert.requests[0][:2] == (0, 0)  # step 0's request was answered
        advice = learner.learner.episode_advice
        assert advice.given == 1 and sum(advice.failed.values()) == 0
    finally:
        expert.close()


def test_the_wait_ends_saying_when_two_nodes_serve_advise():
    """The wait ended with "an expert serves 'advise'" also when two did, and no answer is taken
    then (test_faults.py). (Nodes come one by one, so this is said where both appeared together.)"""
    from types import SimpleNamespace

    from eqhrl_ros.nodes.start_wait import StartWait

    said = []
    logger = SimpleNamespace(
        warning=lambda line: said.append(('warn', line)), info=lambda line: said.append(('info', line))
    )
    advice = SimpleNamespace(ready=lambda: True, serving=lambda: ['/expert', '/stranger'])
    wait = StartWait(
        SimpleNamespace(get_logger=lambda: logger), lambda: 'answer', None, advice, lambda: 10.0, None, None, None
    )
    wait._since = time.monotonic() - 1.5
    wait._say_end()
    assert len(said) == 1 and said[0][0] == 'warn', said
    assert said[0][1].startswith("2 nodes serve 'advise' (/expert, /stranger) (1.5 s): acting, and taking no answer")
    advice.serving = list  # one serves
    wait._say_end()
    assert said[1][0] == 'info' and said[1][1].startswith("an expert serves 'advise' (1.5 s)")


@pytest.mark.parametrize(
    'extra,waits',
    [
        (dict(expert_wait_s=2.0), True),  # no expert comes: acts alone once the wait runs out
        (dict(expert_wait_s=0.0), False),  # 0: at once
        (dict(expert_wait_s=10.0, advising_budget=0), False),  # advice closed: nothing to wait for
        (dict(expert_wait_s=10.0, advice_enabled=False), False),
    ],
)
def test_with_no_expert_the_wait_ends_at_expert_wait_s_or_is_not_made(harness, ros_context, tmp_path, extra, waits):
    learner = harness.add(
        LearnerNode(context=ros_context, parameter_overrides=small_learner_params(tmp_path, **{**ASKING, **extra}))
    )
    actions, sent = first_observation(harness)
    assert harness.spin_until(lambda: bool(actions), timeout=8.0)
    waited = time.monotonic() - sent
    assert (waited >= 1.9) == waits, waited  # the first action's own work takes well under that
    harness.spin_until(lambda: len(actions) > 1, timeout=0.3)
    assert len(actions) == 1  # step 0 acted on once (a lock-step env would now step)
    asked = extra.get('advising_budget', 1) and extra.get('advice_enabled', True)
    # The gate fired; with advice open, nobody served it: unavailable.
    assert learner.learner.episode_advice.failed['unavailable'] == (1 if asked else 0)


def test_the_expert_serves_advise_only_once_it_knows_the_env(harness, ros_context):
    """A heuristic expert with no env_id declined every request until env_info came; a learner
    waiting for a server would have stopped waiting for a node bound to decline."""
    expert = harness.add(ExpertNode(context=ros_context))
    env = harness.add(rclpy.create_node('double_integrator_env', context=ros_context))
    harness.spin_until(lambda: False, timeout=0.5)
    assert expert.count_services('/advise') == 0 and expert.service is None
    env.create_publisher(Float32MultiArray, 'observation', 10)  # an env publishes its observations
    publisher = env.create_publisher(EnvInfo, 'env_info', env_info.ENV_INFO_QOS)
    publisher.publish(env_info.env_info_msg(EnvSpec('double_integrator', 2, [-1.0], [1.0])))
    assert harness.spin_until(lambda: expert.count_services('/advise') == 1, timeout=10)
