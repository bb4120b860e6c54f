"""Spinning and shutting down a node the same way in every executable."""

from __future__ import annotations

import sys
from typing import Callable, Optional

import gymnasium
import rclpy
import rclpy.exceptions
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

from ..core.checkpoint import CheckpointError

# What a node raises when it cannot start as configured: bad parameters, an unknown
# env id, an unusable checkpoint or policy file. One clear line, exit code 1.
START_UP_ERRORS = (ValueError, FileNotFoundError, CheckpointError, gymnasium.error.Error,
                   rclpy.exceptions.ParameterException)


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


def run_node(node_class: Callable[[], Node], args=None,
             on_exit: Optional[Callable[[Node], None]] = None) -> None:
    """The main() of every node: init, spin until Ctrl-C/SIGTERM, clean up, always.

    ``on_exit`` runs before the node is destroyed, also after a signal (the learner
    saves its checkpoint there). A start-up refusal prints one line and exits with 1.
    """
    rclpy.init(args=args)
    node = None
    try:
        node = node_class()
        spin(node)
    except START_UP_ERRORS as error:
        name = getattr(node_class, '__name__', 'node')
        print(f'{name}: refused to start: {error}', file=sys.stderr)
        raise SystemExit(1)
    finally:
        if node is not None:
            if on_exit is not None:
                on_exit(node)
            node.destroy_node()
        rclpy.try_shutdown()
