"""ActingNode: what the learner node and an actor node share: acting on the env node's
observations with EQSACLearner.propose, asking the expert service when the gates fire, and
turning each observation into a transition. What becomes of a transition is the subclass's:
the learner node learns from it at once (Algorithm 1 in lock-step), an actor node sends it to
a trainer (nodes/actor_node.py).

Its jobs, each in a part of its own:
- the advice requests (nodes/advice_client.py): nothing in this node ever blocks waiting for
  another node;
- who drives each step: the learner, the person asked to take the wheel, or the person unasked
  (nodes/person_wheel.py, over core/experts/wheel.py and takeover.py);
- the health it reports on /diagnostics (nodes/acting_health.py);
- what each observation means for the episode, across gaps, restarts, stalls and stops
  (nodes/episode_tracking.py); turning them into transitions (here).
"""

from __future__ import annotations

import threading
import time
from typing import Optional

import numpy as np
from rclpy.node import Node
from std_msgs.msg import Bool, Float32MultiArray, String

from eqhrl_interfaces.msg import AdviceRequest, EpisodeStats, GateDecision

from ..core.algorithm import cpu_threads
from ..core.algorithm.config import advice_protocol
from ..core.algorithm.learner import EpisodeSummary, EQSACLearner, LearnerConfig
from ..core.data.advice import Advice
from ..core.data.signing import CommandCheck, signer_from
from ..core.data.transitions import StepLimits
from ..core.envs.spec import EnvSpec
from ..parameters import LEARNER_CONFIG_PARAMS
from . import messages
from .acting_health import acting_checks
from .advice_client import AdviceClient, PendingAdvice, say_unused_answer
from .camera_input import CameraInput
from .env_info import EnvInfoWatcher, configured_spec, shown
from .episode_tracking import EpisodeTracking, episode_line
from .graph_trust import OnePublisher, subscribe_stop
from .health import WARN, Check, Health
from .params import choices_validator, declare, reject_unknown_overrides
from .person_wheel import PersonWheel
from .recording import NodeRecord
from .spinning import leaves_nothing_when_refused, steady_clock
from .start_wait import StartWait


class ActingNode(Node):
    """The acting half, shared by the learner and actor nodes. A subclass gives its node name
    and parameter table, and says what a transition and an episode's end become."""

    @leaves_nothing_when_refused
    def __init__(self, node_name: str, node_params: tuple, **kwargs):
        super().__init__(node_name, **kwargs)
        reject_unknown_overrides(self, LEARNER_CONFIG_PARAMS, node_params, settings_of='learner')
        values = declare(self, LEARNER_CONFIG_PARAMS)
        self.params = declare(self, node_params)
        # Check in the on-set callback (a later one may still refuse the change), act in the
        # post-set one, once every check has passed (ros2/demos set_parameters_callback.py).
        self.add_on_set_parameters_callback(choices_validator(LEARNER_CONFIG_PARAMS))
        self.add_post_set_parameters_callback(self._after_set_parameters)
        p = self.params
        cpu_threads.for_node(p['torch_threads'], self.get_logger().info)  # 0: fitted to the machine

        self.config = LearnerConfig.from_params(values)
        self._before_start()
        # Made once the env's spaces are known (_configure): at once from env_id or the spaces
        # parameters, else from the env's env_info.
        self.learner: Optional[EQSACLearner] = None
        self.spec = None

        self.action_pub = self.create_publisher(Float32MultiArray, 'action', messages.RELIABLE_QOS)
        self.stats_pub = self.create_publisher(EpisodeStats, '~/episode_stats', messages.RELIABLE_QOS)
        self.gate_pub = self.create_publisher(GateDecision, '~/gate_debug', messages.RELIABLE_QOS)
        self.request_pub = self.create_publisher(AdviceRequest, '~/advice_request', messages.LATCHED_QOS)
        self.driver_pub = self.create_publisher(String, '~/driver', messages.LATCHED_QOS)  # who drives now
        # Observations arrive serialized (raw): see messages.SerializedReader.
        observations = self.create_subscription(
            Float32MultiArray, 'observation', self._on_observation, messages.OBSERVATION_QOS, raw=True
        )
        self._observation_topic = observations.topic_name
        # One env feeds a learner (env_node, if named): while a second node publishes observation, none is taken.
        self.observation_source = OnePublisher(self, self._observation_topic, p.get('env_node', ''))
        # key_file: advise is signed (advice_client) and person_command checked; KeyFileError refuses the node.
        self.signer = signer_from(p['key_file'], self.get_logger().warning)
        self._listen_to_the_person(p)
        self.wheel: Optional[PersonWheel] = None  # who drives: made with the learner (its action bounds)
        # The person's STOP holds the env: the episode is paused (not abandoned), and its record
        # says for how long (EpisodeSummary.stops, stopped_s). A release as the envs take it.
        self._stop_topic = subscribe_stop(self, self._on_stop).topic
        self.early_observations = 0  # observations before the spaces were known (ignored)
        self.recording: Optional[NodeRecord] = None  # record: true (the learner node)

        self._lock = threading.RLock()  # callbacks may run on several threads
        # Timers on the steady clock: with use_sim_time and a /clock that stops (or never
        # starts), ROS time stands still, and an advice timeout or a stall must still fire.
        self._steady = steady_clock()
        self.advice = AdviceClient(self, self.params, self._lock, self._steady, self._resolve, self.signer)
        self.tracking = EpisodeTracking(self.get_logger())  # the step acted on, gaps, stalls, stops
        self._last_action: Optional[np.ndarray] = None
        self._last_advised = False
        self._last_source = 'learner'  # who chose the last action (core/data/advice.ACTION_SOURCES)
        self.dropped_messages = 0
        self.step_limits = StepLimits(p['max_abs_observation'], p['max_abs_reward'])
        self.repeated_observations = 0  # the env re-sent an observation (our action did not arrive in time)
        self.create_timer(0.25, self._check_stall, clock=self._steady)
        self.done = False
        self.summaries: list[EpisodeSummary] = []
        # The first observation waits for the env's pace (auto, by env_id) and an expert (start_wait.py).
        self.start_wait = StartWait(
            self,
            lambda: self.protocol if p['advice_enabled'] and self.learner.advice_window().open else None,
            lambda: self.env_info.judging,
            self.advice,
            lambda: p['expert_wait_s'],
            lambda data: self._on_observation(data, held=True),
            self._steady,
            self._lock,
        )
        self.camera_input: Optional[CameraInput] = None  # camera: made with the learner
        self.env_info = EnvInfoWatcher(
            self,
            None if p.get('camera') else configured_spec(p),  # a camera's size comes from env_info
            self._configure,
            working=lambda: bool(self.learner and self.learner.total_steps),
            on_announced=lambda: self.start_wait.release(),
        )
        self.health = Health(self, self.health_checks)

    @property
    def stalls(self) -> int:
        return self.tracking.stalls

    @property
    def observation_gaps(self) -> int:
        return self.tracking.observation_gaps

    def health_checks(self) -> list:
        """The expert, the env and the budget, for /diagnostics (nodes/acting_health.py)."""
        if self.learner is None:
            return [Check('env', WARN, f'waiting for env_info on {self.env_info.topic}')]
        return acting_checks(self)

    def _before_start(self) -> None:
        """The subclass's own set-up, before the learner can exist (its output folder)."""

    def _configure(self, spec: EnvSpec) -> None:
        """Build the learner for the env's spaces (and what the subclass needs with it). From
        __init__ its errors refuse the start; from env_info they stop the node (exit 1)."""
        camera = spec.camera(self.params['camera']) if self.params.get('camera') else None
        learner = EQSACLearner(
            spec.observation_size,
            spec.action_low,
            spec.action_high,
            self.config,
            spec.success_criterion(),
            camera and camera.spec(self.params['camera_stack']),
        )
        learner.log = self.get_logger()  # compile_update's one line
        self._prepare(learner, spec)
        wheel = PersonWheel(
            learner,
            self.config.takeover_threshold,
            lambda msg: self._publish_recorded(self.request_pub, msg),
            lambda driver: self._publish_recorded(self.driver_pub, String(data=driver)),
            self.get_logger(),
        )
        with self._lock:
            self._action_out = messages.action_out(learner.action_dim)  # rewritten per step
            self._observation_reader = messages.SerializedReader(
                messages.observation_layouts(spec.observation_size), 'observation'
            )
            self.spec, self.learner, self.wheel = spec, learner, wheel
            if camera is not None:
                self.camera_input = CameraInput(
                    self,
                    camera,
                    self.params['camera_stack'],
                    self.params['camera_wait_s'],
                    self._lock,
                    lambda data: self._on_observation(data, held=True),  # a frame came, or the wait ended
                    self.params['camera_publisher'],
                    self.params['camera_transport'],
                )
        self.get_logger().info(
            f'{self.config.mode} on {shown(spec.name)} ({spec.source}): obs {spec.observation_size}, '
            f'action {spec.action_size}, success {spec.success_rule}, advice protocol {self._protocol_said()}, '
            f'budget {self.config.advising_budget} episodes{self._describe()}'
        )
        if self.config.never_asks():  # e.g. mode:=random on a file whose rate is 0
            self.get_logger().warn(
                f'{self.config.never_asks()} (set random_ask_rate, the chance of asking at each step: 0.05, say)'
            )

    @property
    def pace(self) -> Optional[EnvSpec]:
        """The env's pace (real-time or lock-step, rate, episode length): its own env_info once
        heard (a learner configured by env_id cannot know it otherwise), else the spec in use."""
        return self.env_info.announced or self.spec

    def _listen_to_the_person(self, p: dict) -> None:
        """person_command (teleop_expert passes it on): a takeover when it departs from ours. It drives
        the robot: taken only while teleop_expert alone publishes it (with key_file, signed with it)."""
        person = self.create_subscription(Float32MultiArray, messages.PERSON_COMMAND_TOPIC, self._on_person_command, 10)
        self._person_topic = person.topic_name
        expected = p['person_publisher'] or f'{self.get_namespace().rstrip("/")}/teleop_expert'
        self.person_guard = OnePublisher(self, self._person_topic, expected)
        self.person_check = CommandCheck(self.signer) if self.signer else None
        self.refused_person_commands = 0

    @property
    def protocol(self) -> str:
        """How a request asks now: 'answer' or 'wheel' (advice_protocol for the env's pace); ''
        while that is not known: 'auto' configured by env_id waits for the env's own env_info
        (start_wait.py says why). Configured by the spaces as parameters, for an env that may
        publish no env_info, 'auto' is the answer until an env_info says otherwise."""
        pace = self.pace
        if pace is None:
            return ''
        if self.config.advice_protocol == 'auto' and self.env_info.announced is None and self.params.get('env_id'):
            return ''
        return advice_protocol(self.config.advice_protocol, pace.realtime)

    def _protocol_said(self) -> str:
        configured = self.config.advice_protocol
        return configured if configured != 'auto' else 'auto (the wheel in real time, one answer in lock-step)'

    def _prepare(self, learner: EQSACLearner, spec: EnvSpec) -> None:
        """The subclass's use of a new learner for the env ``spec`` before it acts (a checkpoint to
        load, a record)."""

    def _describe(self) -> str:
        """The end of the start-up log line."""
        return ''

    # ------------------------------------------------------------------ parameters at run time

    def _after_set_parameters(self, changes) -> None:
        with self._lock:
            for change in changes:
                if change.name in ('advising_budget', 'advising_budget_s'):  # the learner's, once it exists
                    value = int(change.value) if change.name == 'advising_budget' else float(change.value)
                    if self.learner is not None:
                        getattr(self.learner, f'set_{change.name}')(value)
                    else:
                        setattr(self.config, change.name, value)
                elif hasattr(self.config, change.name) and change.name.startswith('wheel_'):
                    setattr(self.config, change.name, change.value)  # read when the next request opens
                elif change.name in self.params:
                    self.params[change.name] = change.value

    # ------------------------------------------------------------------ observations

    def _on_observation(self, data: bytes, held: bool = False) -> None:
        """``held``: the observation start_wait held, acted on now (seen and recorded then)."""
        with self._lock:
            if self.done:
                return
            if self.learner is None:
                self.early_observations += 1  # the env re-sends it; acted on once the spaces are known
                return
            if not held:
                if not self.observation_source.admits(self.get_logger(), 'observation'):
                    return
                self.tracking.observed()
                if self.recording is not None:
                    self.recording.write_raw(self._observation_topic, Float32MultiArray, data)
            try:
                state_dim = self.learner.observation.state_dim
                env_step = messages.parse_observation(self._observation_reader.values(data), state_dim)
                beyond = self.step_limits.refusal(env_step.obs, env_step.reward)  # finite, but no env's
                if beyond:
                    raise messages.MessageError(f"'{self._observation_topic}': {beyond}")
            except messages.MessageError as error:
                self.dropped_messages += 1
                self.get_logger().error(f'dropped observation: {error}', throttle_duration_sec=5.0)
                return
            if not held and self.start_wait.hold(data):
                return
            key = (env_step.episode, env_step.step)
            if key == self.tracking.key:
                self.repeated_observations += 1
                # The env sent the same observation again: our action did not reach it.
                if self.camera_input is not None:
                    self.camera_input.seen_again()
                if self.advice.pending is None and self._last_action is not None:
                    self._publish_action(self._last_action)
                return
            if self.camera_input is not None:
                env_step = self.camera_input.attach(env_step, data)
                if env_step is None:
                    return  # its frame is late (it waits), or never came (dropped)
            if self.advice.pending is not None:
                self._observe_while_waiting(env_step, key)
                return

            if self.tracking.follows(key):
                if self._store(env_step):
                    return  # the episode ended; the env's reset message starts the next
            else:
                self.tracking.start_from(self.learner, env_step, key)
            if env_step.done:
                # A final observation with no predecessor we acted on: nothing to store or act on.
                self.tracking.key = key
                self.tracking.state = None
                return
            self._act(env_step.obs, key)

    def _observe_while_waiting(self, env_step: messages.EnvStep, key: tuple) -> None:
        """A real-time env keeps stepping with the held (previous) action while the person
        decides: those are real transitions, stored as such; the advice, when it comes,
        applies to the latest observation. (A lock-step env sends nothing meanwhile.)"""
        if not self.tracking.follows(key) or self._last_action is None:
            return
        if env_step.done:
            # The episode ends before the answer: counted as such (not the person's timeout), and
            # said at once, so that the page and teleop_expert end the request too.
            pending = self.advice.take_pending()
            self.learner.resolve_advice(pending.proposal, failure='episode_ended')  # acted on already
            self._publish_recorded(
                self.request_pub,
                messages.advice_request_msg(
                    'failed', pending.proposal.request, self.params['advice_timeout_s'], 'episode_ended'
                ),
            )
        self._last_advised, self._last_source = False, 'learner'
        if not self._store(env_step):
            self.tracking.state, self.tracking.key = env_step.obs, key

    def _store(self, env_step: messages.EnvStep) -> bool:
        """Hand on the transition the message completes; returns True when the episode ended."""
        if env_step.done:  # an open request for the wheel, or a takeover, ends with the episode
            self.wheel.episode_ends(time.monotonic())
        try:
            summary = self._transition(
                self.tracking.state,
                self._last_action,
                env_step.reward,
                env_step.obs,
                env_step.terminated,
                env_step.truncated,
                self._last_advised,
                env_step.success,
                self._last_source,
            )
        except ValueError as error:
            self.dropped_messages += 1
            self.get_logger().error(f'transition not stored: {error}', throttle_duration_sec=5.0)
            return False
        if summary is None:
            return False
        self.tracking.key = (env_step.episode, env_step.step)
        self.tracking.state = None
        self._on_episode_end(summary)
        return True

    def _transition(self, obs, action, reward, next_obs, terminated, truncated, advised, success, source):
        """(s_t, a_t, r_t, s_{t+1}) is complete: count it in the episode and learn from it or send
        it (``source``: who chose a_t, one of ACTION_SOURCES). Returns the episode's summary when it
        ended the episode; ValueError on a bad one."""
        raise NotImplementedError

    # ------------------------------------------------------------------ acting and advice

    def _on_person_command(self, msg: Float32MultiArray) -> None:
        try:
            refusal = self.person_guard.refusal()  # who publishes, then (with key_file) who signed, then what
            if not refusal:
                action, deadman, take_over = messages.person_command(msg, self.person_check)
        except (KeyError, ValueError) as error:
            refusal = str(error)
        if refusal:
            self.refused_person_commands += 1
            self.get_logger().error(f'person commands refused: {refusal}', throttle_duration_sec=5.0)
            return
        with self._lock:
            if self.wheel is not None:
                self.wheel.heard(action, deadman, take_over, time.monotonic())
            if self.recording is not None:
                self.recording.write(self._person_topic, msg)

    def _act(self, obs: np.ndarray, key: tuple) -> None:
        self.tracking.state, self.tracking.key = obs, key
        proposal = self.learner.propose(obs)
        if self.params['publish_gate_debug'] or self.recording is not None:
            gate = messages.gate_msg(self.learner.episode, self.learner.episode_step, proposal.decision)
            if self.params['publish_gate_debug']:
                self.gate_pub.publish(gate)
            if self.recording is not None:  # every decision, published or not
                self.recording.write(self.gate_pub.topic_name, gate)
        now = time.monotonic()
        decided = self.wheel.turn(proposal, now)
        if decided is not None:  # the person drives, or a request for the wheel waits: no new request
            self._finish_step(*decided)
            return
        if not (proposal.decision.fire and self.params['advice_enabled']):
            self._finish_step(proposal.action, advised=False)
            return
        protocol = self.protocol
        if protocol == 'wheel' and self.person_guard.heard_from():
            # Ask the person to take over from here; the learner drives meanwhile.
            self._finish_step(self.wheel.ask(proposal, now, key[1], self.pace), advised=False)
            return
        if protocol != 'answer' or not self.advice.ready():  # nobody to ask: counted as unavailable
            self.start_wait.say_unasked(protocol, self.env_info.topic, self._person_topic, self.advice.ready())
            self._finish_step(
                *self.learner.resolve_advice(proposal, failure='unavailable').action_and_advised(), 'learner'
            )
            return
        # The wait is cut to what is left of the person's seconds: an answer cannot overspend them.
        timeout = max(1e-3, min(self.params['advice_timeout_s'], self.learner.person_budget_left_s))
        self.advice.ask(proposal, key, timeout)
        self._publish_recorded(self.request_pub, messages.advice_request_msg('pending', proposal.request, timeout))

    def _resolve(self, pending: PendingAdvice, advice: Optional[Advice] = None, failure: str = '') -> None:
        """A request ended (advice_client.py): count the outcome, tell the person's UI, and act."""
        resolution = self.learner.resolve_advice(pending.proposal, advice, failure)
        human = advice is not None and advice.human
        say_unused_answer(self.get_logger(), resolution, advice, self.learner.scaler)
        self._publish_recorded(
            self.request_pub,
            messages.advice_request_msg(
                resolution.outcome,
                pending.proposal.request,
                self.params['advice_timeout_s'],
                resolution.detail,
                human,
                advice.response_time_s if human else time.monotonic() - pending.sent,
                resolution.action if resolution.outcome == 'given' else (),
            ),
        )
        self._finish_step(*resolution.action_and_advised(), resolution.source)

    def _finish_step(self, action: np.ndarray, advised: bool, source: str = 'learner') -> None:
        self._last_action = np.asarray(action, dtype=np.float32)
        self._last_advised = advised
        self._last_source = source
        self._publish_action(self._last_action)

    def _publish_action(self, action: np.ndarray) -> None:
        self._publish_recorded(self.action_pub, self._action_out.fill(action, *self.tracking.key))

    def _publish_recorded(self, publisher, msg) -> None:
        """Publish, and write into the record when there is one."""
        publisher.publish(msg)
        if self.recording is None:
            return
        if isinstance(msg, (bytes, bytearray, memoryview)):  # published serialized (the action)
            self.recording.write_raw(publisher.topic_name, publisher.msg_type, msg)
        else:
            self.recording.write(publisher.topic_name, msg)

    # ------------------------------------------------------------------ a vanished env

    def _check_stall(self) -> None:
        with self._lock:
            if not self.done:
                waiting = self.advice.pending is not None
                self.tracking.check_stall(self.learner, waiting, self.params['stall_timeout_s'])

    def _on_stop(self, msg: Bool) -> None:
        with self._lock:
            if self.recording is not None:
                self.recording.write(self._stop_topic, msg)
            self.tracking.stop(bool(msg.data), self.learner)
            if self.wheel is not None:
                self.wheel.stopped(bool(msg.data), time.monotonic())
            # An open request for one answer holds too: its timeout, and (told so here) the person's window.
            left = self.advice.pause() if msg.data else self.advice.resume()
            if left is not None:
                self._publish_recorded(
                    self.request_pub,
                    messages.advice_request_msg(
                        'pending', self.advice.pending.proposal.request, left, 'stopped' if msg.data else ''
                    ),
                )

    # ------------------------------------------------------------------ episodes

    def _on_episode_end(self, summary: EpisodeSummary) -> None:
        self.summaries.append(summary)
        self._publish_recorded(self.stats_pub, messages.stats_msg(summary))
        self._episode_done(summary)
        experts = ', '.join(f'{name} {n}' for name, n in self.advice.experts_heard.items())
        self.advice.experts_heard.clear()
        self.get_logger().info(episode_line(summary, self.learner.advice_total.failed, experts))
        self._after_episode(summary)

    def _episode_done(self, summary: EpisodeSummary) -> None:
        """Keep the finished episode (a row of the record, or the trainer's batch): before the log line."""

    def _after_episode(self, summary: EpisodeSummary) -> None:
        """After the log line: saves, and stopping at max_episodes."""
