"""The first observation held until the learner can ask as it should: the env has said its pace
(advice_protocol auto), and an expert serves 'advise' (one answer per request).

The pace. A learner configured by ``env_id`` knows the env's spaces but not whether it runs in
real time: only the env's own env_info says so, and it is taken a moment after the env's first
observation (once the graph vouches for the env, env_info.py). Acting at once would let the first
gates that fire ask nothing, or ask the wrong way (one answer about a state a real-time env has
left). So the first observation waits for env_info, for at most AUTO_PACE_WAIT_S; and while an
env_info that came waits for the graph to vouch for its sender (env_info.py: on a loaded machine the
env's node shows on the graph seconds after its message), for at most AUTO_PACE_JUDGED_S. (Three
robots' nodes started at once on 2 cores: one learner's env_info was held 2 s, dropped, and heard
again 5 s on; at 3 s it acted, and its first request was counted unavailable, nothing asked.)

The expert. Nodes started together find each other over some seconds (the middleware's
discovery, then the expert's own wait for env_info: it serves 'advise' only once it knows the
env). A lock-step env runs as fast as the learner acts, so the advising budget's first episodes
could all go by meanwhile, every request failed as unavailable (a loaded 2-core machine once spent
all 10 of them so). So while advice is open and asks for one answer, the first observation also
waits for the 'advise' service, for at most the node's expert_wait_s (0: not at all).

Either wait ends early when its reason goes, and then the node acts on what it held, at once. A
lock-step env waits for the action meanwhile. A real-time one goes on: the observations it sends
meanwhile are held in order too (up to HELD_MAX) and acted on in order, as by a learner that fell
behind, so that the episode is seen whole. (Holding only the latest made the learner join its first
episode at step 1, marked interrupted, whenever a step came before env_info: test_realtime_rate
failed so.)
"""

from __future__ import annotations

import time
from collections import deque
from typing import Callable

from rclpy.node import Node

# How long the first observation waits for the env's env_info before the node acts without it
# (its gates then ask nothing until env_info comes: acting_node.py says so in a warning).
AUTO_PACE_WAIT_S = 3.0
AUTO_PACE_JUDGED_S = 10.0  # ... and while an env_info that came is being judged (env_info.HOLD_S)
# Most observations held meanwhile (a real-time env at up to 100 Hz for the longest wait); past it the
# oldest go, and the learner joins that episode where the held ones start (marked interrupted).
HELD_MAX = 1024
POLL_S = 0.05  # how often a wait looks whether its reason has gone (the service shows no event)


class StartWait:
    """``protocol()``: how a request would ask now ('answer', 'wheel'), '' while the env's pace is
    unknown, None when nothing would be asked (advice off or closed); ``pace_judged()``: an env_info
    came and waits for the graph to vouch for its sender (EnvInfoWatcher.judging); ``advice``: the
    node's AdviceClient (``ready()``: a server of 'advise' is there; ``serving()``: the nodes, while
    two serve); ``expert_wait_s()``: the node's parameter; ``act(data)``: act on a held observation
    (the node's own observation callback, told the message was seen already).
    The caller holds its lock around ``hold``; ``release`` and the timer take ``lock``."""

    def __init__(
        self, node: Node, protocol, pace_judged, advice, expert_wait_s, act: Callable[[bytes], None], clock, lock
    ):
        self._node, self._protocol, self._pace_judged, self._advice = node, protocol, pace_judged, advice
        self._expert_wait_s, self._act, self._clock, self._lock = expert_wait_s, act, clock, lock
        self.held: deque[bytes] = deque(maxlen=HELD_MAX)  # in the order they came
        self.state = 'not yet'  # 'not yet', 'waiting' (a timer polls), 'over'
        self.superseded = 0  # observations held, then let go for later ones (past HELD_MAX)
        self.waited_for = ''  # what the first observation waited for ('' when it did not wait)
        self.waited_s = 0.0  # how long it waited, once the wait is over
        self._judged_said = False  # the line that the wait goes on for a judged env_info is said once
        self._since = 0.0
        self._timer = None

    def reason(self) -> str:
        """What the first observation waits for now: 'pace', 'expert' or '' (nothing)."""
        protocol = self._protocol()
        waited = time.monotonic() - self._since if self.state == 'waiting' else 0.0
        if protocol == '' and (waited < AUTO_PACE_WAIT_S or (waited < AUTO_PACE_JUDGED_S and self._pace_judged())):
            return 'pace'
        if protocol == 'answer' and waited < self._expert_wait_s() and not self._advice.ready():
            return 'expert'
        return ''

    def hold(self, data: bytes) -> bool:
        """True when ``data`` is held (a reason to wait is there and its wait has not run out)."""
        if self.state == 'over':
            return False  # release (under the same lock) has acted on every one held before this
        if self.state == 'not yet':
            reason = self.reason()
            if not reason:
                self.state = 'over'
                return False
            self.state, self._since, self.waited_for = 'waiting', time.monotonic(), reason
            self._timer = self._node.create_timer(POLL_S, self._poll, clock=self._clock)
            self._say(reason)
        self.superseded += len(self.held) == HELD_MAX
        self.held.append(data)
        return True

    def _say(self, reason: str) -> None:
        if reason == 'pace':
            self._node.get_logger().info(
                f"advice_protocol auto: waiting up to {AUTO_PACE_WAIT_S:g} s for the env's env_info "
                '(real time: the wheel; lock-step: one answer) before acting'
            )
        else:
            self._node.get_logger().info(
                f"waiting up to {self._expert_wait_s():g} s for an expert to serve 'advise' before acting "
                '(expert_wait_s)'
            )

    def _say_end(self) -> None:
        waited = self.waited_s = time.monotonic() - self._since
        if self._protocol() == 'answer' and self._expert_wait_s() > 0:
            serving = self._advice.serving() if self._advice.ready() else []
            if serving:  # no answer is taken until one serves (advice_client.py): said at once
                self._node.get_logger().warning(
                    f"{len(serving)} nodes serve 'advise' ({', '.join(serving)}) ({waited:.1f} s): acting, and "
                    'taking no answer until one node serves it'
                )
                return
            if self._advice.ready():
                line = f"an expert serves 'advise' ({waited:.1f} s): acting"
            else:
                line = (
                    f"no expert serves 'advise' after {waited:.1f} s: acting alone (until one comes, "
                    'a request the gates make fails as unavailable)'
                )
            self._node.get_logger().info(line)

    def _poll(self) -> None:
        with self._lock:
            if self.state != 'waiting':
                return
            reason = self.reason()
            if reason:
                if reason != self.waited_for:  # the pace came: now the expert
                    self.waited_for = reason
                    self._say(reason)
                elif reason == 'pace' and not self._judged_said and time.monotonic() - self._since >= AUTO_PACE_WAIT_S:
                    self._judged_said = True
                    self._node.get_logger().info(
                        'advice_protocol auto: an env_info came and waits for the graph to show its sender (the '
                        f"env's node, seconds late on a loaded machine): waiting on, up to {AUTO_PACE_JUDGED_S:g} s"
                    )
                return
            self.state = 'over'
            self._say_end()
        self.release()

    def release(self) -> None:
        """The reason went (env_info came, an expert serves) or the wait ran out: act on the
        observations held, in order, at once. Under the node's lock (reentrant): no later
        observation goes before them."""
        with self._lock:
            if self.state == 'not yet':
                return  # nothing held: the first observation decides whether to wait
            if self.state == 'waiting':
                if self.reason():
                    return  # env_info came, and now the expert is waited for
                self.state = 'over'
                self._say_end()
            if self._timer is not None:
                self._timer.cancel()  # once is enough
            while self.held:
                self._act(self.held.popleft())

    def say_unasked(self, protocol: str, env_info_topic: str, person_topic: str, advise_served: bool) -> None:
        """The gates fired and nobody could be asked, in a warning at most every 5 s: the pace is
        still unknown (protocol '': the wait ran out) or no person can take the wheel. (No node serving
        'advise' for one answer is said by the episode's line: 'failed 1 (unavailable)'.)"""
        if protocol == 'wheel':
            advise = (
                "; a node serves 'advise': set advice_protocol answer to ask it for one answer instead"
                if advise_served
                else ''
            )
            self._node.get_logger().warn(
                f"the gates fired, and nobody can take the wheel: the graph shows no node publishing '{person_topic}' "
                "(the person's teleop_expert; at a start, nodes launched together find each other over seconds), "
                f"so nothing was asked (counted as unavailable, no person's seconds){advise}",
                throttle_duration_sec=5.0,
            )
        elif not protocol:
            self._node.get_logger().warn(
                f"advice_protocol auto: no env_info from the env on '{env_info_topic}' in {self.waited_s:.1f} s, "
                'so whether it runs in real time (the wheel) or lock-step (one answer) is not known; the gates '
                'fired, nothing was asked and the learner acts on its own (counted as unavailable; set '
                'advice_protocol answer or wheel for an env that publishes no env_info)',
                throttle_duration_sec=5.0,
            )
