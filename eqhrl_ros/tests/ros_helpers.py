"""Shared helpers for tests that spin ROS nodes in the test process."""

import threading
import time
from pathlib import Path

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from std_msgs.msg import Float32MultiArray

from eqhrl_interfaces.msg import EpisodeStats, GateDecision
from eqhrl_interfaces.srv import Advise
from eqhrl_ros.nodes import messages
from eqhrl_ros.nodes.gym_env_node import GymEnvNode
from eqhrl_ros.nodes.learner_node import LearnerNode
from eqhrl_ros.nodes.run_files import RunFiles
from eqhrl_ros.nodes.spinning import make_executor

PARAMS_DIR = Path(__file__).resolve().parents[1] / 'params'


def spin_until(executor, condition, timeout=10.0):
    deadline = time.monotonic() + timeout
    while not condition() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.02)
    return condition()


def params(**values):
    return [Parameter(name, value=value) for name, value in values.items()]


def small_learner_params(tmp_path, **extra):
    values = dict(
        env_id='Pendulum-v1',
        mode='eqsac',
        hidden_sizes=[16, 16],
        batch_size=16,
        learning_starts=40,
        queue_length=3,
        advising_budget=2,
        advice_timeout_s=0.3,
        output_dir=str(tmp_path),
        publish_gate_debug=True,
        checkpoint_every_episodes=1,
        # Each test starts its expert (or none) on purpose, before or after the env; the learner's
        # wait for one at the start has tests of its own (test_start_wait.py).
        expert_wait_s=0.0,
    )
    values.update(extra)
    return params(**values)


def asking_learner_params(tmp_path, **extra):
    """A small learner that asks often (random requests at 20 % of steps, 5 episodes of budget) and
    never updates (the first update's compile would stall a real-time env for a second)."""
    values = dict(mode='random', random_ask_rate=0.2, advising_budget=5, learning_starts=10**6)
    return small_learner_params(tmp_path, **{**values, **extra})


def applied_actions(env) -> list:
    """The first action value the env node steps with, step by step (its _step, wrapped)."""
    applied = []
    original = env._step

    def recording(action):
        original(action)
        applied.append(float(env._previous_action[0]))

    env._step = recording
    return applied


class Harness:
    """Nodes in one executor, destroyed at the end of the test."""

    def __init__(self, context, executor='single'):
        """``executor``: a kind for make_executor; 'default' is what the nodes' main() spins."""
        self.context = context
        self.executor = make_executor(None if executor == 'default' else executor, context=context)
        self.nodes = []

    def add(self, node):
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def spin_until(self, condition, timeout=10.0):
        return spin_until(self.executor, condition, timeout)

    def close(self):
        self.executor.shutdown()
        for node in self.nodes:
            if isinstance(node, RunFiles):
                if hasattr(node, 'stop_learning'):
                    node.stop_learning()
                node.close()
            node.destroy_node()


class Probe:
    """A test node that records observations/stats/gates and can publish actions."""

    def __init__(self, harness, name='probe'):
        self.node = harness.add(rclpy.create_node(name, context=harness.context))
        self.observations, self.stats, self.gates = [], [], []
        self.node.create_subscription(Float32MultiArray, 'observation', self.observations.append, 50)
        self.node.create_subscription(EpisodeStats, 'learner/episode_stats', self.stats.append, 100)
        self.node.create_subscription(GateDecision, 'learner/gate_debug', self.gates.append, 1000)
        self._action_pub = None
        self.actions = []
        self.node.create_subscription(Float32MultiArray, 'action', self.actions.append, 50)

    @property
    def action_pub(self):
        """A publisher on 'action', made when a test first acts: an env takes no action while two
        nodes publish it, so a probe that only watches must not be one of them."""
        if self._action_pub is None:
            self._action_pub = self.node.create_publisher(Float32MultiArray, 'action', 10)
        return self._action_pub

    def acted_on(self) -> list:
        """The (episode, step) each action on 'action' answers (tagged actions only)."""
        fields = (messages.parse_fields(m) for m in self.actions)
        return [(int(f['episode']), int(f['step'])) for f in fields if 'step' in f]


def observation_publisher(harness):
    """A publisher on 'observation' that a learner already in ``harness`` has matched, and the
    Probe that sees the learner's answers on 'action'."""
    probe = Probe(harness)
    publisher = probe.node.create_publisher(Float32MultiArray, 'observation', 10)
    assert harness.spin_until(lambda: publisher.get_subscription_count() > 0)
    return publisher, probe


class StubExpert:
    """Serves Advise from its own executor thread, like a separate process would."""

    def __init__(self, context, answer='advise', delay=0.0, name='stub_expert', expert_name='stub', **fields):
        self.node = rclpy.create_node(name, context=context)
        self.requests = []
        self.signatures = []  # each request's signature (empty: unsigned), as it came
        self.answer, self.delay, self.expert_name = answer, delay, expert_name
        self.fields = fields  # more of the response, set as given (human, response_time_s, reason)
        self.node.create_service(Advise, 'advise', self._serve)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def _serve(self, request, response):
        self.requests.append((request.episode, request.step, request.discrepancy, request.entropy))
        self.signatures.append(bytes(request.signature))
        if self.delay:
            time.sleep(self.delay)
        response.expert_name = self.expert_name
        if isinstance(self.answer, list):  # a given (possibly bad) action
            response.advised, response.action = True, self.answer
        elif self.answer == 'advise':
            response.advised, response.action = True, [1.0]
        else:
            response.advised, response.reason = False, 'not now'
        for name, value in self.fields.items():
            setattr(response, name, value)
        return response

    def close(self):
        self.executor.shutdown()
        self.thread.join(timeout=5)
        self.node.destroy_node()


def run_learner(harness, ros_context, tmp_path, episodes=3, **extra):
    probe = Probe(harness)
    harness.add(GymEnvNode(context=ros_context, parameter_overrides=params(max_episode_steps=25)))
    learner = harness.add(
        LearnerNode(
            context=ros_context, parameter_overrides=small_learner_params(tmp_path, max_episodes=episodes, **extra)
        )
    )
    assert harness.spin_until(lambda: learner.done, timeout=60)
    return learner, probe


def rosout_listener(context, heard: list):
    """A node that appends (logger name, text) of each /rosout line to ``heard``; make it before the
    node to hear, so that it hears that node's start too."""
    from rcl_interfaces.msg import Log
    from rclpy.qos import DurabilityPolicy, QoSProfile

    listener = rclpy.create_node('rosout_listener', context=context)
    qos = QoSProfile(depth=1000, durability=DurabilityPolicy.TRANSIENT_LOCAL)  # as rosout publishes
    listener.create_subscription(Log, '/rosout', lambda m: heard.append((m.name, m.msg)), qos)
    return listener
