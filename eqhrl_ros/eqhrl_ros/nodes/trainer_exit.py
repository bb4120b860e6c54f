"""How a trainer node ends: its actors' last batches, then the learning thread stops, then the
save (checkpoint, record, CSV), so that they end together."""

from __future__ import annotations

import time

from .run_files import save_and_close


def _take_the_last_batches(node) -> None:
    """At exit, before the save: actors stopped by the same Ctrl-C (one launch) send what they
    have left and wait for it to be stored (their exit_wait_s). Keep spinning, storing and
    acknowledging, until no actor publishes any more, for at most exit_wait_s."""
    from rclpy.executors import SingleThreadedExecutor

    wait = node.params['exit_wait_s']
    if wait <= 0 or not node.context.ok():
        return
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    deadline = time.monotonic() + wait
    try:
        while time.monotonic() < deadline and node.context.ok() and not node.done:
            if node.count_publishers(node.transitions_topic) == 0 and not node._inbox:
                break
            executor.spin_once(timeout_sec=0.05)
    finally:
        executor.remove_node(node)
        executor.shutdown(timeout_sec=0)


def stop_save_and_close(node) -> None:
    """At exit: the actors' last batches, then the learning thread stops, so that the checkpoint
    and the record end together."""
    try:
        _take_the_last_batches(node)
    except Exception as error:  # the middleware may already be going down (a second Ctrl-C)
        node.get_logger().warn(f'could not take the last batches: {error}')
    node.stop_learning()
    if node.paying:  # stopped while making the updates owed at max_episodes: what is left is said
        node.get_logger().warn(
            f'stopped with {node.trainer.updates_owed()} of the updates owed at max_episodes still unmade: '
            f'the saved policy has had {node.learner.updates} updates (a resume does not make the rest)'
        )
    save_and_close(node)
