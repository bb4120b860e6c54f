"""Each node's health on the standard ``/diagnostics`` topic (diagnostic_msgs/DiagnosticArray, 1 Hz),
where ROS users look: ``ros2 topic echo /diagnostics``, rqt_runtime_monitor, Foxglove.

A node gives a function that returns its checks; each check is one DiagnosticStatus named
``<node>: <check>`` with a level (OK, WARN, ERROR), a one-line message and its numbers. A healthy
run is all OK: WARN says something a person should look at (no expert, a stalled env, a silent
actor, the robot stopped), ERROR something that stops learning.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node

from .spinning import steady_clock

TOPIC = '/diagnostics'
OK, WARN, ERROR = 0, 1, 2
_LEVELS = {OK: DiagnosticStatus.OK, WARN: DiagnosticStatus.WARN, ERROR: DiagnosticStatus.ERROR}


@dataclass
class Check:
    name: str
    level: int
    message: str
    values: dict = field(default_factory=dict)


class Health:
    """Publishes ``checks()`` on /diagnostics every ``period_s`` (steady clock); ``last`` holds them."""

    def __init__(self, node: Node, checks: Callable[[], list], period_s: float = 1.0):
        self.node, self.checks = node, checks
        self.last: list[Check] = []
        self.publisher = node.create_publisher(DiagnosticArray, TOPIC, 10)
        node.create_timer(period_s, self.publish, clock=steady_clock())

    def level(self, name: str) -> int:
        return next((c.level for c in self.last if c.name == name), -1)

    def publish(self) -> None:
        try:
            checks = self.checks()
        except Exception as error:  # a check that fails says so, as an ERROR, and the node goes on
            checks = [Check('health', ERROR, f'a health check failed: {error!r:.200}')]
        self.last = checks
        me = self.node.get_fully_qualified_name()
        msg = DiagnosticArray()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.status = [
            DiagnosticStatus(
                level=_LEVELS[c.level],
                name=f'{me}: {c.name}',
                message=c.message,
                hardware_id=me,
                values=[KeyValue(key=str(k), value=str(v)) for k, v in c.values.items()],
            )
            for c in checks
        ]
        self.publisher.publish(msg)
