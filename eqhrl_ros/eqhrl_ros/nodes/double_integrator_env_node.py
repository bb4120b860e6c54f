"""double_integrator_env: an example env node that is not gymnasium. Copy it for your own robot.

A point mass on a line: state [x, v], force u in [-1, 1], x'' = u. The task is to bring it
to rest at x = 0: reward -(x^2 + 0.1 v^2 + 0.01 u^2) per step, 100 steps of 0.1 s. A PD law
(the expert's heuristic backend for this env) scores about -4; pushing at random about -580.

The node class speaks the protocol of the package README ("Connect your own robot or
simulator") with nothing but rclpy, numpy, std_msgs and eqhrl_interfaces (only main() uses
this package's runner, for a clean Ctrl-C):
- it announces itself once on the latched ``env_info`` (eqhrl_interfaces/msg/EnvInfo);
- it publishes each step on ``observation``: obs[2], reward, terminated, truncated, episode,
  step, success (a std_msgs/Float32MultiArray, labelled);
- it steps when an action comes on ``action`` (lock-step), or at ``rate_hz`` with the latest
  action (``realtime``), where an action older than ``action_timeout_s`` is replaced by zero
  force (the deadman a real robot needs);
- it takes actions only while one node publishes ``action``: a second (another learner, a
  stranger's ``ros2 topic pub``) stops it taking any until one is left.
"""

from __future__ import annotations

import time

import numpy as np
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Bool, Float32MultiArray, MultiArrayDimension, MultiArrayLayout

from eqhrl_interfaces.msg import EnvInfo

NAME = 'double_integrator'  # the expert's heuristic backend has a PD controller for this name
OBS_LABELS = ('x', 'v')
ACTION_LABELS = ('force',)
ACTION_LOW, ACTION_HIGH = -1.0, 1.0
UNKNOWN = ('_NODE_NAMESPACE_UNKNOWN_', '_NODE_NAME_UNKNOWN_')  # rmw's name for a node it no longer knows


# The node's parameters: name, default, description, (low, high) or None.
PARAMETERS = (
    ('max_episode_steps', 100, 'Steps before truncation', (1, 2**31 - 1)),
    ('seed', 0, 'Seed of the start states', (0, 2**31 - 1)),
    ('dt', 0.1, 'Integration step in seconds', (0.001, 10.0)),
    ('realtime', False, 'Step at rate_hz with the latest action (false: lock-step, one step per action)', None),
    ('rate_hz', 10.0, 'Real-time step rate', (0.1, 1000.0)),
    ('action_timeout_s', 0.5, 'Real-time deadman: zero force when the latest action is older than this', (0.01, 60.0)),
    ('republish_period_s', 0.5, 'Lock-step: re-send the observation when no action came for this long', (0.01, 60.0)),
    ('max_action_change', 0.0, 'Most the force may change from one step to the next (0: no limit)', (0.0, 1e9)),
)


class DoubleIntegrator:
    """The dynamics, with no ROS in them: x'' = u, semi-implicit Euler with step dt."""

    def __init__(self, dt: float = 0.1, seed: int = 0):
        self.dt = dt
        self.rng = np.random.default_rng(seed)
        self.x = self.v = 0.0

    def reset(self) -> np.ndarray:
        self.x, self.v = self.rng.uniform(-1.0, 1.0), self.rng.uniform(-0.5, 0.5)
        return np.array([self.x, self.v], dtype=np.float32)

    def step(self, u: float) -> tuple[np.ndarray, float]:
        u = float(np.clip(u, ACTION_LOW, ACTION_HIGH))  # the action limits, whatever arrives
        self.v += u * self.dt
        self.x += self.v * self.dt
        reward = -(self.x**2 + 0.1 * self.v**2 + 0.01 * u**2)
        return np.array([self.x, self.v], dtype=np.float32), reward

    def at_rest(self) -> bool:
        return abs(self.x) < 0.25 and abs(self.v) < 0.25


def layout(*fields: tuple[str, int]) -> MultiArrayLayout:
    return MultiArrayLayout(dim=[MultiArrayDimension(label=label, size=size, stride=size) for label, size in fields])


OBSERVATION_LAYOUT = layout(
    ('obs', 2), ('reward', 1), ('terminated', 1), ('truncated', 1), ('episode', 1), ('step', 1), ('success', 1)
)


class DoubleIntegratorEnv(Node):
    def __init__(self, **kwargs):
        super().__init__('double_integrator_env', **kwargs)

        values = {}
        for name, default, description, bounds in PARAMETERS:
            descriptor = ParameterDescriptor(description=description, read_only=True)
            if isinstance(default, float) and bounds:
                descriptor.floating_point_range = [FloatingPointRange(from_value=bounds[0], to_value=bounds[1])]
            elif isinstance(default, int) and not isinstance(default, bool) and bounds:
                descriptor.integer_range = [IntegerRange(from_value=bounds[0], to_value=bounds[1])]
            values[name] = self.declare_parameter(name, default, descriptor).value
        self.max_steps = values['max_episode_steps']
        self.realtime, self.rate_hz = values['realtime'], values['rate_hz']
        self.action_timeout_s = values['action_timeout_s']
        self.republish_period_s = values['republish_period_s']
        self.system = DoubleIntegrator(values['dt'], values['seed'])
        self.episode, self.step_index = 0, 0
        self.action, self.action_time = 0.0, 0.0
        self.rejected_actions = 0
        self.max_action_change = values['max_action_change']
        self.previous_u = 0.0
        # The person's stop (std_msgs/Bool on `/stop`, latched): a robot must honour it whatever
        # the learner sends. Here, while stopped, the system is not stepped at all (it holds).
        self.stopped = False

        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        latched = QoSProfile(
            depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
        )
        self.info_pub = self.create_publisher(EnvInfo, 'env_info', latched)
        self.observation_pub = self.create_publisher(Float32MultiArray, 'observation', qos)
        self.create_subscription(Float32MultiArray, 'action', self._on_action, qos)
        # One learner drives the robot: while a second node publishes action (another learner, a
        # stranger), no action is taken, as neither can be told from the other (asked of the graph
        # at most every 0.5 s: a query walks every endpoint).
        self.action_topic = self.resolve_topic_name('action')
        self.action_publishers, self.publishers_seen_at, self.refused_actions = 1, float('-inf'), 0
        self.create_subscription(Bool, '/stop', self._on_stop, latched)  # every env hears one STOP
        self.info_pub.publish(
            EnvInfo(
                name=NAME,
                observation_size=2,
                observation_labels=list(OBS_LABELS),
                action_size=1,
                action_labels=list(ACTION_LABELS),
                action_low=[ACTION_LOW],
                action_high=[ACTION_HIGH],
                max_episode_steps=self.max_steps,
                realtime=self.realtime,
                rate_hz=self.rate_hz if self.realtime else 0.0,
                success_rule=EnvInfo.SUCCESS_REPORTED,  # the last field of each observation
                publisher=self.get_fully_qualified_name(),  # tells it from a stranger's env_info
            )
        )
        self._reset()
        # The steady clock: this node is the simulator, so its pace must not wait on ROS time
        # (use_sim_time with a /clock that stops or never starts would stop it for good).
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        if self.realtime:
            self.create_timer(1.0 / self.rate_hz, self._tick, clock=steady)
        else:
            self.create_timer(self.republish_period_s / 2, self._republish_if_idle, clock=steady)
        self.get_logger().info(f'{NAME}: {"real-time at %g Hz" % self.rate_hz if self.realtime else "lock-step"}')

    def _publish(self, obs, reward: float, terminated: bool, truncated: bool, success: bool) -> None:
        values = [*obs, reward, float(terminated), float(truncated), self.episode, self.step_index, float(success)]
        self.last_msg = Float32MultiArray(layout=OBSERVATION_LAYOUT, data=[float(v) for v in values])
        self.observation_pub.publish(self.last_msg)
        self.last_publish = time.monotonic()

    def _reset(self) -> None:
        self.step_index = 0
        self._publish(self.system.reset(), 0.0, False, False, False)

    def _on_stop(self, msg: Bool) -> None:
        # A stop from any node, at once; a release only while one node alone publishes /stop (else a
        # stranger beside the person's page could set the robot going).
        infos = self.get_publishers_info_by_topic('/stop')
        if not msg.data and len({(i.node_namespace, i.node_name) for i in infos} - {UNKNOWN}) > 1:
            self.get_logger().warn(
                'stop release refused: two nodes publish /stop; still stopped', throttle_duration_sec=5.0
            )
            return
        if bool(msg.data) != self.stopped:
            self.stopped = bool(msg.data)
            self.get_logger().warn('STOPPED: holding' if self.stopped else 'stop released')
            if not self.stopped:
                self.observation_pub.publish(self.last_msg)  # the learner acts on from here

    def _step(self, u: float) -> None:
        if self.max_action_change > 0:  # a rate limit: the force moves at most this much a step
            u = float(np.clip(u, self.previous_u - self.max_action_change, self.previous_u + self.max_action_change))
        self.previous_u = u
        obs, reward = self.system.step(u)
        self.step_index += 1
        truncated = self.step_index >= self.max_steps
        # success is judged here (EnvInfo.success_rule 'reported'): at rest on the final step.
        self._publish(obs, reward, False, truncated, truncated and self.system.at_rest())
        if truncated:
            self.episode += 1
            self._reset()

    def _on_action(self, msg: Float32MultiArray) -> None:
        data = np.asarray(msg.data, dtype=np.float32)
        # action[1], optionally tagged with the (episode, step) it answers.
        if data.shape[0] not in (1, 3) or not np.isfinite(data).all():
            self.rejected_actions += 1
            self.get_logger().error(f'rejected action {data.tolist()}', throttle_duration_sec=5.0)
            return
        if self.stopped:
            return  # the person's stop outranks the learner
        if time.monotonic() - self.publishers_seen_at >= 0.5:
            # Nodes, not endpoints (a node restarted after a kill -9 may show twice for a while),
            # and only nodes the graph names (one being torn down shows as _NODE_NAME_UNKNOWN_).
            infos = self.get_publishers_info_by_topic(self.action_topic)
            self.action_publishers = len({(i.node_namespace, i.node_name) for i in infos} - {UNKNOWN})
            self.publishers_seen_at = time.monotonic()
        if self.action_publishers > 1:
            self.refused_actions += 1
            self.get_logger().warn(
                f'action refused: {self.action_publishers} nodes publish {self.action_topic}, and their actions '
                f'cannot be told apart ({self.refused_actions} refused so far)',
                throttle_duration_sec=5.0,
            )
            return
        if self.realtime:
            self.action, self.action_time = float(data[0]), time.monotonic()
            return
        if data.shape[0] == 3 and (int(data[1]), int(data[2])) != (self.episode, self.step_index):
            return  # an answer to an observation already stepped past
        self._step(float(data[0]))

    def _tick(self) -> None:
        if self.stopped:
            return
        # Deadman: a real robot must not keep pushing on an old command.
        fresh = time.monotonic() - self.action_time < self.action_timeout_s
        self._step(self.action if fresh else 0.0)

    def _republish_if_idle(self) -> None:
        # A learner that started late, restarted or lost the message gets the observation again.
        if time.monotonic() - self.last_publish >= self.republish_period_s and not self.stopped:
            self.observation_pub.publish(self.last_msg)
            self.last_publish = time.monotonic()


def main(args=None):
    # This package's runner: Ctrl-C and SIGTERM (also twice, as ros2 launch sends them) end the
    # node cleanly with exit code 0. In your own package, rclpy.init(), rclpy.spin(node) and
    # rclpy.try_shutdown() are enough to start with.
    from eqhrl_ros.nodes.spinning import run_node

    run_node(DoubleIntegratorEnv, args, name='double_integrator_env')


if __name__ == '__main__':
    main()
