"""Who publishes a topic (or serves a service), judged through the ROS graph.

rclpy (Jazzy) tells a subscriber nothing about which publisher sent a message, so a node that
must take a topic from one peer only (teleop_expert's commands, the env's env_info) asks the
graph instead: while another node publishes on the topic too, no message on it can be told
from a stranger's, and it is refused. That is a guard against a second publisher on the graph;
against a stranger that replaces the real one, use SROS2 (the package README's security section).
"""

from __future__ import annotations

import time
from typing import Callable

from rclpy.node import Node

GRAPH_CACHE_S = 0.5  # the graph is asked at most this often per topic (a query walks every endpoint)


# How rmw names the node of an endpoint it cannot map to a node (rmw_dds_common).
UNKNOWN_NODE = '_NODE_NAMESPACE_UNKNOWN_/_NODE_NAME_UNKNOWN_'


def full_name(namespace: str, name: str) -> str:
    return f'{namespace.rstrip("/")}/{name}'


def publishers(node: Node, topic: str) -> set:
    """Full names of the nodes publishing on ``topic`` (a resolved name)."""
    return {full_name(i.node_namespace, i.node_name) for i in node.get_publishers_info_by_topic(topic)}


def servers(node: Node, service: str) -> set:
    """Full names of the nodes serving ``service`` (a resolved name). rclpy (Jazzy) has no query of
    a service's servers, so each node of the graph is asked for its services: call it only when
    ``count_services`` says there is more than one."""
    from rclpy._rclpy_pybind11 import NodeNameNonExistentError

    names = set()
    for name, namespace in node.get_node_names_and_namespaces():
        try:
            served = node.get_service_names_and_types_by_node(name, namespace)
        except NodeNameNonExistentError:  # it left between the two queries
            continue
        if any(each == service for each, _ in served):
            names.add(full_name(namespace, name))
    return names


class OnePublisher:
    """Messages on ``topic`` are trusted while exactly one node publishes it, and it is one of
    ``expected`` when that is given (full node names such as /advice_console)."""

    def __init__(self, node: Node, topic: str, expected=()):
        self.node, self.topic = node, topic
        self.expected = (expected,) if isinstance(expected, str) else tuple(expected)
        self.expected = tuple(e for e in self.expected if e)
        self._checked_at, self._verdict, self._names = float('-inf'), '', frozenset()
        self.refused = 0  # messages admits() turned away

    def admits(self, logger, what: str) -> bool:
        """Whether a message on the topic may be taken now; if not, it is counted and ``logger``
        warns why (at most every 5 s), naming ``what`` was refused."""
        refusal = self.refusal()
        if refusal:
            self.refused += 1
            logger.warn(f'{what} refused: {refusal} ({self.refused} refused so far)', throttle_duration_sec=5.0)
        return not refusal

    def refusal(self) -> str:
        """'' while the topic's publisher can be trusted; else why not, in one line."""
        now = time.monotonic()
        if now - self._checked_at >= GRAPH_CACHE_S:
            self._checked_at, self._verdict = now, self._judge()
        return self._verdict

    @property
    def publishing(self) -> frozenset:
        """The nodes that published the topic when it was last judged."""
        return self._names

    def heard_from(self) -> bool:
        """Whether one node the topic may be taken from publishes it now (refusal() is '' and the
        graph names a publisher): a request that only it can answer has someone to reach."""
        return not self.refusal() and bool(self._names)

    def _judge(self) -> str:
        # A publisher whose node the graph no longer names is a participant being torn down (its
        # node gone, its endpoints not yet): not a second node. A restarted node's old endpoints,
        # still there after a kill -9, carry its own name, and count once.
        names = self._names = frozenset(publishers(self.node, self.topic) - {UNKNOWN_NODE})
        if self.expected and names and not names <= set(self.expected):
            return f"'{self.topic}' is published by {sorted(names)}, not by {' or '.join(self.expected)}"
        if len(names) > 1:
            return (
                f"'{self.topic}' has {len(names)} publishers ({', '.join(sorted(names))}): a message cannot be "
                "told from a stranger's, so none is taken until one publisher is left"
            )
        return ''


def subscribe_from_one(
    node: Node, kind, topic: str, callback, qos, what: str = '', judged: Callable[[object], bool] = lambda msg: True
) -> OnePublisher:
    """A subscription whose messages reach ``callback`` only while one node alone publishes
    ``topic`` (OnePublisher, no name expected): what the person's page or terminal shows of the
    learner (its requests, statistics, driver, the env's frames) is then never a stranger's
    beside it. Only the messages ``judged`` picks are held to that (subscribe_stop: a release, not
    a stop). Returns the guard (its ``refused`` counts what was turned away)."""
    guard = OnePublisher(node, node.resolve_topic_name(topic))

    def taken(msg) -> None:
        if not judged(msg) or guard.admits(node.get_logger(), what or guard.topic):
            callback(msg)

    node.create_subscription(kind, topic, taken, qos)
    return guard


def subscribe_stop(node: Node, callback) -> OnePublisher:
    """The person's STOP (/stop, latched) as a node takes it: a stop from any node, at once (the safe
    way), and a release only while one node alone publishes /stop. Before, a stranger's false
    beside the person's page set a stopped robot going."""
    from std_msgs.msg import Bool

    from .messages import STOP_QOS, STOP_TOPIC

    what = 'the release of STOP (still stopped)'
    return subscribe_from_one(node, Bool, STOP_TOPIC, callback, STOP_QOS, what, judged=lambda msg: not msg.data)
