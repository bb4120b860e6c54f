"""learner: runs EQSACLearner on the env node's observations and asks the expert service.

Executor design: nothing in this node ever blocks waiting for another node. When
the gates fire, the advice request goes out with ``call_async``; whichever comes
first, the response (a done-callback) or a one-shot timeout timer, decides the
action. So a slow or absent expert cannot wedge the env, the statistics or
shutdown, under a single-threaded executor or a multi-threaded one. (A synchronous
``call`` inside a subscription callback deadlocks a single-threaded executor.)
"""

from __future__ import annotations

import csv
import threading
import time
from collections import Counter, deque
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import gymnasium as gym
import numpy as np
import torch
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float32MultiArray

from eqhrl_interfaces.srv import Advise

from ..core.checkpoint import export_policy, load_checkpoint, save_checkpoint
from ..core.envs import success_criterion
from ..core.experts import Advice
from ..core.learner import EpisodeSummary, EQSACLearner, LearnerConfig, Proposal
from . import messages
from .lifecycle import run_node
from .params import (LEARNER_CONFIG_PARAMS, LEARNER_NODE_PARAMS, choices_validator, declare,
                     reject_unknown_overrides)

QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
STATS_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
# The latest advice request stays available to a UI that starts later.
LATCHED_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)


@dataclass
class PendingAdvice:
    token: int
    proposal: Proposal
    key: tuple            # (env episode, env step) the advice is for
    timer: object
    sent: float = 0.0     # time.monotonic() when the request went out


def env_spaces(env_id: str) -> tuple[int, np.ndarray, np.ndarray]:
    """Observation size and action bounds of an env id, from its spec (no episode is run)."""
    env = gym.make(env_id)
    try:
        return (int(np.prod(env.observation_space.shape)),
                env.action_space.low.astype(np.float32), env.action_space.high.astype(np.float32))
    finally:
        env.close()


def rewrite_csv_before(path: Path, episode: int) -> None:
    """Keep only rows of episodes < ``episode`` (those a resumed learner will not redo)."""
    if not path.exists():
        return
    with path.open(newline='') as f:
        rows = list(csv.reader(f))
    if not rows:
        return
    header, body = rows[0], [r for r in rows[1:] if r and int(r[0]) < episode]
    tmp = path.with_suffix('.csv.tmp')
    with tmp.open('w', newline='') as f:
        csv.writer(f).writerows([header, *body])
    tmp.replace(path)


class LearnerNode(Node):
    def __init__(self, **kwargs):
        super().__init__('learner', **kwargs)
        reject_unknown_overrides(self, LEARNER_CONFIG_PARAMS, LEARNER_NODE_PARAMS)
        values = declare(self, LEARNER_CONFIG_PARAMS)
        self.params = declare(self, LEARNER_NODE_PARAMS)
        self.add_on_set_parameters_callback(choices_validator(LEARNER_CONFIG_PARAMS))
        self.add_on_set_parameters_callback(self._on_set_parameters)
        p = self.params
        if p['torch_threads'] > 0:
            torch.set_num_threads(p['torch_threads'])

        self.config = LearnerConfig.from_params(values)
        obs_dim, low, high = env_spaces(p['env_id'])
        self.learner = EQSACLearner(obs_dim, low, high, self.config, success_criterion(p['env_id']))
        self.output_dir = Path(p['output_dir'])
        self.output_dir.mkdir(parents=True, exist_ok=True)
        self.checkpoint_path = self.output_dir / 'checkpoint.pt'
        self.replay_path = self.output_dir / 'replay.pt' if p['save_replay'] else None
        self.csv_path = self.output_dir / 'episodes.csv'
        if p['resume']:
            # A bad checkpoint stops start-up with CheckpointError: silently starting
            # from scratch would overwrite the run the person asked to continue.
            load_checkpoint(self.learner, self.checkpoint_path, self.replay_path)
            self.get_logger().info(f'resumed from {self.checkpoint_path} at episode {self.learner.episode}')
            rewrite_csv_before(self.csv_path, self.learner.episode)
        elif self.csv_path.exists():
            self.csv_path.unlink()   # a fresh run starts a fresh record
        self._csv_file = self.csv_path.open('a', newline='')
        self._csv = csv.writer(self._csv_file)
        if self.csv_path.stat().st_size == 0:
            self._csv.writerow(EpisodeSummary.CSV_FIELDS)
            self._csv_file.flush()

        self.action_pub = self.create_publisher(Float32MultiArray, 'action', QOS)
        self._action_out = messages.action_out(self.learner.action_dim)   # rewritten per step
        self.stats_pub = self.create_publisher(Float32MultiArray, '~/episode_stats', STATS_QOS)
        self.gate_pub = self.create_publisher(Float32MultiArray, '~/gate_debug', QOS)
        self.request_pub = self.create_publisher(Float32MultiArray, '~/advice_request', LATCHED_QOS)
        # Observations arrive serialized (raw): see messages.SerializedReader.
        self._observation_reader = messages.SerializedReader()
        self.create_subscription(Float32MultiArray, 'observation', self._on_observation, QOS, raw=True)
        self.advice_client = self.create_client(Advise, 'advise')

        self._lock = threading.RLock()       # callbacks may run on several threads
        self._state: Optional[np.ndarray] = None   # s_t the last action answered
        self._key: Optional[tuple] = None          # its (env episode, env step)
        self._last_action: Optional[np.ndarray] = None
        self._last_advised = False
        self._pending: Optional[PendingAdvice] = None
        self._token = 0
        self.dropped_messages = 0
        self.stalled_episodes = 0
        self.observation_gaps = 0        # an observation that skipped steps (a message was lost)
        self.repeated_observations = 0   # the env re-sent an observation (our action did not arrive in time)
        self.advice_latencies: deque = deque(maxlen=100_000)   # seconds, request to answer
        self.experts_heard: Counter = Counter()    # expert_name -> advice answers this episode
        self._last_observation_time = time.monotonic()
        self.create_timer(0.25, self._check_stall)
        self.done = False
        self.summaries: list[EpisodeSummary] = []
        self.get_logger().info(
            f"{self.config.mode} on {p['env_id']}: obs {obs_dim}, action {len(low)}, "
            f"budget {self.config.advising_budget} episodes, output {self.output_dir}")

    # ------------------------------------------------------------------ parameters at run time

    def _on_set_parameters(self, changes):
        from rcl_interfaces.msg import SetParametersResult
        for change in changes:
            if change.name == 'advising_budget':
                self.learner.gates.advising_budget = int(change.value)
                self.config.advising_budget = int(change.value)
            elif change.name in self.params:
                self.params[change.name] = change.value
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ observations

    def _on_observation(self, data: bytes) -> None:
        with self._lock:
            if self.done:
                return
            self._last_observation_time = time.monotonic()
            try:
                env_step = messages.parse_observation(self._observation_reader.values(data),
                                                      self.learner.obs_dim)
            except messages.MessageError as error:
                self.dropped_messages += 1
                self.get_logger().error(f'dropped observation: {error}',
                                        throttle_duration_sec=5.0)
                return
            key = (env_step.episode, env_step.step)
            if key == self._key:
                self.repeated_observations += 1
                # The env sent the same observation again: our action did not reach it.
                if self._pending is None and self._last_action is not None:
                    self._publish_action(self._last_action)
                return
            if self._pending is not None:
                self._observe_while_waiting(env_step, key)
                return

            if self._follows(key):
                if self._store(env_step):
                    return   # the episode ended; the env's reset message starts the next
            elif env_step.step > 0 and self._key is not None and self._state is not None:
                self.observation_gaps += 1
                self.get_logger().warn(f'observation {key} does not follow {self._key}; '
                                       'starting from it without a transition', throttle_duration_sec=5.0)
            elif env_step.step == 0 and self.learner.episode_step > 0:
                # The env started a new episode in the middle of ours (it restarted).
                self.get_logger().warn(f'env restarted; abandoning episode {self.learner.episode} '
                                       f'after {self.learner.episode_step} steps')
                self.learner.abandon_episode()
            if env_step.done:
                # A final observation with no predecessor we acted on: nothing to store or act on.
                self._key = key
                self._state = None
                return
            self._act(env_step.obs, key)

    def _follows(self, key: tuple) -> bool:
        return (key[1] > 0 and self._state is not None and self._key is not None
                and key == (self._key[0], self._key[1] + 1))

    def _observe_while_waiting(self, env_step: messages.EnvStep, key: tuple) -> None:
        """A real-time env keeps stepping with the held (previous) action while the person
        decides: those are real transitions, stored as such; the advice, when it comes,
        applies to the latest observation. (A lock-step env sends nothing meanwhile.)"""
        if not self._follows(key) or self._last_action is None:
            return
        if env_step.done:
            # The episode ends before the answer: the request counts as timed out in it.
            pending = self._take_pending(self._pending.token)
            self.learner.resolve_advice(pending.proposal, failure='timeout')
            self.request_pub.publish(messages.advice_request_msg(
                'failed', pending.proposal.request, self.params['advice_timeout_s']))
        self._last_advised = False
        if not self._store(env_step):
            self._state, self._key = env_step.obs, key

    def _store(self, env_step: messages.EnvStep) -> bool:
        """Store the transition the message completes; returns True when the episode ended."""
        try:
            summary = self.learner.step(self._state, self._last_action, env_step.reward, env_step.obs,
                                        env_step.terminated, env_step.truncated, self._last_advised)
        except ValueError as error:
            self.dropped_messages += 1
            self.get_logger().error(f'transition not stored: {error}', throttle_duration_sec=5.0)
            return False
        if summary is None:
            return False
        self._key = (env_step.episode, env_step.step)
        self._state = None
        self._on_episode_end(summary)
        return True

    # ------------------------------------------------------------------ acting and advice

    def _act(self, obs: np.ndarray, key: tuple) -> None:
        self._state, self._key = obs, key
        proposal = self.learner.propose(obs)
        if self.params['publish_gate_debug']:
            self.gate_pub.publish(messages.gate_msg(self.learner.episode, self.learner.episode_step,
                                                    proposal.decision))
        if not (proposal.decision.fire and self.params['advice_enabled']):
            self._finish_step(proposal.action, advised=False)
            return
        if not self.advice_client.service_is_ready():
            action, advised = self.learner.resolve_advice(proposal, failure='unavailable')
            self._finish_step(action, advised)
            return
        self._token += 1
        token = self._token
        request = self._request_msg(proposal)
        timer = self.create_timer(self.params['advice_timeout_s'], lambda: self._on_advice_timeout(token))
        self._pending = PendingAdvice(token, proposal, key, timer, time.monotonic())
        self.request_pub.publish(messages.advice_request_msg('pending', proposal.request,
                                                             self.params['advice_timeout_s']))
        future = self.advice_client.call_async(request)
        future.add_done_callback(lambda f: self._on_advice_response(token, f))

    @staticmethod
    def _request_msg(proposal: Proposal) -> Advise.Request:
        r = proposal.request
        return Advise.Request(
            observation=r.observation.tolist(), proposed_action=r.proposed_action.tolist(),
            action_low=r.action_low.tolist(), action_high=r.action_high.tolist(),
            discrepancy=float(r.discrepancy), entropy=float(r.entropy),
            episode=int(r.episode), step=int(r.step))

    def _take_pending(self, token: int) -> Optional[PendingAdvice]:
        pending = self._pending
        if pending is None or pending.token != token:
            return None   # already resolved (a late answer after the timeout, or the reverse)
        self._pending = None
        self.destroy_timer(pending.timer)
        return pending

    def _resolve(self, pending: PendingAdvice, advice: Optional[Advice] = None, failure: str = '') -> None:
        """Count the outcome, tell the person's UI, and act."""
        counts = self.learner.episode_advice
        given, declined = counts.given, counts.declined
        action, advised = self.learner.resolve_advice(pending.proposal, advice, failure)
        outcome = ('given' if counts.given > given else 'declined' if counts.declined > declined else 'failed')
        self.request_pub.publish(messages.advice_request_msg(outcome, pending.proposal.request,
                                                             self.params['advice_timeout_s']))
        self._finish_step(action, advised)

    def _on_advice_timeout(self, token: int) -> None:
        with self._lock:
            pending = self._take_pending(token)
            if pending is None:
                return
            self._resolve(pending, failure='timeout')

    def _on_advice_response(self, token: int, future) -> None:
        with self._lock:
            pending = self._take_pending(token)
            if pending is None:
                return
            self.advice_latencies.append(time.monotonic() - pending.sent)
            try:
                response = future.result()
            except Exception as error:
                self.get_logger().warn(f'advice call failed: {error!r}', throttle_duration_sec=5.0)
                self._resolve(pending, failure='error')
                return
            self.experts_heard[response.expert_name or '(unnamed)'] += 1
            accept = self.params['accept_expert']
            if accept and response.expert_name != accept:
                self.get_logger().warn(f"ignored advice from '{response.expert_name}' "
                                       f"(accept_expert is '{accept}')", throttle_duration_sec=5.0)
                self._resolve(pending, failure='untrusted')
            else:
                self._resolve(pending, Advice(
                    np.asarray(response.action, dtype=np.float32) if response.advised else None,
                    response.reason, response.expert_name, bool(response.human)))

    def _finish_step(self, action: np.ndarray, advised: bool) -> None:
        self._last_action = np.asarray(action, dtype=np.float32)
        self._last_advised = advised
        self._publish_action(self._last_action)

    def _publish_action(self, action: np.ndarray) -> None:
        self.action_pub.publish(self._action_out.fill(action, *self._key))

    # ------------------------------------------------------------------ a vanished env

    def _check_stall(self) -> None:
        with self._lock:
            if self.done or self._state is None or self._pending is not None:
                return
            silent = time.monotonic() - self._last_observation_time
            if silent < self.params['stall_timeout_s']:
                return
            self.stalled_episodes += 1
            self.get_logger().warn(
                f'no observation for {silent:.1f} s: abandoning episode {self.learner.episode} after '
                f'{self.learner.episode_step} steps; waiting for the env to start a new one')
            self.learner.abandon_episode()
            self._state = self._key = self._last_action = None
            self.experts_heard.clear()

    # ------------------------------------------------------------------ episodes

    def _on_episode_end(self, summary: EpisodeSummary) -> None:
        self.summaries.append(summary)
        self.stats_pub.publish(messages.stats_msg(summary))
        self._csv.writerow(summary.csv_row())
        self._csv_file.flush()
        failed = self.learner.advice_total.failed
        failures = ', '.join(f'{k} {v}' for k, v in failed.items() if v)
        experts = ', '.join(f'{name} {n}' for name, n in self.experts_heard.items())
        self.experts_heard.clear()
        self.get_logger().info(
            f'episode {summary.episode:4d}  return {summary.episode_return:9.2f}  len {summary.length:4d}  '
            f'advice {summary.advice_given}/{summary.advice_asked}'
            f'{" (%d from a person)" % summary.advice_human if summary.advice_human else ""}'
            f'{"  declined %d" % summary.advice_declined if summary.advice_declined else ""}'
            f'{"  failed %d (total: %s)" % (summary.advice_failed, failures) if summary.advice_failed else ""}'
            f'  success {int(summary.success)}  steps {summary.total_steps}  alpha {summary.alpha:.3f}'
            f'{"  answered by: " + experts if experts else ""}')
        every = self.params['checkpoint_every_episodes']
        if every and self.learner.episode % every == 0:
            self.save()
        limit = self.params['max_episodes']
        if limit and self.learner.episode >= limit:
            self.done = True
            self.save()
            self.get_logger().info(f'reached max_episodes={limit}; learning stopped')
            if self.params['shutdown_when_done']:
                self.context.try_shutdown()

    def save(self) -> None:
        """Checkpoint, exported policy and CSV, all flushed to disk."""
        with self._lock:
            save_checkpoint(self.learner, self.checkpoint_path, self.replay_path)
            export_policy(self.learner, self.output_dir / 'policy.pt')
            if not self._csv_file.closed:
                self._csv_file.flush()

    def close(self) -> None:
        with self._lock:
            if not self._csv_file.closed:
                self._csv_file.close()


def _save_and_close(node: LearnerNode) -> None:
    node.save()      # Ctrl-C and SIGTERM included: rclpy turns both into a clean exit
    node.close()


def main(args=None):
    run_node(LearnerNode, args, on_exit=_save_and_close)

if __name__ == '__main__':
    main()
