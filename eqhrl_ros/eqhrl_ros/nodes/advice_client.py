"""The acting node's side of the advise service: one request at a time, never waited for.

The request goes out with ``call_async``; whichever comes first, the response (a done-callback)
or a one-shot timeout timer on the steady clock, ends it and calls ``on_end(pending, advice,
failure)`` (under the node's lock). So a slow or absent expert cannot wedge the env, the
statistics or shutdown, under a single-threaded executor or a multi-threaded one. (A synchronous
``call`` inside a subscription callback deadlocks a single-threaded executor.)
"""

from __future__ import annotations

import time
from collections import Counter, deque
from dataclasses import dataclass
from typing import Callable, Optional

from eqhrl_interfaces.srv import Advise

from ..core.algorithm.advice_outcomes import Resolution
from ..core.algorithm.learner import Proposal
from ..core.data.advice import ACTION_FAULTS, Advice, refused_action_words
from ..core.data.signing import Signer
from . import advise_msgs
from .graph_trust import UNKNOWN_NODE, servers
from .messages import EXPERT_NAMES_KEPT, printable_name
from .recording import introspect


def say_unused_answer(logger, resolution: Resolution, advice: Optional[Advice], scaler) -> None:
    """Say why an answer came and was not used: a decline's reason (a person's "why not" is worth
    seeing; a declining controller says why too), or what was wrong with an action that the
    learner refused, so that whoever wrote the expert can fix it (the episode's line counts them)."""
    if resolution.outcome == 'declined' and resolution.detail:
        logger.info(f'advice declined: {printable_name(resolution.detail)}', throttle_duration_sec=2.0)
    elif resolution.outcome == 'failed' and resolution.detail in ACTION_FAULTS and advice is not None:
        words = refused_action_words(advice.action, scaler.low, scaler.high)
        if words:
            logger.warn(
                f"advice from '{advice.expert_name}' refused ({resolution.detail}): its action {words}; "
                'the learner took its own action',
                throttle_duration_sec=5.0,
            )


@dataclass
class PendingAdvice:
    token: int
    proposal: Proposal
    key: tuple  # (env episode, env step) the advice is for
    timer: object
    sent: float = 0.0  # time.monotonic() when the request went out
    deadline: float = 0.0  # time.monotonic() when it times out (moved on by a STOP's pause)
    paused_at: Optional[float] = None  # a STOP holds it (and its timeout) since then
    request: Optional[Advise.Request] = None  # as sent (its counter and signature: the answer's must match)


class AdviceClient:
    """Asks the 'advise' service; ``on_end`` gets each request's end (answer, timeout or error)."""

    def __init__(self, node, params: dict, lock, clock, on_end: Callable, signer: Optional[Signer] = None):
        self.node = node
        self.params = params  # the node's live parameters: advice_timeout_s, accept_expert
        # With key_file's signer, requests are signed and only answers signed for them are taken.
        self.seal = advise_msgs.request_seal(signer)
        self.lock = lock
        self.clock = clock
        self.on_end = on_end
        self.client = node.create_client(Advise, 'advise')
        introspect(self.client, node)  # every call on advise/_service_event (ros2 bag, the record)
        self.pending: Optional[PendingAdvice] = None
        self._token = 0
        self.latencies: deque = deque(maxlen=100_000)  # seconds, request to answer
        self.experts_heard: Counter = Counter()  # expert_name -> advice answers this episode

    @property
    def service_name(self) -> str:
        return self.client.srv_name

    def ready(self) -> bool:
        return self.client.service_is_ready()

    def servers(self) -> int:
        return self.node.count_services(self.client.srv_name)

    def ask(self, proposal: Proposal, key: tuple, timeout: Optional[float] = None) -> None:
        """Send the proposal's request, waiting ``timeout`` seconds (default advice_timeout_s);
        its end comes to on_end."""
        self._token += 1
        token = self._token
        timeout = self.params['advice_timeout_s'] if timeout is None else timeout
        request = advise_msgs.sign_request(advise_msgs.request_msg(proposal.request, timeout), self.seal)
        timer = self.node.create_timer(timeout, lambda: self._on_timeout(token), clock=self.clock)
        now = time.monotonic()
        self.pending = PendingAdvice(token, proposal, key, timer, now, now + timeout, request=request)
        future = self.client.call_async(request)
        future.add_done_callback(lambda f: self._on_response(token, f))

    def serving(self) -> list:
        """The nodes serving 'advise' while more than one does, else []. Each gets every request,
        and rclpy keeps the first answer without saying whose it is: while a second node serves,
        no unsigned answer can be told from a stranger's (graph_trust's rule for topics); with
        key_file, the signature tells, so [] always. A restarted expert's old endpoints carry its own
        name and count once."""
        if self.seal is not None or self.servers() <= 1:
            return []
        names = servers(self.node, self.node.resolve_service_name(self.client.srv_name)) - {UNKNOWN_NODE}
        return sorted(names) if len(names) > 1 else []

    def pause(self) -> Optional[float]:
        """A STOP: the open request's timeout holds; returns the seconds it has left (None: none open)."""
        pending = self.pending
        if pending is None or pending.paused_at is not None:
            return None
        pending.paused_at = time.monotonic()
        self.node.destroy_timer(pending.timer)
        return max(0.0, pending.deadline - pending.paused_at)

    def resume(self) -> Optional[float]:
        """The STOP released: the timeout goes on with what it had left, which is returned."""
        pending = self.pending
        if pending is None or pending.paused_at is None:
            return None
        now = time.monotonic()
        pending.deadline += now - pending.paused_at
        pending.paused_at = None
        left = max(1e-3, pending.deadline - now)
        token = pending.token
        pending.timer = self.node.create_timer(left, lambda: self._on_timeout(token), clock=self.clock)
        return left

    def take_pending(self, token: Optional[int] = None) -> Optional[PendingAdvice]:
        """The open request, ended here (its timer gone); None when ``token`` is not the open one
        (already ended: a late answer after the timeout, or the reverse)."""
        pending = self.pending
        if pending is None or (token is not None and pending.token != token):
            return None
        self.pending = None
        if pending.paused_at is None:
            self.node.destroy_timer(pending.timer)
        return pending

    def _on_timeout(self, token: int) -> None:
        with self.lock:
            # One-shot: a timer that fired is gone; a STOP's pause destroyed it, a resume made a new one.
            if self.pending is not None and self.pending.token == token and self.pending.paused_at is not None:
                return
            pending = self.take_pending(token)
            if pending is not None:
                self.on_end(pending, failure='timeout')

    def _on_response(self, token: int, future) -> None:
        with self.lock:
            pending = self.take_pending(token)
            if pending is None:
                return
            self.latencies.append(time.monotonic() - pending.sent)
            try:
                response = future.result()
            except Exception as error:
                self.node.get_logger().warn(f'advice call failed: {error!r}', throttle_duration_sec=5.0)
                self.on_end(pending, failure='error')
                return
            try:
                advice, failure = self._judged(response, pending)
            except Exception as error:  # another node's answer must not leave the request open for ever
                self.node.get_logger().error(f'an answer could not be read: {error!r}', throttle_duration_sec=5.0)
                advice, failure = None, 'error'
            self.on_end(pending, advice, failure)

    def _judged(self, response: Advise.Response, pending: PendingAdvice) -> tuple[Optional[Advice], str]:
        """(the advice, '') when the answer is taken, else (None, why not: 'untrusted'), each said."""
        name = printable_name(response.expert_name)
        if name in self.experts_heard or len(self.experts_heard) < EXPERT_NAMES_KEPT:
            self.experts_heard[name] += 1
        else:
            self.experts_heard['(others)'] += 1
        accept, serving, logger = self.params['accept_expert'], self.serving(), self.node.get_logger()
        unsigned = advise_msgs.answer_refusal(response, pending.request, self.seal)
        if unsigned:
            logger.warn(f"ignored advice from '{name}': {unsigned}", throttle_duration_sec=5.0)
        elif serving:
            service = self.node.resolve_service_name(self.client.srv_name)
            logger.warn(
                f"ignored advice: {len(serving)} nodes serve '{service}' ({', '.join(serving)}), so an answer "
                "cannot be told from a stranger's; none is taken until one node serves it",
                throttle_duration_sec=5.0,
            )
        elif accept and response.expert_name != accept:
            logger.warn(f"ignored advice from '{name}' (accept_expert is '{accept}')", throttle_duration_sec=5.0)
        else:
            return self._person_time_checked(advise_msgs.advice_from_response(response, name), pending), ''
        return None, 'untrusted'

    def _person_time_checked(self, advice: Advice, pending: PendingAdvice) -> Advice:
        waited = time.monotonic() - pending.sent
        checked, changed = advise_msgs.person_time_checked(advice, waited)
        if changed:
            self.node.get_logger().warn(
                f"'{advice.expert_name}' says a person took {advice.response_time_s} s on a request the learner "
                f'waited {waited:.3f} s on; counted as {waited:.3f} s (an expert measures inside that wait)',
                throttle_duration_sec=5.0,
            )
        return checked
