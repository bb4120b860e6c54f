"""Spinning and shutting down a node the same way in every executable.

Signals: rclpy's own handlers are not installed. Its C handler shuts the context down
at once, wherever the node is (a callback then fails to publish: "publisher's context
is invalid"), and it chains to Python's default handler, which raises
KeyboardInterrupt at an arbitrary line, e.g. half-way through a gradient update or
inside destroy_node. Here SIGINT and SIGTERM only ask the spin loop to stop; the
callback that is running finishes, then the node saves what it must and exits 0. A
second signal during that is reported and does not interrupt it (SIGKILL still ends
the process at once). ``ros2 launch`` sends SIGINT, then SIGTERM after a while:
both are handled the same way.
"""

from __future__ import annotations

import faulthandler
import functools
import gc
import logging
import os
import signal
import sys
from typing import Callable, Optional

import rclpy
import rclpy.exceptions
from rclpy.clock import Clock, ClockType
from rclpy.executors import Executor, ExternalShutdownException, MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future

from ..core.data.errors import CheckpointError


# What a node raises when it cannot start as configured: bad parameters, an unknown
# env id, an unusable checkpoint, policy file or output folder. One clear line, exit code 1.
def start_up_errors() -> tuple:
    errors = (ValueError, OSError, CheckpointError, rclpy.exceptions.ParameterException)
    gymnasium = sys.modules.get('gymnasium')  # loaded by the nodes that make envs
    return errors + ((gymnasium.error.Error,) if gymnasium is not None else ())


def leaves_nothing_when_refused(init: Callable) -> Callable:
    """For a node's ``__init__``: a node that refuses to start (raises) destroys the publishers,
    subscriptions and timers it had made, then raises. Else, until the garbage collector found it,
    the half-built node stayed on the graph (a ghost publisher of a learner's action, seen by an
    env as a second node driving it) in any process that goes on: eqhrl-train's, a test run's."""

    @functools.wraps(init)
    def wrapped(self, *args, **kwargs):
        try:
            init(self, *args, **kwargs)
        except BaseException:
            try:
                Node.destroy_node(self)
            except Exception:  # Node.__init__ itself failed: nothing was made
                pass
            raise

    return wrapped


class ExitError(RuntimeError):
    """The node stopped but could not finish cleanly (e.g. its last save failed): one line, exit 1."""


def stop_with_error(node: Node, message: str) -> None:
    """A running node that cannot go on as configured (e.g. the env's env_info disagrees with
    it): log one error line and stop spinning; run_node then exits with code 1. The message is
    kept as ``node.exit_error`` (the first one, if several come)."""
    node.get_logger().error(message)
    if getattr(node, 'exit_error', None) is None:
        node.exit_error = message
    node.context.try_shutdown()


EXECUTORS = ('single', 'events', 'multi')
DEFAULT_EXECUTOR = 'single'


def make_executor(kind: Optional[str] = None, context=None, coroutines: bool = False):
    """The executor that spins our nodes: ``kind`` or $EQHRL_EXECUTOR, else 'single'.

    'single' (rclpy's SingleThreadedExecutor) takes messages through a wait set, so what
    waits to be processed is bounded by each subscription's QoS depth: a flood of
    messages cannot grow the process's memory. 'events' (rclpy.experimental's
    EventsExecutor) steps the env several times as fast through the topics with updates off,
    but queues one event per arriving message without a limit, so a flood grows memory
    until it stops (benchmarks/flood.py); use it only on a closed graph. Where an rclpy
    lacks it, 'single' is used. 'multi' is the MultiThreadedExecutor; the nodes are safe
    under all three.

    ``coroutines``: a node answers from coroutine callbacks (a person's answer window, a
    simulated person's reaction time). rclpy's EventsExecutor does not run those, so such a
    node gets 'single' instead of 'events'.
    """
    kind = kind or os.environ.get('EQHRL_EXECUTOR') or DEFAULT_EXECUTOR
    if kind not in EXECUTORS:
        raise ValueError(f'executor {kind!r} is not one of {EXECUTORS}')
    if kind == 'events' and not coroutines:
        try:
            from rclpy.experimental import EventsExecutor
        except ImportError:
            kind = 'single'
        else:
            return EventsExecutor(context=context)
    if kind == 'multi':
        return MultiThreadedExecutor(context=context)
    return SingleThreadedExecutor(context=context)


def needs_coroutines(node: Node) -> bool:
    """The node answers from coroutine callbacks (see make_executor)."""
    return bool(getattr(node, 'coroutine_callbacks', False))


def steady_clock() -> Clock:
    """A clock for timeouts that must fire whatever ROS time does (use_sim_time, a stopped /clock)."""
    return Clock(clock_type=ClockType.STEADY_TIME)


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


# Seconds after a stop request before a shutdown that has not finished reports its stacks.
STOP_REPORT_S = 20.0


class StopSignals:
    """SIGINT and SIGTERM as a request to stop, read by the spin loop between callbacks."""

    def __init__(self, name: str, saves: bool = True):
        self.name = name
        self.saves = saves  # the node writes files at exit (its second signal says so)
        self.received: list[int] = []

    @property
    def requested(self) -> bool:
        return bool(self.received)

    def install(self) -> 'StopSignals':
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self._on_signal)
        return self

    def finished(self) -> None:
        """The node is cleaned up: ignore further signals while the interpreter exits. (At exit
        Python resets its own handlers to the default, which would end the process with the
        signal, exit code -2, if a second Ctrl-C landed then; an ignored signal stays ignored.)"""
        faulthandler.cancel_dump_traceback_later()
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, signal.SIG_IGN)

    def _on_signal(self, signum, _frame) -> None:
        self.received.append(signum)
        if len(self.received) == 1:
            # A stop that has not ended after STOP_REPORT_S prints every thread's stack to stderr
            # (and the process goes on): what a stuck shutdown waits for, in the log.
            faulthandler.dump_traceback_later(STOP_REPORT_S, exit=False)
        if len(self.received) == 2:
            # os.write, not print: the signal may have landed inside a write to stderr.
            doing = 'finishing the save (SIGKILL aborts it)' if self.saves else 'exiting'
            os.write(2, f'{self.name}: {signal.Signals(signum).name} again: already stopping, {doing}\n'.encode())


def init(args=None, name: str = 'node', context=None, saves: bool = True) -> StopSignals:
    """rclpy.init without rclpy's signal handlers, and ours installed (see the module doc)."""
    rclpy.init(args=args, context=context, signal_handler_options=SignalHandlerOptions.NO)
    stop = StopSignals(name, saves).install()
    end_with_parent()
    return stop


def end_with_parent() -> None:
    """A SIGINT, a stop as at Ctrl-C (saved, exit 0), when the process that started this one dies.
    `ros2 launch` ends at SIGTERM without stopping its nodes (launch's own warning: 'using SIGTERM
    can result in orphaned processes'), and so did a kill -9 of it or of `ros2 run`: the orphaned
    learner went on acting, and the next launch's learner made a second publisher on 'action', so
    the env stepped for neither. Linux's PR_SET_PDEATHSIG; elsewhere, nothing."""
    if not sys.platform.startswith('linux'):
        return
    import ctypes

    parent = os.getppid()
    ctypes.CDLL(None).prctl(1, int(signal.SIGINT), 0, 0, 0)  # 1: PR_SET_PDEATHSIG
    if os.getppid() != parent:  # it died before the line above could watch it
        os.kill(os.getpid(), signal.SIGINT)


def spin(node_or_executor, stop: Optional[StopSignals] = None) -> None:
    """Spin until ``stop`` is requested or the context is shut down from inside; return normally.

    One callback at a time through spin_once, so a stop request is seen within 0.1 s and
    never interrupts a callback.
    """
    context = node_or_executor.context
    try:
        if isinstance(node_or_executor, Node):
            executor = make_executor(context=context, coroutines=needs_coroutines(node_or_executor))
            executor.add_node(node_or_executor)
            try:
                _spin_executor(executor, context, stop)
            finally:
                executor.remove_node(node_or_executor)
                _end(executor)
        else:
            try:
                _spin_executor(node_or_executor, context, stop)
            finally:
                _end(node_or_executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        if context.ok():
            raise


def _end(executor) -> None:
    """End a Python executor's spinning for good. A stop read between callbacks that were ready
    together leaves rclpy's executor in the middle of iterating them, with the handles of
    ready waitables held; destroy_node() then waits for them forever (an expert node hung on
    SIGTERM this way). shutdown() drops that iteration and releases them."""
    if isinstance(executor, Executor):
        executor.shutdown(timeout_sec=0)


def spin_apart(executors: list, stop: Optional[StopSignals] = None) -> None:
    """Spin several executors at once: the first in this thread (where signals land), each
    other in a thread of its own; return when all have stopped. Why: a node whose callbacks
    take long (the learner's gradient updates) then cannot delay another's timers (a
    real-time env keeps its rate); torch releases the GIL while it computes."""
    import threading

    errors = []

    def run(executor):
        try:
            spin(executor, stop)
        except Exception as error:  # raised again in the main thread, after all have stopped
            errors.append(error)
            executor.context.try_shutdown()

    threads = [
        threading.Thread(target=run, args=(e,), name=f'executor-{i}', daemon=True)
        for i, e in enumerate(executors[1:], 1)
    ]
    for thread in threads:
        thread.start()
    try:
        spin(executors[0], stop)
    finally:
        for thread in threads:
            thread.join()
    if errors:
        raise errors[0]


def _spin_executor(executor, context, stop: Optional[StopSignals]) -> None:
    # spin_once in a loop for every executor kind: the EventsExecutor of rclpy 7.1 (Jazzy)
    # never runs timers inside spin(), and the loop is where a stop request is read.
    while context.ok() and not (stop and stop.requested):
        executor.spin_once(timeout_sec=0.1)


def run_node(
    node_class: Callable[[], Node],
    args=None,
    on_exit: Optional[Callable[[Node], None]] = None,
    name: Optional[str] = None,
) -> None:
    """The main() of every node: init, spin until Ctrl-C/SIGTERM, clean up, always.

    ``on_exit`` runs before the node is destroyed, also after a signal (the learner
    saves its checkpoint there); an ExitError from it is one line and exit code 1. A
    start-up refusal prints one line and exits with 1.
    """
    name = name or getattr(node_class, '__name__', 'node')
    stop = init(args, name, saves=on_exit is not None)
    node = None
    try:
        node = node_class()
        spin(node, stop)
    except start_up_errors() as error:
        if node is not None:
            raise
        print(f'{name}: refused to start: {error}', file=sys.stderr)
        raise SystemExit(1) from None
    finally:
        status = 0
        if node is not None:
            if getattr(node, 'exit_error', None):
                status = 1  # the node stopped itself with an error line (stop_with_error)
            if on_exit is not None:
                try:
                    on_exit(node)
                except ExitError as error:
                    print(f'{name}: {error}', file=sys.stderr)
                    status = 1
            node.destroy_node()
        rclpy.try_shutdown()
        stop.finished()
        # All is saved, closed and shut down: spare the interpreter's last garbage collection over
        # torch's object graph (and, after compile_update, the compiler's), which alone made a
        # node's exit 1.0-1.8 s longer (docs/performance.md, "A node's exit").
        gc.freeze()
        if sys.exc_info()[0] is None:  # (an error on its way up keeps its traceback)
            end_process(status)
        if status:
            raise SystemExit(status)


def end_process(status: int) -> None:
    """Once all is saved, closed and shut down: end the process with ``status`` at once while a
    compile_update compile still runs in its background thread. The interpreter's own exit stops
    a daemon thread inside the compiler's C++ and aborts the process ('terminate called without
    an active exception', exit code 134: a Ctrl-C in a learner's first half minute)."""
    compiled = sys.modules.get('eqhrl_ros.core.algorithm.compiled_update')  # none: nothing compiles
    if compiled is not None and compiled.compiling():
        logging.shutdown()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)


async def pause(node, seconds: float, clock) -> None:
    """Await ``seconds`` on ``clock`` inside a coroutine callback, without blocking the
    executor's thread (a one-shot timer completes a future)."""
    if seconds <= 0:
        return
    done = Future()
    timer = node.create_timer(seconds, lambda: done.done() or done.set_result(None), clock=clock)
    try:
        await done
    finally:
        node.destroy_timer(timer)
