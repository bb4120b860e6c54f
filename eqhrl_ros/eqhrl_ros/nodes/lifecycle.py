"""Spinning and shutting down a node the same way in every executable."""

from __future__ import annotations

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node


def spin(node_or_executor) -> None:
    """Spin until Ctrl-C, SIGTERM or a shutdown from inside; return normally in all three cases.

    rclpy turns SIGINT and SIGTERM into a context shutdown. Depending on when the
    signal lands, spinning then ends with KeyboardInterrupt, ExternalShutdownException,
    or an RCLError about an invalid context from building the next wait set. The last
    is a normal exit only when the context really was shut down.
    """
    context = node_or_executor.context
    try:
        if isinstance(node_or_executor, Node):
            rclpy.spin(node_or_executor)
        else:
            node_or_executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        if context.ok():
            raise
