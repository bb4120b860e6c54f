"""/diagnostics (nodes/health.py): each node's checks, and each change of level to WARN and back."""

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from std_msgs.msg import Bool

from eqhrl_ros.nodes import messages
from eqhrl_ros.nodes.actor_node import ActorNode
from eqhrl_ros.nodes.expert_node import ExpertNode
from eqhrl_ros.nodes.gym_env_node import GymEnvNode
from eqhrl_ros.nodes.health import OK, WARN
from eqhrl_ros.nodes.learner_node import LearnerNode
from eqhrl_ros.nodes.trainer_node import TrainerNode

from ros_helpers import params, small_learner_params


def test_the_learner_says_when_no_expert_serves_and_when_one_does(harness, ros_context, tmp_path):
    heard = []
    listener = harness.add(rclpy.create_node('monitor', context=ros_context))
    listener.create_subscription(DiagnosticArray, '/diagnostics', heard.append, 50)
    learner = harness.add(
        LearnerNode(context=ros_context, parameter_overrides=small_learner_params(tmp_path, advising_budget=100))
    )
    assert harness.spin_until(lambda: learner.health.level('expert') == WARN, timeout=10)
    expert = harness.add(ExpertNode(context=ros_context, parameter_overrides=params(env_id='Pendulum-v1')))
    assert harness.spin_until(lambda: learner.health.level('expert') == OK, timeout=10)
    # A second node serving advise: no answer can be told from its (test_faults.py), so WARN, and OK once it leaves.
    second = ExpertNode(
        context=ros_context,
        parameter_overrides=params(env_id='Pendulum-v1'),
        cli_args=['--ros-args', '-r', '__node:=second'],
    )
    harness.executor.add_node(second)
    assert harness.spin_until(lambda: learner.health.level('expert') == WARN, timeout=10)
    harness.executor.remove_node(second)
    second.destroy_node()
    assert harness.spin_until(lambda: learner.health.level('expert') == OK, timeout=10)

    def statuses():
        return [s for msg in heard for s in msg.status if s.name == '/learner: expert']

    assert harness.spin_until(lambda: {s.level for s in statuses()} >= {DiagnosticStatus.WARN, DiagnosticStatus.OK})
    statuses = statuses()
    assert any(kv.key == 'advise servers' for kv in statuses[-1].values) and expert is not None
    said = "2 nodes serve 'advise': no answer is taken until one does"
    assert any(s.level == DiagnosticStatus.WARN and s.message == said for s in statuses), [s.message for s in statuses]


def test_the_learner_warns_when_most_answers_are_not_its_to_take(harness, ros_context, tmp_path):
    """A key_file on the learner and none on its expert: every answer is unsigned, so none is taken.
    The expert serves, so the check said OK; now it warns."""
    from eqhrl_ros.core.data.signing import new_key_file

    key = str(new_key_file(tmp_path / 'deployment.key'))
    harness.add(GymEnvNode(context=ros_context, parameter_overrides=params(max_episode_steps=10**6)))
    harness.add(ExpertNode(context=ros_context, parameter_overrides=params(env_id='Pendulum-v1')))
    overrides = small_learner_params(
        tmp_path, mode='random', random_ask_rate=0.5, advising_budget=100, learning_starts=10**6, key_file=key
    )
    learner = harness.add(LearnerNode(context=ros_context, parameter_overrides=overrides))
    assert harness.spin_until(lambda: learner.health.level('expert') == WARN, timeout=20)
    check = next(c for c in learner.health.last if c.name == 'expert')
    assert check.message.endswith(
        'answers were not taken (untrusted: not signed with key_file, or not from accept_expert)'
    )
    assert check.values['untrusted'] >= 10 and check.values['given'] == 0


def test_the_learner_warns_of_a_stalled_env_and_clears_when_it_steps_again(harness, ros_context, tmp_path):
    env = harness.add(GymEnvNode(context=ros_context, parameter_overrides=params(max_episode_steps=10**6)))
    learner = harness.add(
        LearnerNode(
            context=ros_context,
            parameter_overrides=small_learner_params(
                tmp_path, advising_budget=0, stall_timeout_s=0.3, learning_starts=10**6
            ),
        )
    )
    stop = harness.add(rclpy.create_node('person', context=ros_context)).create_publisher(
        Bool, messages.STOP_TOPIC, messages.STOP_QOS
    )
    assert harness.spin_until(lambda: learner.learner is not None and learner.learner.total_steps > 5, timeout=20)
    assert harness.spin_until(lambda: learner.health.level('env') == OK and env.health.level('stop') == OK)
    stop.publish(Bool(data=True))  # the env holds: the learner sees no observation
    assert harness.spin_until(lambda: learner.health.level('env') == WARN and env.health.level('stop') == WARN, 10)
    stop.publish(Bool(data=False))
    assert harness.spin_until(lambda: learner.health.level('env') == OK and env.health.level('stop') == OK, 10)


def test_the_trainer_warns_of_a_silent_actor_and_the_actor_of_a_missing_trainer(harness, ros_context, tmp_path):
    algorithm = dict(env_id='Pendulum-v1', hidden_sizes=[16, 16], batch_size=16, learning_starts=60, advising_budget=0)
    env = harness.add(
        GymEnvNode(context=ros_context, namespace='/a0', parameter_overrides=params(max_episode_steps=20))
    )
    actor = harness.add(
        ActorNode(context=ros_context, namespace='/a0', parameter_overrides=params(**algorithm, flush_period_s=0.1))
    )
    assert harness.spin_until(lambda: actor.health.level('trainer') == WARN, timeout=10)  # no trainer yet
    trainer = harness.add(
        TrainerNode(
            context=ros_context,
            parameter_overrides=params(
                **algorithm,
                output_dir=str(tmp_path / 't'),
                actor_silence_s=1.0,
                checkpoint_every_episodes=0,
                actors=['/a0/actor'],
            ),
        )
    )
    assert harness.spin_until(lambda: trainer.health.level('actors') == OK and actor.health.level('trainer') == OK, 30)
    harness.executor.remove_node(env)  # the actor's env stops: the actor sends nothing more
    assert harness.spin_until(lambda: trainer.health.level('actors') == WARN, timeout=10)
    harness.executor.add_node(env)
    assert harness.spin_until(lambda: trainer.health.level('actors') == OK, timeout=10)
