"""A person in the loop through ROS, played by the simulated person: teleop_expert's answer
window (answered, skipped and timed-out requests, reaction times) and the expert node's
simulated_human backend."""

import time

import numpy as np
import pytest
import rclpy
from std_msgs.msg import Float32MultiArray

from eqhrl_interfaces.msg import AdviceRequest as AdviceRequestMsg
from eqhrl_ros.core.data.advice import ACTION_SOURCES, AdviceRequest
from eqhrl_ros.core.experts.factory import make_expert
from eqhrl_ros.core.experts.simulated_human import HumanLimits, SimulatedHuman
from eqhrl_ros.nodes import messages
from eqhrl_ros.nodes.expert_node import ExpertNode
from eqhrl_ros.nodes.gym_env_node import GymEnvNode
from eqhrl_ros.nodes.learner_node import LearnerNode
from eqhrl_ros.nodes.spinning import steady_clock
from eqhrl_ros.nodes.teleop_expert_node import TeleopExpertNode

from ros_helpers import applied_actions, asking_learner_params, params, small_learner_params

PENDULUM_LOW, PENDULUM_HIGH = np.array([-2.0], np.float32), np.array([2.0], np.float32)


class PersonAtAConsole:
    """A simulated person in front of a UI (keyboard_teleop, advice_console): sees each request on
    learner/advice_request and, after their reaction time, publishes on teleop_command what the
    UI sends for a key press: the command with the answer button pressed, or the skip button.
    A missed request gets nothing."""

    def __init__(self, harness, human: SimulatedHuman, scale: float):
        self.node = harness.add(rclpy.create_node('keyboard_teleop', context=harness.context))  # the UI it stands for
        self.human, self.scale = human, scale
        self.plans = []  # one per request, in order
        self.seen = set()
        self.publisher = self.node.create_publisher(Float32MultiArray, 'teleop_command', 10)
        self.node.create_subscription(
            AdviceRequestMsg, 'learner/advice_request', self._on_request, messages.LATCHED_QOS
        )
        self.clock = steady_clock()

    def _on_request(self, msg):
        key = (msg.episode, msg.step)
        if msg.outcome != AdviceRequestMsg.PENDING or key in self.seen:
            return
        self.seen.add(key)
        request = AdviceRequest(
            np.asarray(msg.observation, np.float32), np.asarray(msg.proposed_action, np.float32),
            PENDULUM_LOW, PENDULUM_HIGH, msg.discrepancy, msg.entropy, msg.episode, msg.step,
        )  # fmt: skip
        plan = self.human.plan(request)
        self.plans.append(plan)
        if plan.kind == 'miss':
            return
        timer = None

        def act():
            self.node.destroy_timer(timer)
            command = [0.0] if plan.action is None else (plan.action / self.scale).tolist()
            answer, skip = plan.kind == 'answer', plan.kind == 'skip'
            self.publisher.publish(messages.command_msg(command, True, answer, skip))  # press
            self.publisher.publish(messages.command_msg(command, True, False, False))  # release

        timer = self.node.create_timer(plan.delay_s, act, clock=self.clock)


@pytest.mark.alone  # reaction times to 80 ms
def test_teleop_expert_holds_each_request_for_the_person_and_counts_what_they_did(harness, ros_context, tmp_path):
    window = 1.0
    teleop = harness.add(
        TeleopExpertNode(
            context=ros_context,
            parameter_overrides=params(
                source='array', axes=[0], scales=[2.0], offsets=[0.0], answer_window_s=window, answer_mode='window'
            ),
        )
    )
    limits = HumanLimits(reaction_median_s=0.25, reaction_sigma=0.3, skip_probability=0.25, miss_probability=0.25)
    person = PersonAtAConsole(harness, SimulatedHuman(make_expert('heuristic', 'Pendulum-v1'), limits, seed=1), 2.0)
    assert harness.spin_until(lambda: person.publisher.get_subscription_count() > 0)
    env = harness.add(GymEnvNode(context=ros_context, parameter_overrides=params(max_episode_steps=25)))
    learner = harness.add(
        LearnerNode(
            context=ros_context,
            parameter_overrides=small_learner_params(tmp_path, mode='qasac', max_episodes=2, advice_timeout_s=1.5),
        )
    )
    assert harness.spin_until(lambda: learner.done, timeout=90)

    kinds = [p.kind for p in person.plans]
    assert {'answer', 'skip', 'miss'} <= set(kinds), kinds  # the seed gives every kind
    assert max(p.delay_s for p in person.plans if p.kind != 'miss') < window - 0.2  # none borderline
    assert teleop.answers == {
        'answered': kinds.count('answer'),
        'skipped': kinds.count('skip'),
        'timed_out': kinds.count('miss'),
        'declined': 0,
    }
    totals = learner.learner.advice_total
    assert totals.asked == len(kinds)
    assert totals.given == totals.human == kinds.count('answer')
    assert totals.declined == kinds.count('skip') and totals.failed['timeout'] == kinds.count('miss')
    # Reaction times as teleop_expert measured them: the simulated delays, give or take transport.
    delays = [p.delay_s for p in person.plans if p.kind != 'miss']
    assert teleop.reaction_times == pytest.approx(delays, abs=0.08)
    person_time = sum(delays) + window * kinds.count('miss')
    assert totals.human_time_s == pytest.approx(person_time, abs=0.08 * len(kinds))
    assert learner.summaries[-1].human_time_total_s == pytest.approx(totals.human_time_s, rel=1e-4)
    # The lock-step env waited: every episode whole.
    assert [s.length for s in learner.summaries] == [25, 25] and not any(s.interrupted for s in learner.summaries)
    assert env.params['realtime'] is False


def test_the_expert_node_plays_a_person_with_the_simulated_human_backend(harness, ros_context, tmp_path):
    expert = harness.add(
        ExpertNode(
            context=ros_context,
            parameter_overrides=params(
                backend='simulated_human',
                env_id='Pendulum-v1',
                reaction_median_s=0.2,
                reaction_sigma=0.2,
                miss_probability=0.3,
                skip_probability=0.0,
                answer_window_s=0.6,
                seed=4,
            ),
        )
    )
    harness.add(GymEnvNode(context=ros_context, parameter_overrides=params(max_episode_steps=25)))
    learner = harness.add(
        LearnerNode(
            context=ros_context,
            parameter_overrides=small_learner_params(tmp_path, mode='qasac', max_episodes=2, advice_timeout_s=1.0),
        )
    )
    assert harness.spin_until(lambda: learner.done, timeout=90)
    totals = learner.learner.advice_total
    assert expert.requests == totals.asked > 0
    assert totals.given == totals.human > 0 and totals.failed['timeout'] > 0
    assert totals.given + totals.failed['timeout'] == totals.asked
    # The person's time was waited out for real: each answer came after its reaction time.
    assert min(learner.advice.latencies) > 0.05
    assert totals.human_time_s == pytest.approx(sum(learner.advice.latencies), abs=0.05 * totals.asked)


def test_a_request_the_episode_ends_is_ended_at_once_everywhere_and_not_counted_as_a_timeout(
    harness, ros_context, tmp_path
):
    """Real time, episodes of 6 steps at 30 Hz (0.2 s), a person who never answers within them:
    before, each such request was counted as the person's timeout with 0 s, while teleop_expert
    held it open (a later key press landed on it). Now it is counted as episode_ended, said at
    once on learner/advice_request, and teleop_expert ends it too."""
    teleop = harness.add(
        TeleopExpertNode(
            context=ros_context,
            parameter_overrides=params(source='array', axes=[0], scales=[2.0], offsets=[0.0], answer_window_s=2.5),
        )
    )
    seen = []
    watcher = harness.add(rclpy.create_node('watcher', context=ros_context))
    watcher.create_subscription(AdviceRequestMsg, 'learner/advice_request', seen.append, 50)
    harness.add(
        GymEnvNode(context=ros_context, parameter_overrides=params(realtime=True, rate_hz=30.0, max_episode_steps=6))
    )
    learner = harness.add(
        LearnerNode(
            context=ros_context,
            parameter_overrides=small_learner_params(
                tmp_path,
                mode='qasac',
                queue_length=1,
                advising_budget=100,
                max_episodes=6,
                advice_timeout_s=3.0,
                advice_protocol='answer',  # the paper's one answer, in a real-time env (the wheel has its own test)
            ),
        )
    )
    assert harness.spin_until(lambda: learner.done, timeout=90)
    totals = learner.learner.advice_total
    assert totals.failed['episode_ended'] >= 1 and totals.failed['timeout'] == 0
    assert teleop.ended_by_learner >= 1 and teleop.answers['timed_out'] == 0

    def ended():
        return [m for m in seen if m.outcome == AdviceRequestMsg.FAILED and m.detail == 'episode_ended']

    assert harness.spin_until(lambda: len(ended()) == totals.failed['episode_ended'], timeout=5), len(ended())
    assert totals.human_time_s == 0.0  # the person was not given the time: none is counted as theirs


def test_the_persons_budget_in_seconds_is_set_at_run_time_and_kept_by_checkpoints(harness, ros_context, tmp_path):
    from rclpy.parameter import Parameter

    from eqhrl_ros.core.runs.checkpoint import load_checkpoint, save_checkpoint

    learner = harness.add(LearnerNode(context=ros_context, parameter_overrides=small_learner_params(tmp_path)))
    assert harness.spin_until(lambda: learner.learner is not None)
    assert learner.set_parameters([Parameter('advising_budget_s', value=45.0)])[0].successful
    assert learner.learner.config.advising_budget_s == 45.0
    assert not learner.set_parameters([Parameter('advising_budget_s', value=-1.0)])[0].successful
    save_checkpoint(learner.learner, tmp_path / 'ckpt.pt')
    from eqhrl_ros.core import EQSACLearner, LearnerConfig

    fresh = EQSACLearner(3, [-2.0], [2.0], LearnerConfig(hidden=(16, 16)))
    load_checkpoint(fresh, tmp_path / 'ckpt.pt')
    assert fresh.config.advising_budget_s == 45.0


def test_a_resumed_run_keeps_the_budgets_set_while_it_ran(harness, ros_context, tmp_path):
    """Before: --resume went back to the params file's budget (20), losing the 35 set on the page."""
    from rclpy.parameter import Parameter

    first = LearnerNode(context=ros_context, parameter_overrides=small_learner_params(tmp_path, advising_budget=20))
    harness.add(first)
    assert harness.spin_until(lambda: first.learner is not None)
    first.set_parameters([Parameter('advising_budget', value=35), Parameter('advising_budget_s', value=90.0)])
    first.save()
    harness.nodes.remove(first)
    harness.executor.remove_node(first)
    first.close()
    first.destroy_node()
    again = LearnerNode(
        context=ros_context, parameter_overrides=small_learner_params(tmp_path, advising_budget=20, resume=True)
    )
    harness.add(again)
    assert harness.spin_until(lambda: again.learner is not None)
    assert again.learner.config.advising_budget == 35 and again.learner.gates.advising_budget == 35
    assert again.get_parameter('advising_budget').value == 35
    assert again.get_parameter('advising_budget_s').value == 90.0


def test_the_person_takes_over_unasked_and_hands_back_by_releasing_the_deadman(harness, ros_context, tmp_path):
    """A lock-step env, a learner that never asks (budget 0), and a person's command on
    person_command as teleop_expert passes it on: with the deadman held and far from the
    learner's action, the env gets the person's action every step, counted as takeover; released,
    the learner acts again at the next step."""
    env = harness.add(GymEnvNode(context=ros_context, parameter_overrides=params(max_episode_steps=10**6)))
    learner = harness.add(  # no updates: the first one (the compiler's import) would stall a second
        LearnerNode(
            context=ros_context,
            parameter_overrides=small_learner_params(
                tmp_path, advising_budget=0, learning_starts=10**6, takeover_threshold=0.25
            ),
        )
    )
    person = harness.add(
        rclpy.create_node('teleop_expert', context=ros_context)
    )  # whom the learner takes commands from
    pub = person.create_publisher(Float32MultiArray, messages.PERSON_COMMAND_TOPIC, 10)
    applied = applied_actions(env)
    assert harness.spin_until(lambda: learner.learner is not None and env.steps_taken > 5, timeout=20)
    hold = person.create_timer(0.02, lambda: pub.publish(messages.person_command_msg([-2.0], True, False)))
    assert harness.spin_until(lambda: learner.learner.episode_advice.takeover_steps >= 20, timeout=20)
    taken = learner.learner.episode_advice
    assert taken.takeovers == 1 and taken.asked == 0
    start = len(applied)
    harness.spin_until(lambda: len(applied) > start + 10, timeout=10)
    assert applied[-10:] == [-2.0] * 10  # the person's action, step after step
    person.destroy_timer(hold)
    release = person.create_timer(0.02, lambda: pub.publish(messages.person_command_msg([-2.0], False, False)))
    assert harness.spin_until(lambda: learner.wheel.person is not None and not learner.wheel.person.deadman, timeout=10)
    steps, start = taken.takeover_steps, len(applied)  # the release has arrived
    assert harness.spin_until(lambda: len(applied) > start + 40, timeout=10)
    assert learner.learner.episode_advice.takeover_steps <= steps + 1  # the learner's again within one step
    assert -2.0 not in applied[-30:]
    person.destroy_timer(release)


def test_in_real_time_a_request_asks_for_the_wheel_and_the_robot_follows_the_person(harness, ros_context, tmp_path):
    """advice_protocol auto in a real-time env is the wheel. The learner alerts and drives on with
    its own policy; a deadman held from before the alert never takes it (that request times out);
    a press after the alert takes it: from the next step on the env gets the person's action, each
    step counted as asked and stored in D_advising; the release hands back within one step, and the
    person's seconds run from the alert to the hand-back."""
    env = harness.add(
        GymEnvNode(
            context=ros_context, parameter_overrides=params(realtime=True, rate_hz=40.0, max_episode_steps=10**6)
        )
    )
    learner = harness.add(
        LearnerNode(
            context=ros_context,
            parameter_overrides=asking_learner_params(
                tmp_path,
                wheel_take_s=1.0,
                wheel_agree_steps=0,
                wheel_max_s=0.0,
                record=True,
            ),
        )
    )
    person = harness.add(
        rclpy.create_node('teleop_expert', context=ros_context)
    )  # whom the learner takes commands from
    pub = person.create_publisher(Float32MultiArray, messages.PERSON_COMMAND_TOPIC, 10)
    requests = []
    person.create_subscription(AdviceRequestMsg, 'learner/advice_request', requests.append, messages.LATCHED_QOS)
    applied = applied_actions(env)
    held = {'deadman': True}  # held from the start: before any request
    person.create_timer(0.02, lambda: pub.publish(messages.person_command_msg([-2.0], held['deadman'], False)))
    assert harness.spin_until(lambda: any(r.outcome == AdviceRequestMsg.FAILED for r in requests), timeout=30)
    first = [r for r in requests if r.outcome != AdviceRequestMsg.PENDING][0]
    assert first.wheel and first.outcome == AdviceRequestMsg.FAILED and first.detail == 'timeout'
    assert learner.protocol == 'wheel' and learner.learner.episode_advice.asked_steps == 0
    assert -2.0 not in applied  # never the person's: their press came before the request

    held['deadman'] = False
    assert harness.spin_until(
        lambda: requests and requests[-1].outcome == AdviceRequestMsg.PENDING and learner.wheel.open, timeout=30
    )
    alerted = time.monotonic()
    harness.spin_until(lambda: time.monotonic() - alerted > 0.3)  # the person reacts
    held['deadman'] = True
    assert harness.spin_until(lambda: requests and requests[-1].outcome == AdviceRequestMsg.TAKEN, timeout=5)
    taken_at = len(applied)
    assert harness.spin_until(lambda: len(applied) > taken_at + 20, timeout=5)
    assert applied[taken_at + 1 : taken_at + 20] == [-2.0] * 19  # the person's action at every step
    held['deadman'] = False
    assert harness.spin_until(lambda: requests and requests[-1].outcome == AdviceRequestMsg.GIVEN, timeout=5)
    given = requests[-1]
    assert given.wheel and given.detail == 'released' and given.human and given.steps_driven >= 20
    handed = len(applied)
    assert harness.spin_until(lambda: len(applied) > handed + 20, timeout=5)
    assert -2.0 not in applied[handed + 2 :]  # the learner's again within a step
    counts = learner.learner.episode_advice
    assert counts.asked_steps == given.steps_driven == len(learner.learner.advice_replay)
    assert counts.given == counts.human == 1 and counts.failed['timeout'] >= 1
    # Each of those steps is labelled as asked in the transitions the record keeps (TransitionBatch.sources).
    sources = [row[6] for row in learner._recorded]
    assert sources.count(ACTION_SOURCES.index('asked')) == counts.asked_steps and sources.count(0) > 20
    # The stretch's seconds: from the alert (reaction included) to the hand-back.
    assert given.response_time_s >= 0.3 + given.steps_driven / 40.0 * 0.8


def test_stop_holds_an_open_request_for_one_answer_and_its_window(harness, ros_context, tmp_path):
    """advice_protocol answer in real time: a STOP while a request waits holds the learner's
    timeout and teleop_expert's window (no answer lands while the env ignores actions); released,
    the request goes on, is answered, and the stop is not counted as the person's time."""
    from std_msgs.msg import Bool

    harness.add(
        GymEnvNode(
            context=ros_context, parameter_overrides=params(realtime=True, rate_hz=30.0, max_episode_steps=10**6)
        )
    )
    teleop = harness.add(
        TeleopExpertNode(
            context=ros_context,
            parameter_overrides=params(source='array', axes=[0], scales=[2.0], offsets=[0.0], answer_window_s=1.5),
        )
    )
    learner = harness.add(
        LearnerNode(
            context=ros_context,
            parameter_overrides=asking_learner_params(
                tmp_path,
                advice_protocol='answer',
                advice_timeout_s=2.0,
            ),
        )
    )
    person = harness.add(rclpy.create_node('keyboard_teleop', context=ros_context))  # the UI it stands for
    commands = person.create_publisher(Float32MultiArray, 'teleop_command', 10)
    stop = person.create_publisher(Bool, messages.STOP_TOPIC, messages.STOP_QOS)
    requests = []
    person.create_subscription(AdviceRequestMsg, 'learner/advice_request', requests.append, messages.LATCHED_QOS)
    assert harness.spin_until(lambda: learner.advice.pending is not None and teleop.expert.pending, timeout=30)
    asked = time.monotonic()
    stop.publish(Bool(data=True))
    assert harness.spin_until(lambda: requests and requests[-1].detail == 'stopped', timeout=5)
    held_for = time.monotonic()
    harness.spin_until(lambda: time.monotonic() - held_for > 2.5, timeout=5)  # past both windows
    assert learner.advice.pending is not None and teleop.expert.pending is not None
    commands.publish(messages.command_msg([0.5], True, True, False))  # an answer while stopped: held
    harness.spin_until(lambda: time.monotonic() - held_for > 2.8, timeout=5)
    assert learner.advice.pending is not None
    stop.publish(Bool(data=False))
    assert harness.spin_until(
        lambda: requests and requests[-1].outcome == AdviceRequestMsg.PENDING and not requests[-1].detail
    )
    commands.publish(messages.command_msg([0.5], True, False, False))
    commands.publish(messages.command_msg([0.5], True, True, False))  # Enter
    assert harness.spin_until(lambda: requests and requests[-1].outcome == AdviceRequestMsg.GIVEN, timeout=5)
    given = requests[-1]
    assert given.human and list(given.given_action) == [1.0]
    stopped_s = learner.summaries[-1].stopped_s if learner.summaries else None
    assert given.response_time_s < time.monotonic() - asked - 2.5  # the stop is not the person's time
    assert stopped_s is None or stopped_s >= 2.5


def test_a_stranger_beside_teleop_expert_on_person_command_drives_nothing(harness, ros_context, tmp_path):
    """person_command drives the robot: the learner takes it only while teleop_expert alone
    publishes it. A second node sending the deadman and take-over gets no step."""
    harness.add(GymEnvNode(context=ros_context, parameter_overrides=params(max_episode_steps=10**6)))
    learner = harness.add(
        LearnerNode(context=ros_context, parameter_overrides=small_learner_params(tmp_path, learning_starts=10**6))
    )
    teleop = harness.add(rclpy.create_node('teleop_expert', context=ros_context))
    mallory = harness.add(rclpy.create_node('mallory', context=ros_context))
    quiet = teleop.create_publisher(Float32MultiArray, messages.PERSON_COMMAND_TOPIC, 10)  # noqa: F841
    pub = mallory.create_publisher(Float32MultiArray, messages.PERSON_COMMAND_TOPIC, 10)
    mallory.create_timer(0.02, lambda: pub.publish(messages.person_command_msg([-2.0], True, True)))
    assert harness.spin_until(lambda: learner.refused_person_commands > 20, timeout=20)
    assert learner.learner.episode_advice.takeover_steps == 0 and learner.wheel.person is None


def test_with_a_shared_key_a_stranger_posing_as_teleop_expert_drives_nothing(harness, ros_context, tmp_path):
    """person_command drives the robot. Without a key, a stranger named teleop_expert while the real
    one is not running is taken for it. With key_file, the learner takes only commands signed with
    the key, which teleop_expert signs as it passes the person's signed commands on."""
    from eqhrl_ros.core.data.signing import CommandSeal, Signer, new_key_file, read_key

    key = str(new_key_file(tmp_path / 'deployment.key'))
    harness.add(GymEnvNode(context=ros_context, parameter_overrides=params(max_episode_steps=10**6)))
    learner = harness.add(
        LearnerNode(
            context=ros_context,
            parameter_overrides=small_learner_params(
                tmp_path, advising_budget=0, learning_starts=10**6, takeover_threshold=0.25, key_file=key
            ),  # fmt: skip
        )
    )
    impostor = harness.add(rclpy.create_node('teleop_expert', context=ros_context))
    pub = impostor.create_publisher(Float32MultiArray, messages.PERSON_COMMAND_TOPIC, 10)
    other_key = CommandSeal(Signer(b'not the deployment key, no'))
    impostor.create_timer(0.02, lambda: pub.publish(messages.person_command_msg([-2.0], True, True)))
    impostor.create_timer(0.02, lambda: pub.publish(messages.person_command_msg([-2.0], True, True, other_key)))
    assert harness.spin_until(lambda: learner.refused_person_commands > 20, timeout=20)
    assert learner.learner.episode_advice.takeover_steps == 0 and learner.wheel.person is None
    harness.nodes.remove(impostor)
    impostor.destroy_node()

    teleop = harness.add(
        TeleopExpertNode(
            context=ros_context,
            parameter_overrides=params(source='array', axes=[0], scales=[2.0], offsets=[0.0], key_file=key),
        )
    )
    driver = harness.add(rclpy.create_node('advice_console', context=ros_context))
    commands = driver.create_publisher(Float32MultiArray, 'teleop_command', 10)
    person = CommandSeal(Signer(read_key(key)))
    assert harness.spin_until(lambda: teleop.env_info.spec is not None, timeout=20)
    driver.create_timer(
        0.02, lambda: commands.publish(messages.command_msg([-1.0], True, False, False, person, take_over=True))
    )
    assert harness.spin_until(lambda: learner.learner.episode_advice.takeover_steps >= 10, timeout=20)
