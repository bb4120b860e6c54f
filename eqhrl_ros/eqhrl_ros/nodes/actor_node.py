"""actor: acts on the env node's observations with the latest weights; a trainer learns.

It holds the policy and the twin critics, evaluates D(s), E(s) and the gates, asks the
`advise` service as the learner node does (nodes/acting_node.py), and publishes each action at
the env's pace: no gradient update ever runs in its callbacks. Every transition, with its
advised flag, goes to the trainer on /transitions in batches with sequence numbers; new
weights from /weights are applied between two steps (callbacks share one lock).

With no trainer listening (not started yet, restarting, gone), it goes on acting with the
weights it has and keeps its transitions, up to outbox_limit, for when a trainer appears.

A lock-step simulator steps as soon as the actor answers, so actors can run far ahead of a
trainer on the same cores (docs/performance.md). weights_wait_steps bounds that: after so
many steps on the same weights, the actor holds its answer until newer weights arrive (or
until no trainer listens any more). It does so only once the trainer updates (weights of a
version above 0).
"""

from __future__ import annotations

import os
import socket
import time
from collections import deque
from typing import Optional

import numpy as np
from rclpy.time import Time

from eqhrl_interfaces.msg import PolicyWeights, TransitionAck, TransitionBatch

from ..core.algorithm.learner import EpisodeSummary, EQSACLearner
from ..core.data.transitions import ACK_WAIT_S, MAX_MISSING, Outbox
from ..core.data.weights import TrainerPin, WeightsError, apply_weights
from ..core.envs.spec import EnvSpec
from ..parameters import ACTOR_NODE_PARAMS
from . import trainer_msgs
from .acting_node import ActingNode
from .health import OK, WARN, Check
from .spinning import run_node

# After a silence, acknowledgements ask for nothing again for this long (see _on_ack).
REJOIN_GRACE_S = 1.0


class ActorNode(ActingNode):
    def __init__(self, **kwargs):
        self.outbox: Optional[Outbox] = None
        self.weights_applied = 0
        self.weights_refused = 0
        self.weights_version: Optional[int] = None
        self.trainer_id = ''
        self.weights_latencies: deque = deque(maxlen=100_000)  # seconds, published to applied
        self.sent_batches = 0
        self.sent_transitions = 0
        self._waiting_weights: Optional[PolicyWeights] = None  # arrived before the spaces were known
        self._other_trainer: Optional[PolicyWeights] = None  # another trainer's, held until it publishes alone
        self._trainer_away_since: Optional[float] = None
        self._steps_on_weights = 0  # steps acted since the weights in use arrived
        self._deferred: Optional[tuple] = None  # (obs, key) held until newer weights arrive
        self.weights_waits = 0
        self.run_ended = False  # the trainer followed said its run has ended (its max_episodes)
        # This process's run: a restarted actor numbers its batches from 0 again, under a new run.
        self.actor_run = f'{socket.gethostname()}:{os.getpid()}:{time.time_ns() % 10**12}'
        super().__init__('actor', ACTOR_NODE_PARAMS, **kwargs)
        self.pin = TrainerPin(self.params['trainer_id'])
        # self.signer (key_file's, or None) is the acting node's: it signs the batches too.
        self.actor_name = self.params['actor_name'] or self.get_fully_qualified_name()
        self.transitions_pub = self.create_publisher(
            TransitionBatch, trainer_msgs.TRANSITIONS_TOPIC, trainer_msgs.TRANSITIONS_QOS
        )
        # The trainer's acknowledgements: batches are kept until its checkpoint holds them.
        acks = self.create_subscription(
            TransitionAck,
            trainer_msgs.ack_topic(self.transitions_pub.topic_name),
            self._on_ack,
            trainer_msgs.ACK_QOS,
        )
        self.ack_topic = acks.topic_name
        self.acks = 0
        self.acks_refused = 0
        self._last_ack = time.monotonic()
        self._last_probe = 0.0
        self._resend_from = 0.0  # time.monotonic() before which acknowledgements send nothing again
        self._ack_after_grace: Optional[tuple] = None  # the last acknowledgement, not answered yet
        # Batches sent per flush tick: those sealed since the last tick and SEND_AT_ONCE more. A
        # burst of hundreds (a backlog, or one acknowledgement naming 256 missing) would overflow
        # the trainer's reader history, lose most of them and make another round.
        self._send_budget = trainer_msgs.SEND_AT_ONCE
        self._sealed_mark = 0  # outbox.next_sequence at the last tick
        weights = self.create_subscription(
            PolicyWeights, trainer_msgs.WEIGHTS_TOPIC, self._on_weights, trainer_msgs.WEIGHTS_QOS
        )
        self.weights_topic = weights.topic_name  # after remapping
        self.add_post_set_parameters_callback(self._follow_named_trainer)
        period = min(self.params['flush_period_s'] / 2, 0.1)
        self.create_timer(period, self._flush_if_due, clock=self._steady)

    def _prepare(self, learner: EQSACLearner, spec: EnvSpec) -> None:
        p = self.params
        self.outbox = Outbox(
            p['actor_name'] or self.get_fully_qualified_name(),
            learner.observation.state_dim,
            learner.action_dim,
            min(p['batch_transitions'], p['outbox_limit']),
            p['outbox_limit'],
            run=self.actor_run,
        )

    def _describe(self) -> str:
        return f', transitions to {trainer_msgs.TRANSITIONS_TOPIC}, weights from {trainer_msgs.WEIGHTS_TOPIC}'

    # ------------------------------------------------------------------ acting, paced by the weights

    def _act(self, obs, key) -> None:
        limit = self.params['weights_wait_steps']
        # Only once the trainer updates (weights of version > 0): before learning_starts, no new
        # weights come, and waiting for them would stop the transitions the trainer waits for.
        learning = bool(self.weights_version) and self.transitions_pub.get_subscription_count() > 0
        if limit and learning and self._steps_on_weights >= limit:
            # The env waits for our answer (lock-step); we wait for the trainer's next weights.
            # No previous action to re-send meanwhile: a re-sent observation gets nothing.
            self.tracking.state, self.tracking.key, self._last_action = obs, key, None
            self._deferred = (obs, key)
            self.weights_waits += 1
            return
        self._steps_on_weights += 1
        super()._act(obs, key)

    def _act_on_deferred(self) -> None:
        if self._deferred is not None:
            obs, key = self._deferred
            self._deferred = None
            self._act(obs, key)

    # ------------------------------------------------------------------ transitions out

    def _transition(self, obs, action, reward, next_obs, terminated, truncated, advised, success, source):
        learner = self.learner
        summary = learner.step(obs, action, reward, next_obs, terminated, truncated, advised, success, learn=False)
        observation = learner.observation  # a camera's: the state vectors, and the frames apart
        frames = None if observation.camera is None else (obs['pixels'], next_obs['pixels'][-1])
        self.outbox.add(
            observation.state(obs),
            learner.normalize(action),
            reward,
            observation.state(next_obs),
            terminated,
            advised,
            source,
            frames,
        )
        self._send()
        return summary

    def _episode_done(self, summary: EpisodeSummary) -> None:
        self.outbox.end_episode(summary)
        self._send()

    def _flush_if_due(self) -> None:
        with self._lock:
            if self.outbox is None or self.run_ended:
                return
            if self.outbox.age() >= self.params['flush_period_s']:
                self.outbox.seal()
            self._resend_if_unanswered()
            if self._ack_after_grace is not None and time.monotonic() >= self._resend_from:
                ack, self._ack_after_grace = self._ack_after_grace, None
                self.outbox.acknowledge(*ack)
            sealed, self._sealed_mark = self.outbox.next_sequence - self._sealed_mark, self.outbox.next_sequence
            self._send_budget = trainer_msgs.SEND_AT_ONCE + sealed
            self._send()
            if self._deferred is not None and self.transitions_pub.get_subscription_count() == 0:
                self._act_on_deferred()  # the trainer went away: act with the weights we have
            if self._other_trainer is not None and self.learner is not None and self._weights_publishers() <= 1:
                msg, self._other_trainer = self._other_trainer, None
                self._apply(msg)  # the trainer followed has left: the one that replaced it is alone

    def _send(self) -> None:
        """Publish what is due (batches the trainer lacks, then sealed ones) while a trainer
        listens, at most SEND_AT_ONCE per flush tick; otherwise keep them (bounded)."""
        outbox = self.outbox
        if not outbox.pending:
            return
        if self.transitions_pub.get_subscription_count() == 0:
            if self._trainer_away_since is None:
                self._trainer_away_since = time.monotonic()
                self.get_logger().warn(
                    f'no trainer on {self.transitions_pub.topic_name}: acting with the weights I have, '
                    f'keeping up to {self.params["outbox_limit"]} transitions'
                )
            return
        if self._trainer_away_since is not None:
            self.get_logger().info(
                f'a trainer listens on {self.transitions_pub.topic_name} after '
                f'{time.monotonic() - self._trainer_away_since:.1f} s: sending {outbox.unsent} transitions'
                f'{"; %d dropped meanwhile" % outbox.dropped_transitions if outbox.dropped_transitions else ""}'
            )
            self._trainer_away_since = None
        while self._send_budget > 0:
            batch = outbox.pop_oldest()
            if batch is None:
                break
            self._send_budget -= 1
            msg = trainer_msgs.batch_msg(batch, self.learner.scaler.low, self.learner.scaler.high)
            self.transitions_pub.publish(trainer_msgs.sign_batch(msg, self.signer))
            self.sent_batches += 1
            self.sent_transitions += len(batch)

    def _resend_if_unanswered(self) -> None:
        """Batches sent that the trainer has not stored, and no word from it for ACK_WAIT_S: the
        last ones went into a cut link (or its acknowledgements did), and no later batch came to
        show the gap. Send the oldest of them again, once per ACK_WAIT_S: its acknowledgement
        says what else is missing."""
        outbox, now = self.outbox, time.monotonic()
        if now - self._last_ack < ACK_WAIT_S or now - self._last_probe < ACK_WAIT_S:
            return
        if self.transitions_pub.get_subscription_count() == 0:
            return
        if outbox.probe(now):
            self._last_probe = now
            self.get_logger().info(
                f'no acknowledgement for {ACK_WAIT_S:g} s: sending batch {outbox.received_through + 1} again',
                throttle_duration_sec=5.0,
            )

    def _on_ack(self, msg: TransitionAck) -> None:
        """The followed trainer's acknowledgement of this run's batches: let go of what its checkpoint
        holds; send again what it lacks (each batch at most once per RESEND_AFTER_S: every
        acknowledgement until it arrives names it)."""
        with self._lock:
            if self.outbox is None or msg.actor != self.actor_name or msg.actor_run != self.actor_run:
                return
            refusal = trainer_msgs.signature_refusal(msg, self.signer)
            if refusal or msg.trainer_id != self.trainer_id or not self.trainer_id:
                self.acks_refused += 1  # a stranger's (or a trainer's not followed) would make us drop batches
                if refusal:
                    self.get_logger().warn(f'acknowledgement refused: {refusal}', throttle_duration_sec=5.0)
                return
            self.acks += 1
            if msg.run_ended:
                # It stops the acting: unsigned, taken only while one node (the trainer) publishes
                # acknowledgements, never from a stranger who copied the trainer's id beside it.
                publishers = self.count_publishers(self.ack_topic)
                if self.signer is None and publishers > 1:
                    self.get_logger().warn(
                        f'an acknowledgement ending the run while {publishers} nodes publish {self.ack_topic}: '
                        'not taken (only the trainer alone ends it)',
                        throttle_duration_sec=5.0,
                    )
                    return
                self._end_run(msg)
                return
            through, now = int(msg.received_through), time.monotonic()
            if now - self._last_ack > ACK_WAIT_S:
                # The first word after a silence (a cut link back): DDS is still delivering what it
                # kept of the batches sent meanwhile. Sending those again now would duplicate them.
                self._resend_from = now + REJOIN_GRACE_S
            self._last_ack = now
            missing = [int(s) for s in msg.missing[:MAX_MISSING]]
            ack = (through, int(msg.saved_through), missing, int(msg.highest_received))
            resend = now >= self._resend_from
            self._ack_after_grace = None if resend else ack  # the flush timer answers it once the grace ends
            again = self.outbox.acknowledge(*ack, resend=resend)
            if again:
                self.get_logger().info(
                    f'the trainer lacks {again} batch(es) after {through}: sending them again',
                    throttle_duration_sec=5.0,
                )
            self._send()

    def _end_run(self, msg: TransitionAck) -> None:
        """The trainer's run has ended: act no more (as a learner at max_episodes) and send
        nothing more; what it did not store was made after the run, not lost."""
        if self.run_ended:
            return
        self.run_ended = self.done = True
        self._deferred = None
        if msg.received_through >= 0:  # let go of what its last checkpoint holds
            self.outbox.acknowledge(int(msg.received_through), int(msg.saved_through), resend=False)
        self.get_logger().info(
            f"trainer '{msg.trainer_id}' has ended its run (max_episodes): acting stopped; "
            f'{self.outbox.unsent} transitions made after its end are not sent'
        )

    # ------------------------------------------------------------------ weights in

    def _on_weights(self, msg: PolicyWeights) -> None:
        with self._lock:
            if self.learner is None:
                self._waiting_weights = msg
                return
            self._apply(msg)

    def _configure(self, spec) -> None:
        super()._configure(spec)
        with self._lock:
            if self._waiting_weights is not None:
                msg, self._waiting_weights = self._waiting_weights, None
                self._apply(msg)

    def _weights_publishers(self) -> int:
        return self.count_publishers(self.weights_topic)

    def _apply(self, msg: PolicyWeights) -> None:
        """Between two steps (under the node's lock): the networks whole, or not at all, and only
        from the trainer this actor follows (core.data.weights.TrainerPin)."""
        new_trainer = msg.trainer_id != self.trainer_id
        unsigned = trainer_msgs.signature_refusal(msg, self.signer)
        if unsigned:
            self.weights_refused += 1
            self.get_logger().warn(f'weights v{msg.version} refused: {unsigned}', throttle_duration_sec=5.0)
            return
        # A trainer that signs with this deployment's key is trusted beside another: it holds the key.
        alone = self.signer is not None or self._weights_publishers() <= 1
        verdict = self.pin.judge(msg.trainer_id, int(msg.version), int(msg.episodes), self.learner.episode, alone)
        if verdict == 'stale':
            return  # older than what we act with
        if verdict != 'apply':
            self.weights_refused += 1
            if 'still publishes' in verdict:
                self._other_trainer = msg  # taken if the one followed leaves and this one stays alone
            shown = ''.join(
                c if c.isprintable() and c.isascii() else '?' for c in verdict[:300]
            )  # ids are a sender's text
            self.get_logger().warn(f'weights v{msg.version} refused: {shown}', throttle_duration_sec=5.0)
            return
        try:
            apply_weights(self.learner, msg.tensors.tobytes() if hasattr(msg.tensors, 'tobytes') else msg.tensors)
        except WeightsError as error:
            self.weights_refused += 1
            self.get_logger().error(f'weights v{msg.version} refused: {error}', throttle_duration_sec=5.0)
            return
        if new_trainer:
            self.get_logger().info(f"weights from trainer '{msg.trainer_id}' (v{msg.version})")
            if self.outbox is not None and self.outbox.unacked:
                # Another trainer (a restart): the oldest batch kept goes to it at once, and its
                # acknowledgement says what of the rest it lacks (a resumed one has its checkpoint's).
                self.outbox.new_trainer()
                self._last_ack = self._last_probe = 0.0
                self.get_logger().info(f'{self.outbox.unsent} transitions kept for the new trainer')
        self.trainer_id, self.weights_version = msg.trainer_id, int(msg.version)
        self.pin.applied(msg.trainer_id, msg.version)
        self.weights_applied += 1
        published = Time.from_msg(msg.stamp, clock_type=self.get_clock().clock_type)
        self.weights_latencies.append((self.get_clock().now() - published).nanoseconds / 1e9)
        # Eq. 7's budget counts episodes over all actors: the trainer's count, or ours if larger.
        self.learner.tally.episode = max(self.learner.episode, int(msg.episodes))
        self._steps_on_weights = 0
        self._act_on_deferred()

    def health_checks(self) -> list:
        checks = super().health_checks()
        outbox = self.outbox
        values = {
            'weights version': self.weights_version if self.weights_version is not None else '-',
            'weights applied': self.weights_applied,
            'weights refused': self.weights_refused,
            'transitions kept (until the trainer saves them)': outbox.waiting if outbox else 0,
            'transitions the trainer lacks': outbox.unsent if outbox else 0,
            'transitions dropped': outbox.dropped_transitions if outbox else 0,
        }
        if self.run_ended:
            checks.append(
                Check('trainer', OK, f"trainer '{self.trainer_id}' has ended its run: acting stopped", values)
            )
        elif self.transitions_pub.get_subscription_count() == 0:
            checks.append(Check('trainer', WARN, 'no trainer listens: acting with the weights it has', values))
        elif self.weights_version is None:
            checks.append(Check('trainer', WARN, 'a trainer listens, no weights yet', values))
        else:
            checks.append(Check('trainer', OK, f"following trainer '{self.trainer_id}'", values))
        return checks

    def _follow_named_trainer(self, changes) -> None:
        for change in changes:
            if change.name == 'trainer_id':
                with self._lock:
                    self.pin.name(str(change.value))
                    self.get_logger().info(
                        f"following trainer '{change.value}'" if change.value else 'following the next trainer alone'
                    )

    # ------------------------------------------------------------------ exit

    def report(self) -> str:
        """One line: what went out, what was dropped, the weights and how long they took."""
        latency = ''
        if self.weights_latencies:
            ms = np.asarray(self.weights_latencies) * 1000.0
            latency = f' (latency p50 {np.percentile(ms, 50):.1f} ms, p99 {np.percentile(ms, 99):.1f} ms)'
        outbox = self.outbox
        dropped = outbox.dropped_transitions if outbox else 0
        unsent = outbox.unsent if outbox else 0
        resent = outbox.resent_batches if outbox else 0
        steps = self.learner.total_steps if self.learner else 0
        if self.run_ended:  # the trainer's run ended first: what it lacks was made after the run
            left = f"{unsent} made after the trainer's run ended (not sent)"
        else:
            left = f'{unsent} not stored by the trainer{" (lost)" if unsent and self.done else ""}'
        return (
            f'{steps} steps; sent {self.sent_batches} batches ({self.sent_transitions} transitions, '
            f'{resent} batches again), {left}, {dropped} dropped; '
            f'weights applied {self.weights_applied}{latency}, '
            f'refused {self.weights_refused}; waited for weights {self.weights_waits} times'
        )


def _flush_and_report(node: ActorNode) -> None:
    """At exit: act no more, send what is left (a last partial batch included) and wait up to
    exit_wait_s for the trainer to store it all, answering its acknowledgements; then say what
    it still lacks."""
    from rclpy.executors import SingleThreadedExecutor

    try:
        with node._lock:
            node.done = True  # no more steps: the env's next observations are not acted on
            if node.outbox is not None and not node.run_ended:
                node.outbox.seal()
                node._send()
        if node.outbox is not None and not node.run_ended and node.params['exit_wait_s'] > 0:
            executor = SingleThreadedExecutor(context=node.context)
            executor.add_node(node)  # acknowledgements in, batches the trainer lacks out
            deadline = time.monotonic() + node.params['exit_wait_s']
            try:
                while time.monotonic() < deadline and node.context.ok():
                    with node._lock:
                        if node.outbox.unsent == 0 or node.transitions_pub.get_subscription_count() == 0:
                            break
                        node._resend_if_unanswered()
                        node._send()
                    executor.spin_once(timeout_sec=0.05)
            finally:
                executor.remove_node(node)
                executor.shutdown(timeout_sec=0)
    except Exception as error:  # the middleware may already be going down (a second Ctrl-C)
        node.get_logger().warn(f'could not send the last transitions: {error}')
    unsent = node.outbox.unsent if node.outbox is not None and not node.run_ended else 0
    log = node.get_logger().error if unsent else node.get_logger().info
    log(f'actor {node.actor_name}: {node.report()}')


def main(args=None):
    run_node(ActorNode, args, on_exit=_flush_and_report, name='actor')


if __name__ == '__main__':
    main()
