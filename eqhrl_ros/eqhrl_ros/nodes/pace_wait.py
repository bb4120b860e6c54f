"""The first observation held until the env says its pace (advice_protocol auto).

A learner configured by ``env_id`` knows the env's spaces but not whether it runs in real time:
only the env's own env_info says so, and it is taken a moment after the env's first observation
(once the graph vouches for the env, env_info.py). Acting at once would let the first gates that
fire ask nothing, or ask the wrong way (one answer about a state a real-time env has left). So
the acting node holds the first observation until env_info comes, for at most AUTO_PACE_WAIT_S,
and then acts on it at once. A lock-step env waits for the action meanwhile. A real-time one goes
on: the observations it sends meanwhile are held in order too (up to HELD_MAX) and acted on in
order, as by a learner that fell behind, so that the episode is seen whole. (Holding only the
latest made the learner join its first episode at step 1, marked interrupted, whenever a step
came before env_info: test_realtime_rate failed so.)
"""

from __future__ import annotations

from collections import deque
from typing import Callable

from rclpy.node import Node

# How long the first observation waits for the env's env_info before the node acts without it
# (its gates then ask nothing until env_info comes: acting_node.py says so in a warning).
AUTO_PACE_WAIT_S = 3.0
# Most observations held meanwhile (a real-time env at up to 85 Hz for the whole wait); past it the
# oldest go, and the learner joins that episode where the held ones start (marked interrupted).
HELD_MAX = 256


class PaceWait:
    """``unknown()``: the protocol depends on a pace not heard yet; ``act(data)``: act on a held
    observation (the node's own observation callback, told the message was seen already).
    The caller holds its lock around ``hold``; ``release`` and the timer take ``lock``."""

    def __init__(self, node: Node, unknown: Callable[[], bool], act: Callable[[bytes], None], clock, lock):
        self._node, self._unknown, self._act, self._clock, self._lock = node, unknown, act, clock, lock
        self.held: deque[bytes] = deque(maxlen=HELD_MAX)  # in the order they came
        self.state = 'not yet'  # 'not yet', 'waiting' (a timer of AUTO_PACE_WAIT_S runs), 'over'
        self.superseded = 0  # observations held, then let go for later ones (past HELD_MAX)
        self._timer = None

    def hold(self, data: bytes) -> bool:
        """True when ``data`` is held (the pace is unknown and the wait has not run out)."""
        if not self._unknown() or self.state == 'over':
            return False  # release (under the same lock) has acted on every one held before this
        if self.state == 'not yet':
            self.state = 'waiting'
            # The env may send nothing more meanwhile (lock-step, or its last re-send was this one).
            self._timer = self._node.create_timer(AUTO_PACE_WAIT_S, self._over, clock=self._clock)
            self._node.get_logger().info(
                f"advice_protocol auto: waiting up to {AUTO_PACE_WAIT_S:g} s for the env's env_info "
                '(real time: the wheel; lock-step: one answer) before acting'
            )
        self.superseded += len(self.held) == HELD_MAX
        self.held.append(data)
        return True

    def _over(self) -> None:
        with self._lock:
            self.state = 'over'
        self.release()

    def release(self) -> None:
        """The env's own env_info came, or the wait ran out: act on the observations held, in order,
        at once. Under the node's lock (reentrant): no later observation goes before them."""
        with self._lock:
            if self._timer is not None:
                self._timer.cancel()  # once is enough
            while self.held:
                self._act(self.held.popleft())

    def say_unasked(self, topic: str) -> None:
        """The gates fired while the pace is still unknown (the wait ran out): nothing is asked."""
        self._node.get_logger().warn(
            f"advice_protocol auto: no env_info from the env on '{topic}' in {AUTO_PACE_WAIT_S:g} s, so "
            'whether it runs in real time (the wheel) or lock-step (one answer) is not known; the gates fired, '
            'nothing was asked and the learner acts on its own (counted as unavailable; set advice_protocol '
            'answer or wheel for an env that publishes no env_info)',
            throttle_duration_sec=5.0,
        )
