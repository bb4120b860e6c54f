"""policy_driver: a trained policy drives the env, learning and asking nothing (nodes/policy_driver_node.py)."""

from types import SimpleNamespace

import numpy as np
import pytest
from rclpy.node import Node
from std_msgs.msg import Float32MultiArray

from eqhrl_ros.core import EQSACLearner, LearnerConfig
from eqhrl_ros.core.experts.policy import PolicyExpert, export_policy
from eqhrl_ros.nodes import messages
from eqhrl_ros.nodes.gym_env_node import GymEnvNode
from eqhrl_ros.nodes.policy_driver_node import PolicyDriverNode

from ros_helpers import params


def exported(path, obs_dim=3, low=(-2.0,), high=(2.0,)):
    learner = EQSACLearner(obs_dim, list(low), list(high), LearnerConfig(hidden=(16, 16), seed=3))
    export_policy(learner, path)
    return path


def test_the_policy_drives_each_step_with_its_deterministic_action_and_stops_after_max_episodes(
    harness, ros_context, tmp_path
):
    policy = exported(tmp_path / 'policy.pt')
    seen = {'observation': {}, 'action': {}}
    listener = harness.add(Node('listener', context=ros_context))

    def keep(topic):
        def on(msg):
            values = np.array(msg.data, dtype=np.float32)
            if topic == 'observation':
                step = messages.parse_observation(msg, 3)
                seen[topic][(step.episode, step.step)] = (step.obs, step.done)
            else:
                seen[topic][(int(values[-2]), int(values[-1]))] = values[:-2]

        return on

    for topic in seen:
        listener.create_subscription(Float32MultiArray, topic, keep(topic), 100)
    harness.add(GymEnvNode(context=ros_context, parameter_overrides=params(max_episode_steps=20)))
    driver = harness.add(
        PolicyDriverNode(context=ros_context, parameter_overrides=params(policy_path=str(policy), max_episodes=2))
    )
    assert harness.spin_until(lambda: driver.done, timeout=60)
    assert len(driver.returns) == 2 and all(np.isfinite(driver.returns))
    expert = PolicyExpert(policy)
    acted = [key for key, (_, done) in seen['observation'].items() if not done and key in seen['action']]
    assert len(acted) >= 30  # two episodes of 20 steps, the listener heard most
    for key in acted:
        obs, _ = seen['observation'][key]
        assert np.allclose(seen['action'][key], expert.action(obs), atol=1e-5), key
    assert not any(done and key in seen['action'] for key, (_, done) in seen['observation'].items())


def test_an_observation_sent_again_gets_the_same_action_and_a_final_one_none(ros_context, tmp_path):
    driver = PolicyDriverNode(
        context=ros_context,
        parameter_overrides=params(policy_path=str(exported(tmp_path / 'p.pt')), env_id='Pendulum-v1'),
    )
    sent = []
    driver.action_pub.publish = sent.append
    obs = np.array([0.1, 0.2, 0.3], dtype=np.float32)
    driver.observation_source.admits = lambda logger, what: True  # one env, as the graph would say
    for msg in [messages.observation_msg(obs, 0.0, False, False, 0, 0)] * 2:
        driver._on_observation(msg)
    assert len(sent) == 2 and sent[0].data.tolist() == sent[1].data.tolist()
    final = messages.observation_msg(obs, -1.5, True, False, 0, 1)
    driver._on_observation(final)
    driver._on_observation(final)  # before: the re-sent final observation raised inside the callback
    assert len(sent) == 2 and driver.returns == [-1.5]
    assert driver.successes == 0  # Pendulum's rule: upright for the last steps; one step is not that
    driver._on_observation(messages.observation_msg(obs, 0.0, False, False, 1, 0))
    driver._on_observation(messages.observation_msg(obs, -0.5, True, False, 1, 1, success=True))
    assert driver.returns == [-1.5, -0.5] and driver.successes == 1  # the env's own verdict
    lines = []
    driver.get_logger = lambda: SimpleNamespace(info=lines.append)
    driver.destroy_node()  # as at Ctrl-C: before, it ended without a word on what it drove
    assert lines == ['drove 2 episodes: mean return -1.00 (min -1.50, max -0.50), success 50%']


def test_a_policy_of_other_spaces_or_none_is_refused_in_one_line(harness, ros_context, tmp_path):
    with pytest.raises(ValueError, match='policy_path is required'):
        PolicyDriverNode(context=ros_context)
    other = exported(tmp_path / 'other.pt', obs_dim=2, low=(-1.0,), high=(1.0,))
    with pytest.raises(ValueError, match=r"does not fit env 'Pendulum-v1': observation size 2, not 3"):
        PolicyDriverNode(context=ros_context, parameter_overrides=params(policy_path=str(other), env_id='Pendulum-v1'))
    (tmp_path / 'broken.pt').write_bytes(b'not a policy')
    with pytest.raises(Exception, match='broken.pt'):
        PolicyDriverNode(context=ros_context, parameter_overrides=params(policy_path=str(tmp_path / 'broken.pt')))
    # From the env's env_info: the node stops with the same line and exit code 1.
    harness.add(GymEnvNode(context=ros_context, parameter_overrides=params(max_episode_steps=20)))
    driver = harness.add(PolicyDriverNode(context=ros_context, parameter_overrides=params(policy_path=str(other))))
    assert harness.spin_until(lambda: getattr(driver, 'exit_error', None), timeout=30)
    assert 'does not fit env' in driver.exit_error and 'observation size 2, not 3' in driver.exit_error
