"""trainer: learns from the transitions of any number of actor nodes; sends them weights.

Transitions arrive on /transitions (nodes/actor_node.py) and go into D, and advised ones
into D_advising too (core/runs/trainer.py). The subscription only queues each arriving batch;
a learning thread of its own stores the queued batches and makes the updates owed, one at a
time. So the executor is always free to take the next batch: rclpy takes one message per
subscription per wait, and callbacks that held the executor for slices of updates let the
middleware's queue overflow (batches were lost). The updates keep updates_per_transition
updates per transition once D holds learning_starts. Every weights_every_updates updates, the actor's and
the critics' weights go out on /weights (latched: an actor that starts later gets them).
The record (episodes.csv with an `actor` column), checkpoints and resume are the learner
node's; each row is an episode an actor finished, indexed over all actors.
"""

from __future__ import annotations

import os
import socket
import threading
import time
from collections import deque
from typing import Optional

import numpy as np
from rclpy.node import Node

from eqhrl_interfaces.msg import EpisodeStats, PolicyWeights, TransitionAck, TransitionBatch

from ..core.algorithm import cpu_threads
from ..core.algorithm.learner import EQSACLearner, LearnerConfig
from ..core.data.errors import CheckpointError
from ..core.data.signing import signer_from
from ..core.data.summary import EpisodeSummary
from ..core.data.transitions import StepLimits
from ..core.data.weights import encode_weights
from ..core.envs.spec import CameraSpec
from ..core.runs.checkpoint import load_checkpoint
from ..core.runs.records import EpisodeRecord
from ..core.runs.trainer import TRAINER_CSV_FIELDS, Trainer
from ..parameters import LEARNER_CONFIG_PARAMS, TRAINER_PARAMS
from . import messages, trainer_health, trainer_msgs
from .env_info import configured_spec
from .graph_trust import GRAPH_CACHE_S, full_name
from .health import Health
from .messages import printable_name
from .params import choices_validator, declare, reject_unknown_overrides
from .run_files import RunFiles
from .spinning import leaves_nothing_when_refused, run_node, steady_clock, stop_with_error
from .trainer_exit import stop_save_and_close

# Refused batches of this many bytes since the last report make a new transitions subscription.
FLOOD_BYTES = 16e6
# Batches stored between updates at most: under a stream faster than storing, saves and updates
# still come.
STORE_PER_STEP = 256


def give_back_freed_memory() -> None:
    """Return the heap's free pages to the system (glibc's malloc_trim; elsewhere nothing): after
    a flood of large messages, freed but kept, they held the trainer's RSS hundreds of MB up."""
    import ctypes

    try:
        ctypes.CDLL('libc.so.6').malloc_trim(0)
    except (OSError, AttributeError):
        pass


class TrainerNode(RunFiles, Node):
    @leaves_nothing_when_refused
    def __init__(self, **kwargs):
        super().__init__('trainer', **kwargs)
        reject_unknown_overrides(self, LEARNER_CONFIG_PARAMS, TRAINER_PARAMS, settings_of='learner')
        values = declare(self, LEARNER_CONFIG_PARAMS)
        self.params = p = declare(self, TRAINER_PARAMS)
        self.add_on_set_parameters_callback(choices_validator(LEARNER_CONFIG_PARAMS))
        cpu_threads.for_node(p['torch_threads'], self.get_logger().info)  # 0: fitted to the machine
        self.config = LearnerConfig.from_params(values)
        self.signer = signer_from(
            p['key_file'], self.get_logger().warning
        )  # KeyFileError (a ValueError): refused at start-up
        if not (p['actors'] or self.signer or p['accept_any_actor']):
            # Closed by default: otherwise a stranger on the graph, under a name of its own, writes into D.
            raise ValueError(
                'the trainer takes transitions only from actors it knows: name them (actors:=[/actor0/actor, ...]), '
                'give the deployment key the actors sign with (key_file:=...), or on a closed, trusted network '
                'accept_any_actor:=true'
            )
        self._lock = threading.RLock()
        self._open_run_folder()

        # A new id for every trainer process: actors take its weights even at a lower version.
        self.trainer_id = f'{socket.gethostname()}:{os.getpid()}:{time.time_ns() % 10**12}'
        self.trainer: Optional[Trainer] = None
        self.learner: Optional[EQSACLearner] = None
        self.record: Optional[EpisodeRecord] = None
        self.spaces: Optional[tuple] = None  # (obs_dim, action_low, action_high)
        self.done = False  # max_episodes reached: the actors stop, no batch is stored any more
        self.paying = False  # done, and still making the updates owed before the final save
        self.refused_batches = 0
        self.weights_published = 0
        self.summaries: list[tuple[EpisodeSummary, str]] = []
        self.silent_actors: set = set()  # warned about once, until they send again
        self.report_mark = (time.monotonic(), 0, 0)  # (time, transitions, updates) at the last report

        self.weights_pub = self.create_publisher(PolicyWeights, trainer_msgs.WEIGHTS_TOPIC, trainer_msgs.WEIGHTS_QOS)
        self.stats_pub = self.create_publisher(EpisodeStats, '~/episode_stats', messages.RELIABLE_QOS)
        transitions = self._subscribe_transitions()
        # What it has stored and saved, after every batch: actors keep and resend until it is saved.
        self.ack_pub = self.create_publisher(
            TransitionAck, trainer_msgs.ack_topic(transitions.topic_name), trainer_msgs.ACK_QOS
        )
        self.create_timer(p['report_period_s'], self._report, clock=steady_clock())
        self._inbox: deque = deque()  # batches received, not stored yet (the learning thread's)
        self._inbox_bytes = 0
        self._inbox_bytes_lock = threading.Lock()  # the executor adds, the learning thread subtracts
        self._namesakes: dict = {}  # actor name -> (time looked up, nodes of that name publishing transitions)
        self.transitions_topic = self.resolve_topic_name(trainer_msgs.TRANSITIONS_TOPIC)
        self.dropped_batches = 0  # refused because the inbox was full (counted as lost by their actor too)
        self._refused_bytes = 0  # of strangers' batches refused since their memory was last given back
        self._work = threading.Event()  # set when a batch arrives
        self._hold = threading.Event()  # set while another thread saves
        self._save_due = False  # an episode made a periodic checkpoint due (checkpoint_every_episodes)
        self._stopping = threading.Event()

        self.health = Health(self, self.health_checks)
        spec = configured_spec(p)
        if spec is not None:
            self._build(spec.observation_size, spec.action_low, spec.action_high)
        # Last: a trainer that refuses to start (above) leaves no learning thread behind.
        self._learning = threading.Thread(target=self._learn, name='trainer-updates', daemon=True)
        self._learning.start()

    def _build(self, obs_dim: int, action_low, action_high, camera: Optional[CameraSpec] = None) -> None:
        """The learner for these spaces and camera (with resume, from the checkpoint); weights go out at once."""
        learner = EQSACLearner(obs_dim, action_low, action_high, self.config, camera=camera)
        learner.log = self.get_logger()  # compile_update's one line
        extra = None
        if self.params['resume']:
            extra = load_checkpoint(learner, self.checkpoint_path, self.replay_path)
            self._resumed(learner)
        p = self.params
        # Accepted: provenance noted (what the run is, for eqhrl-report), a run overwritten removed only now.
        env = {'env': p['env_id']} if p.get('env_id') else {}  # else the actors' batches gave the spaces
        self.run_folder.begin(**env, mode=self.config.mode, seed=self.config.seed)
        self.record = EpisodeRecord(
            self.csv_path, TRAINER_CSV_FIELDS, keep_before=learner.episode if p['resume'] else None
        )
        if self.record.gap_warning:
            self.get_logger().warn(self.record.gap_warning)
        if p['record']:
            from ..files.mcap_record import record_path
            from .recording import NodeRecord

            path = record_path(self.output_dir, resume=p['resume'])
            self.recording = NodeRecord(self, path, {'mode': self.config.mode, 'trainer': self.trainer_id})
            self.get_logger().info(f'recording the batches it stores and its episodes into {path}')
        self.learner = learner
        self.spaces = (learner.observation.state_dim, learner.scaler.low.copy(), learner.scaler.high.copy())
        limits = StepLimits(p['max_abs_observation'], p['max_abs_reward'])
        self.trainer = Trainer(learner, p['updates_per_transition'], p['weights_every_updates'], limits)
        if extra and isinstance(extra.get('sequences'), dict):
            # Where each actor's stream stood at the save: they send again what came after it.
            try:
                self.trainer.sequences.load_state_dict(extra['sequences'])
            except (KeyError, TypeError, ValueError) as error:
                why = f"{self.checkpoint_path}: its actors' sequences are unreadable ({error})"
                raise CheckpointError(why) from error
            self.get_logger().info(
                f'resumed {len(self.trainer.sequences.actors)} actor stream(s): '
                'each sends again what came after the save'
            )
        seen = f'camera {camera.height}x{camera.width}x{camera.channels} stacked by {camera.stack}, ' if camera else ''
        self.get_logger().info(
            f'{self.config.mode} trainer {self.trainer_id}: obs {obs_dim}, action {learner.action_dim}, {seen}'
            f'{p["updates_per_transition"]:g} updates per transition from {self.config.learning_starts} on, '
            f'weights every {p["weights_every_updates"]} updates, output {self.output_dir}'
        )
        self._publish_weights()

    # ------------------------------------------------------------------ transitions in

    def _subscribe_transitions(self):
        self.transitions_sub = self.create_subscription(
            TransitionBatch, trainer_msgs.TRANSITIONS_TOPIC, self._on_batch, trainer_msgs.TRANSITIONS_READER_QOS
        )
        return self.transitions_sub

    def _give_back_flood_memory(self) -> None:
        """After strangers' batches were refused: the middleware keeps the buffers of the reader's
        history as large as the largest message it held (20 of a flood's), and malloc the freed
        messages' pages. A new subscription and malloc_trim return both. A batch of an actor in
        flight meanwhile is lost on the way and sent again."""
        flood, self._refused_bytes = self._refused_bytes, 0
        if flood >= FLOOD_BYTES:
            self.destroy_subscription(self.transitions_sub)
            self._subscribe_transitions()
            self.get_logger().info(f'{flood / 1e6:.0f} MB of refused batches: their memory given back')
        give_back_freed_memory()

    def _on_batch(self, msg: TransitionBatch) -> None:
        """The executor's part: refuse a batch from an actor it does not hear (not in ``actors``,
        or not signed with key_file) at once, and queue the others for the learning thread,
        nothing more. The queue holds at most inbox_limit_mb; past it a batch is dropped and
        counted (updates far slower than the actors), and its actor's next batch shows the gap.
        So a stranger's flood never reaches the queue: it costs what one message in hand costs."""
        refusal = self._stranger(msg)
        if refusal:
            self.refused_batches += 1
            self._refused_bytes += trainer_msgs.batch_bytes(msg)
            self.get_logger().error(
                f'batch {msg.sequence} of actor {printable_name(msg.actor)} refused: {refusal}',
                throttle_duration_sec=5.0,
            )
            return
        size = trainer_msgs.batch_bytes(msg)
        with self._inbox_bytes_lock:
            full = self._inbox_bytes + size > self.params['inbox_limit_mb'] * 1e6
            if not full:
                self._inbox_bytes += size
        if full:
            self.dropped_batches += 1
            self.get_logger().warn(
                f'inbox full ({self._inbox_bytes / 1e6:.0f} MB waiting to be stored): batch {msg.sequence} of '
                f'actor {printable_name(msg.actor)} dropped ({self.dropped_batches} so far)',
                throttle_duration_sec=5.0,
            )
            return
        self._inbox.append(msg)
        self._work.set()

    def _stranger(self, msg: TransitionBatch) -> str:
        """Why a batch comes from an actor this trainer does not hear ('' when it may)."""
        allowed = self.params['actors']
        if allowed and msg.actor not in allowed:
            return f'actor {printable_name(msg.actor)} is not one of actors ({", ".join(allowed[:5])})'
        return trainer_msgs.signature_refusal(msg, self.signer)

    def _store(self, msg: TransitionBatch) -> None:
        """The learning thread's part: a batch into D (and D_advising), its episodes into the record."""
        if self.done:  # max_episodes reached: learning stopped, the record is closed to new rows
            self._acknowledge(msg.actor, msg.actor_run)  # the sender hears that the run has ended
            return
        try:
            self._check_one_sender(msg.actor)
            batch, low, high = trainer_msgs.batch_from_msg(msg)
            if self.trainer is None and not self._build_from(batch, low, high):
                return
            if self.done:  # built from a resumed run that had reached max_episodes
                self._acknowledge(msg.actor, msg.actor_run)
                return
            self._check_spaces(batch.observations.shape[1], low, high)
            try:
                verdict, rows, stored = self.trainer.receive(batch, payload=msg)
                if self.recording is not None:  # as they came, signature included
                    for stored_msg in stored:
                        self.recording.write(self.transitions_topic, stored_msg)
            finally:  # stored, held, or refused for what it holds: its actor hears where its stream stands
                self._acknowledge(batch.actor)
        except ValueError as error:
            self.refused_batches += 1
            self.get_logger().error(
                f'batch {msg.sequence} of actor {printable_name(msg.actor)} refused: {error}',
                throttle_duration_sec=5.0,
            )
            return
        actor = printable_name(batch.actor)
        if verdict == 'first':
            self.get_logger().info(f'actor {actor} joined at batch {batch.sequence}')
        elif verdict == 'gap':
            self.get_logger().warn(
                f'actor {actor}: batches lost before batch {batch.sequence} '
                f'({self.trainer.sequences.actors[batch.actor].lost} so far)'
            )
        elif verdict == 'restart':
            self.get_logger().info(f'actor {actor} started again')
        elif verdict == 'ahead':
            state = self.trainer.sequences.actors[batch.actor]
            self.get_logger().info(
                f'actor {actor}: batch {batch.sequence} came before batch {state.expected}: held, the missing ones '
                'asked for',
                throttle_duration_sec=5.0,
            )
        if batch.actor in self.silent_actors:
            self.silent_actors.discard(batch.actor)
            self.get_logger().info(f'actor {actor} is sending again')
        for row, who in rows:
            self._on_episode(row, who)

    def _acknowledge(self, actor: str, run: Optional[str] = None) -> None:
        """Where ``actor``'s stream stands, and once the run has ended, that it has (``run``: the
        run of a batch that came after the end, answered even where nothing of it is stored)."""
        state = self.trainer.sequences.actors.get(actor) if self.trainer is not None else None
        if state is not None and (run is None or run == state.run):
            highest, missing = self.trainer.missing(actor)
            self.ack_pub.publish(
                trainer_msgs.ack_msg(self.trainer_id, actor, state, highest, missing, self.signer, self.done)
            )
        elif self.done and run is not None:
            self.ack_pub.publish(trainer_msgs.run_ended_msg(self.trainer_id, actor, run, self.signer))

    def _check_one_sender(self, actor: str) -> None:
        """One node only under an actor's name (``_stranger`` has checked the name): two nodes of
        one full name publishing transitions (two machines launched alike, or a stranger posing as
        an actor) cannot be told apart, so the batches of both are refused."""
        now = time.monotonic()
        looked, count = self._namesakes.get(actor, (float('-inf'), 0))
        if now - looked >= GRAPH_CACHE_S:
            infos = self.get_publishers_info_by_topic(self.transitions_topic)
            count = sum(full_name(i.node_namespace, i.node_name) == actor for i in infos)
            if len(self._namesakes) > 10_000:
                self._namesakes.clear()
            self._namesakes[actor] = (now, count)
        if count > 1:
            raise ValueError(
                f'{count} nodes named {printable_name(actor)} publish transitions: each needs a name of its own '
                '(a namespace, or actors.launch.py on each machine with its own actor_prefix)'
            )

    def _build_from(self, batch, low, high) -> bool:
        """The first batch gives the spaces and the camera (no env_id or spaces parameters were set)."""
        frames = batch.frames
        try:
            camera = None if frames is None else CameraSpec(*frames.frames.shape[1:], stack=frames.stack)
            self._build(batch.observations.shape[1], low, high, camera)
        except Exception as error:  # a checkpoint for other spaces, bad bounds: stop, say why
            stop_with_error(self, f'cannot learn from actor {printable_name(batch.actor)}: {error}')
            return False
        return True

    def _check_spaces(self, obs_dim: int, low, high) -> None:
        own_obs, own_low, own_high = self.spaces
        if (
            obs_dim != own_obs
            or len(low) != len(own_low)
            or not (np.allclose(low, own_low) and np.allclose(high, own_high))
        ):
            raise ValueError(
                f"spaces obs {obs_dim}, action [{list(low)}, {list(high)}] differ from the trainer's "
                f'obs {own_obs}, action [{own_low.tolist()}, {own_high.tolist()}]'
            )

    def _on_episode(self, row: EpisodeSummary, actor: str) -> None:
        self.summaries.append((row, actor))
        stats = messages.stats_msg(row)
        self.stats_pub.publish(stats)
        if self.recording is not None:
            self.recording.write(self.stats_pub.topic_name, stats)
        self._append_row([*row.csv_row(), actor])
        self.get_logger().info(
            f'episode {row.episode:4d}  return {row.episode_return:9.2f}  len {row.length:4d}  '
            f'advice {row.advice_given}/{row.advice_asked}  success {int(row.success)}  '
            f'steps {row.total_steps}  updates {self.learner.updates}  alpha {row.alpha:.3f}  '
            f'{"INTERRUPTED  " if row.interrupted else ""}from {printable_name(actor)}'
        )
        p = self.params
        limit, every = p['max_episodes'], p['checkpoint_every_episodes']
        if limit and self.learner.episode >= limit and not self.done:
            self.done = True
            self.save_or_log()  # every batch stored is saved before the actors hear that the run ended
            for actor in list(self.trainer.sequences.actors):  # each actor stops acting for this run
                self._acknowledge(actor)
            owed = self.trainer.updates_owed()
            if owed > 0:  # free-running actors outran the updates: the final policy gets them all
                self.paying = True
                self.get_logger().info(
                    f'reached max_episodes={limit}: the actors stop; the {owed} updates still owed '
                    f'(updates_per_transition {self.trainer.updates_per_transition:g}) come before the final save'
                )
            else:
                self._finish()
        elif every and self.learner.episode % every == 0:
            self._save_due = True  # saved once the step's batches are all stored (_learn_step)

    def _finish(self) -> None:
        """The run's end, its updates all made: the last weights out, the final save."""
        if self.trainer.weights_at != self.learner.updates:
            self._publish_weights()
        self.save_or_log()
        self.paying = False
        self.get_logger().info(
            f'reached max_episodes={self.params["max_episodes"]}; learning stopped '
            f'({self.learner.updates} updates, {self.learner.total_steps} transitions)'
        )
        if self.params['shutdown_when_done']:
            self.context.try_shutdown()

    # ------------------------------------------------------------------ learning

    def _learn(self) -> None:
        """The learning thread: one step at a time, under the node's lock, so that a save can
        come in between."""
        while not self._stopping.is_set():
            if self._hold.is_set():  # a save from another thread (at exit) goes first
                time.sleep(0.005)
                continue
            if not self._learn_step():
                self._work.wait(0.05)
                self._work.clear()

    def _learn_step(self) -> bool:
        """Store what arrived (up to STORE_PER_STEP batches), then the checkpoint its episodes
        made due, then one update if one is owed; weights out when due. Returns whether there
        was anything to do. One save for all the episodes stored in a step: a resumed trainer
        that an actor sends a thousand kept episodes at once saved a thousand times, and fell
        minutes behind (the actor keeps each episode until a checkpoint holds it, so a save
        made later loses nothing)."""
        with self._lock:
            stored = 0
            while self._inbox and stored < STORE_PER_STEP and not self._stopping.is_set():
                msg = self._inbox.popleft()
                with self._inbox_bytes_lock:
                    self._inbox_bytes -= trainer_msgs.batch_bytes(msg)
                self._store(msg)
                stored += 1
            if self._save_due:
                self._save_due = False
                self.save_or_log()
            busy = self.trainer is not None and (self.paying or not self.done) and self.trainer.updates_owed() > 0
            if busy:
                try:
                    if self.trainer.update().get('restored'):
                        self.get_logger().error(
                            f'an update made the networks non-finite: they were put back as the last '
                            f'weights sent ({self.trainer.restored} times so far)',
                            throttle_duration_sec=5.0,
                        )
                    if self.trainer.weights_due():
                        self._publish_weights()
                except Exception as error:  # never a silent death: say it and stop the node
                    self._stopping.set()
                    stop_with_error(self, f'update failed: {error!r}')
            if self.paying and self.trainer.updates_owed() <= 0 and not self._stopping.is_set():
                self._finish()
            return busy or stored > 0

    def save(self) -> None:
        self._hold.set()
        try:
            super().save()
        finally:
            self._hold.clear()

    def _checkpoint_extra(self):
        """Each actor's stream as far as it is stored: a resumed trainer asks for what came after."""
        return None if self.trainer is None else {'sequences': self.trainer.sequences.state_dict()}

    def _saved(self, extra) -> None:
        if self.trainer is not None and extra is not None:
            self.trainer.sequences.saved(extra['sequences'])

    def stop_learning(self) -> None:
        """End the learning thread (after its current step); safe to call twice."""
        self._stopping.set()
        self._learning.join(timeout=30)

    def destroy_node(self):
        self.stop_learning()
        return super().destroy_node()

    def _publish_weights(self) -> None:
        """The networks out on /weights, if they are finite (else back to the last that were)."""
        learner = self.learner
        if not self.trainer.networks_finite():
            self.trainer.restore_finite()
            self.get_logger().error('the networks became non-finite: put back as the last weights sent, not sent')
            self.trainer.weights_sent()
            return
        self.trainer.keep_finite()
        msg = trainer_msgs.weights_msg(
            self.trainer_id,
            learner.updates,
            learner.episode,
            self.get_clock().now().to_msg(),
            encode_weights(learner, self.params['weights_on_wire']),
        )
        self.weights_pub.publish(trainer_msgs.sign_weights(msg, self.signer))
        self.trainer.weights_sent()
        self.weights_published += 1

    def health_checks(self) -> list:
        """The actors and the learning, for /diagnostics (nodes/trainer_health.py)."""
        return trainer_health.trainer_checks(self)

    def _report(self) -> None:
        if self._refused_bytes:
            self._give_back_flood_memory()
        trainer_health.report(self)


def main(args=None):
    run_node(TrainerNode, args, on_exit=stop_save_and_close, name='trainer')


if __name__ == '__main__':
    main()
