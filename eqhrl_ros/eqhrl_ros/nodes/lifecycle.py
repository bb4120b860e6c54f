"""Spinning and shutting down a node the same way in every executable."""

from __future__ import annotations

import os
import sys
from typing import Callable, Optional

import gymnasium
import rclpy
import rclpy.exceptions
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.node import Node

from ..core.checkpoint import CheckpointError

# What a node raises when it cannot start as configured: bad parameters, an unknown
# env id, an unusable checkpoint or policy file. One clear line, exit code 1.
START_UP_ERRORS = (ValueError, FileNotFoundError, CheckpointError, gymnasium.error.Error,
                   rclpy.exceptions.ParameterException)


EXECUTORS = ('events', 'single', 'multi')


def make_executor(kind: Optional[str] = None, context=None):
    """The executor that spins our nodes: ``kind`` or $EQHRL_EXECUTOR, else 'events'.

    'events' is rclpy's EventsExecutor (rclpy.experimental): a C++ event queue instead
    of a wait set rebuilt in Python before every callback. Through the topics it
    steps the env about 3x as fast as the SingleThreadedExecutor and halves the
    advice round trip (benchmarks/bench_ros.py). Where an rclpy lacks it, 'single'
    is used. 'multi' is the MultiThreadedExecutor; the nodes are safe under all three.
    """
    kind = kind or os.environ.get('EQHRL_EXECUTOR') or 'events'
    if kind not in EXECUTORS:
        raise ValueError(f'executor {kind!r} is not one of {EXECUTORS}')
    if kind == 'events':
        try:
            from rclpy.experimental import EventsExecutor
        except ImportError:
            kind = 'single'
        else:
            return EventsExecutor(context=context)
    if kind == 'multi':
        return MultiThreadedExecutor(context=context)
    return SingleThreadedExecutor(context=context)


def seconds_since_process_start() -> float:
    """Wall time since this process was created (Linux /proc; NaN where unavailable)."""
    try:
        with open('/proc/self/stat') as f:
            start_ticks = int(f.read().rsplit(')', 1)[1].split()[19])
        with open('/proc/uptime') as f:
            uptime = float(f.read().split()[0])
        return uptime - start_ticks / os.sysconf('SC_CLK_TCK')
    except (OSError, ValueError, IndexError):
        return float('nan')


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
            executor = make_executor(context=context)
            executor.add_node(node_or_executor)
            try:
                _spin_executor(executor, context)
            finally:
                executor.remove_node(node_or_executor)
        else:
            _spin_executor(node_or_executor, context)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        if context.ok():
            raise


def _spin_executor(executor, context) -> None:
    if isinstance(executor, (SingleThreadedExecutor, MultiThreadedExecutor)):
        executor.spin()
        return
    # The EventsExecutor of rclpy 7.1 (Jazzy) never runs timers inside spin(), only
    # inside spin_once(): so spin_once until the context is shut down.
    while context.ok():
        executor.spin_once(timeout_sec=0.1)


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
