"""env_info: an env node's EnvSpec on a latched topic, and how the other nodes use it.

The env publishes eqhrl_interfaces/msg/EnvInfo once, transient-local, so a node that
starts later still gets it. Every other node either knows the spaces already (a gymnasium
``env_id`` or the spaces as parameters) and checks each EnvInfo against them, or waits for
the first one and takes the spaces from it. A disagreement is a refusal: one error line,
and a node that has not begun its work stops with exit code 1 (see spinning.stop_with_error);
one at work logs it and goes on.
"""

from __future__ import annotations

import time
from collections import deque
from typing import Callable, Optional

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from eqhrl_interfaces.msg import CameraPart, EnvInfo

from ..core.envs.spec import EnvCamera, EnvSpec, spec_from_parameters
from .graph_trust import publishers
from .spinning import start_up_errors, steady_clock, stop_with_error

TOPIC = 'env_info'
# Latched: one message, kept for late joiners. A subscriber must ask for transient-local too.
ENV_INFO_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
# An env_info not taken when it came is looked at again for this long (its env's observation
# publisher may be discovered a moment after it), then dropped; at most HELD_MESSAGES at once.
# One that names its publisher, for NAMED_HOLD_S only: a stranger's that names the env before
# the env runs must not be taken once the env appears.
HOLD_S = 10.0
NAMED_HOLD_S = 2.0
HELD_MESSAGES = 8
# A node that has not heard the env's own env_info yet (no spaces, or spaces from env_id but not the
# env's pace), holding nothing, subscribes anew this often after one was dropped: the latched
# env_info comes again and is judged again (the env's own, dropped because the graph was slow to
# show its observation publisher, would otherwise never come back: it is published once). Just
# past NAMED_HOLD_S, so that the env's own message, dropped at a slow start, comes again at once.
RESUBSCRIBE_S = 2.5
MAX_CAMERAS = 16  # an EnvInfo that announces more is refused


def env_info_msg(spec: EnvSpec, publisher: str = '') -> EnvInfo:
    """``spec`` as an EnvInfo; ``publisher``: the env node's full name (EnvInfo.msg says why)."""
    return EnvInfo(
        publisher=publisher,
        name=spec.name,
        observation_size=spec.observation_size,
        observation_labels=list(spec.observation_labels),
        action_size=spec.action_size,
        action_labels=list(spec.action_labels),
        action_low=spec.action_low.tolist(),
        action_high=spec.action_high.tolist(),
        max_episode_steps=spec.max_episode_steps,
        realtime=spec.realtime,
        rate_hz=float(spec.rate_hz),
        success_rule=spec.success_rule,
        success_threshold=float(spec.success_threshold),
        cameras=[
            CameraPart(name=c.name, topic=c.topic, height=c.height, width=c.width, encoding=c.encoding)
            for c in spec.cameras
        ],
    )


def shown(name: str) -> str:
    """An env's name as one safe log token: printable ASCII, at most 64 characters."""
    text = ''.join(c if c.isascii() and c.isprintable() else '?' for c in name[:65])
    return (text[:61] + '...' if len(text) > 64 else text) or '(unnamed)'


def spec_from_msg(msg: EnvInfo, source: str = TOPIC) -> EnvSpec:
    """The EnvSpec an EnvInfo describes. ValueError names what is inconsistent in it."""
    if len(msg.cameras) > MAX_CAMERAS:
        raise ValueError(f'{len(msg.cameras)} cameras announced, at most {MAX_CAMERAS} ({source})')
    if msg.action_size != len(msg.action_low):
        raise ValueError(f'action_size {msg.action_size} but {len(msg.action_low)} action bounds ({source})')
    return EnvSpec(
        msg.name,
        int(msg.observation_size),
        msg.action_low,
        msg.action_high,
        observation_labels=tuple(msg.observation_labels),
        action_labels=tuple(msg.action_labels),
        max_episode_steps=int(msg.max_episode_steps),
        realtime=bool(msg.realtime),
        rate_hz=float(msg.rate_hz),
        success_rule=msg.success_rule or 'none',
        success_threshold=float(msg.success_threshold),
        cameras=tuple(EnvCamera(c.name, c.topic, int(c.height), int(c.width), c.encoding) for c in msg.cameras),
        source=source,
    )


def configured_spec(params: dict) -> Optional[EnvSpec]:
    """The spec a node's parameters give (ENV_PARAMS): the spaces as parameters, or a gymnasium
    env_id; None when neither is set (the node then waits for env_info). Both set must agree.
    Raises ValueError (a start-up refusal) on an incomplete or contradictory set."""
    from_parameters = spec_from_parameters(
        params.get('observation_size', 0), params.get('action_low'), params.get('action_high')
    )
    env_id = params.get('env_id', '')
    if not env_id:
        return from_parameters
    from ..core.envs.gymnasium_envs import gym_spec

    spec = gym_spec(env_id)
    if from_parameters is not None:
        differences = spec.disagreements(from_parameters)
        if differences:
            raise ValueError(f'the parameters give {"; ".join(differences)} (from env_id {env_id})')
    return spec


class EnvInfoWatcher:
    """Subscribes to ``env_info`` for a node.

    ``configured``: the spec the node was configured with (env_id or parameters), or None.
    ``on_spec(spec)`` is called once: at once with ``configured``, or with the first EnvInfo
    that arrives. Every EnvInfo is checked against the spec in use; a disagreement, or an
    EnvInfo that contradicts itself, stops the node with one error line naming both sides.
    """

    def __init__(
        self,
        node: Node,
        configured: Optional[EnvSpec],
        on_spec: Callable[[EnvSpec], None],
        working: Callable[[], bool] = lambda: False,
        on_announced: Callable[[], None] = lambda: None,
    ):
        """``working()``: the node has begun its work (the learner has stored a step, the expert
        answered). From then on a disagreeing EnvInfo is logged and ignored, not obeyed: any
        node can publish on env_info, and a run in progress is not ended on its word (the
        observations of another size that a really different env sends are dropped anyway)."""
        self.node = node
        self._working = working
        self._on_announced = on_announced  # once: the env's own EnvInfo, first taken, agrees with the spec
        self.ignored = 0  # disagreeing EnvInfo messages ignored while working
        self.spec: Optional[EnvSpec] = None
        self.announced: Optional[EnvSpec] = None  # the env's own EnvInfo, once heard
        self._on_spec = on_spec
        self.subscription = node.create_subscription(EnvInfo, TOPIC, self._on_env_info, ENV_INFO_QOS)
        self.topic = self.subscription.topic_name
        # Only the env speaks for the env: an env_info naming its publisher is taken while that node
        # publishes env_info and the observations (or is env_node); one naming none, while every
        # node publishing env_info does. Any other is held, not obeyed, and looked at again for
        # HOLD_S (graph_trust.py says why the graph decides). So a stranger's latched env_info
        # neither configures a node nor keeps it from the real env's, which names the env.
        self.env_node = node.get_parameter('env_node').value if node.has_parameter('env_node') else ''
        self.observation_topic = node.resolve_topic_name('observation')
        self.untrusted = 0
        # (time.monotonic() it came, EnvInfo, the nodes publishing env_info then: one of them sent it)
        self._held: deque = deque(maxlen=HELD_MESSAGES)
        self._recheck = node.create_timer(0.5, self._on_recheck, clock=steady_clock())
        self._subscribed_at = time.monotonic()
        self.resubscribed = 0
        if configured is not None:
            self._use(configured)
        else:
            node.get_logger().info(f'waiting for env_info on {self.topic}')

    @property
    def ready(self) -> bool:
        return self.spec is not None

    @property
    def judging(self) -> bool:
        """An env_info came and the env's own has not been taken yet: one is held until the graph
        vouches for its sender, or was dropped and comes again (the node subscribes anew). At a
        start this is most often the env's own, its node not yet on the graph of a loaded machine."""
        return self.announced is None and bool(self._held or self.untrusted)

    def _use(self, spec: EnvSpec) -> None:
        self.spec = spec
        self._on_spec(spec)

    def _refuse(self, message: str) -> None:
        if self._working():
            self.ignored += 1
            self.node.get_logger().error(f'{message}; ignored, this run goes on', throttle_duration_sec=5.0)
        else:
            stop_with_error(self.node, message)

    def refusal(self, msg: Optional[EnvInfo] = None) -> str:
        """'' when ``msg`` comes from the env: it names a node that publishes env_info and the
        observations (or is env_node), or it names none and every publisher of env_info is such a
        node. Else why not."""
        speakers = publishers(self.node, self.topic)
        allowed = {self.env_node} if self.env_node else publishers(self.node, self.observation_topic)
        which = f"'{self.env_node}'" if self.env_node else f'the publisher of {self.observation_topic}'
        claimed = getattr(msg, 'publisher', '') if msg is not None else ''
        if claimed:
            if claimed not in speakers:
                relative = (
                    '' if claimed.startswith('/') else ' (a full node name starts with /: get_fully_qualified_name())'
                )
                unseen = 'which the graph does not show publishing it'  # a forged name, or the graph lags
                return f'{self.topic} names its publisher {shown(claimed)}, {unseen}{relative}'
            if claimed not in allowed:
                return f'{self.topic} names its publisher {shown(claimed)}, which is not {which}' + (
                    '' if self.env_node else self._remap_hint(shown(claimed))
                )
            return ''
        strangers = sorted(speakers - allowed)
        if strangers:
            return f'{self.topic} is published by {strangers}, which is not {which}'
        if not speakers:  # its publisher has left: nobody vouches for it
            return f'{self.topic} has no publisher now'
        return ''

    def _remap_hint(self, env: str) -> str:
        """What to do when the env publishes its observations on a topic this node has another
        name for: most often the learner's and the env's `observation` are remapped, not this
        node's, which reads no observation (an expert, a person's page)."""
        return (
            f" (if {env} is your env and its observations go elsewhere, remap this node's observation there too, "
            f'-r observation:=<that topic>, or name the env: -p env_node:={env})'
        )

    def _vouched(self) -> set:
        """The nodes that may speak for the env now: env_node, else the publishers of observation."""
        return {self.env_node} if self.env_node else publishers(self.node, self.observation_topic)

    def _on_recheck(self) -> None:
        now = time.monotonic()
        if self.announced is None and not self._held and now - self._subscribed_at >= RESUBSCRIBE_S and self.untrusted:
            self.node.destroy_subscription(self.subscription)
            self.subscription = self.node.create_subscription(EnvInfo, TOPIC, self._on_env_info, ENV_INFO_QOS)
            self._subscribed_at, self.resubscribed = now, self.resubscribed + 1
        for held in list(self._held):
            # Taken only if a node that published env_info when it came is vouched for now: a
            # stranger's message, held until the real env appears, is never taken for the env's
            # (none known when it came: the graph had not caught up, and the rule alone decides).
            # Looked at before the drops below: one vouched for at the moment its time is up is taken.
            if not self.refusal(held[1]) and (not held[2] or held[2] & self._vouched()):
                self._held.remove(held)
                self._on_env_info(held[1])
                return
        for held in list(self._held):
            if now - held[0] > (NAMED_HOLD_S if held[1].publisher else HOLD_S):
                self._held.remove(held)  # never vouched for in time: dropped
                self._log_drop(held, now)

    def _log_drop(self, held: tuple, now: float) -> None:
        """A warning, unless this is the first drop and the node will hear the latched env_info again
        (it subscribes anew while it has not heard the env's own): at a start the graph often shows
        the env's observation publisher seconds after its env_info came, and the next look takes it."""
        why = self.refusal(held[1]) or 'its sender is not vouched for'
        line = f'env_info not obeyed: {why}; dropped after {now - held[0]:.1f} s'
        if self.announced is None and not self.resubscribed:
            self.node.get_logger().info(f'{line}; looked at again when it comes again', throttle_duration_sec=5.0)
        else:
            self.node.get_logger().warn(line, throttle_duration_sec=5.0)

    def _on_env_info(self, msg: EnvInfo) -> None:
        if self.node.context is None or not self.node.context.ok():
            return
        refusal = self.refusal(msg)
        if refusal:
            self.untrusted += 1
            speakers = publishers(self.node, self.topic)
            self._held.append((time.monotonic(), msg, speakers))  # taken if the graph vouches for it soon
            # Most often the graph has not caught up with the env yet (a start): a warning only if
            # it is dropped (_on_recheck).
            self.node.get_logger().info(f'env_info held, not obeyed yet: {refusal}', throttle_duration_sec=5.0)
            return
        try:
            announced = spec_from_msg(msg, f"env_info from the env '{shown(msg.name)}'")
        except ValueError as error:
            self._refuse(f'refused {self.topic}: {error}')
            return
        first, self.announced = self.announced is None, announced
        if self.spec is None:
            self.node.get_logger().info(
                f'{self.topic}: {shown(announced.name)}, obs {announced.observation_size}, action '
                f'{announced.action_size} in [{announced.action_low.tolist()}, {announced.action_high.tolist()}]'
            )
            try:
                self._use(announced)
            except start_up_errors() as error:  # the node cannot work with it (no controller, a bad checkpoint)
                stop_with_error(self.node, f"cannot start with {self.topic} of '{shown(announced.name)}': {error}")
            return
        differences = self.spec.disagreements(announced)
        if differences:
            self._refuse(
                f"refused {self.topic}: the env '{shown(announced.name)}' has {'; '.join(differences)} "
                f'(this node was configured by {self.spec.source or "an earlier env_info"})'
            )
        elif announced.name != self.spec.name and self.spec.name:
            self.node.get_logger().warn(
                f"{self.topic}: the env is '{shown(announced.name)}', this node was configured for "
                f"'{self.spec.name}'; the spaces agree, going on"
            )
        if first and not differences:
            self._on_announced()
