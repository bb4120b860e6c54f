"""teleop_expert: a person advises through a joystick, a Twist teleop or a plain command topic.

Subscribes to ``joy`` (sensor_msgs/Joy, from the `joy` node), ``cmd_vel``
(geometry_msgs/Twist, from teleop_twist_keyboard or teleop_twist_joy) or
``teleop_command`` (std_msgs/Float32MultiArray, from keyboard_teleop or advice_console),
as ``source`` says, and serves ``advise``.

In ``answer_mode: window`` each request is held open until the person acts (see
core.experts.teleop.TeleopExpert) or the answer window passes. The service callback is a
coroutine awaiting that moment, in its own callback group: the executor goes on
delivering the person's commands meanwhile, and nothing blocks a thread.
"""

from __future__ import annotations

import math
import threading
import time
from functools import reduce

import numpy as np
from geometry_msgs.msg import Twist
from rcl_interfaces.msg import SetParametersResult
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.task import Future
from sensor_msgs.msg import Joy
from std_msgs.msg import Float32MultiArray

from eqhrl_interfaces.msg import AdviceRequest as AdviceRequestMsg
from eqhrl_interfaces.srv import Advise

from ..core.data.advice import SKIPPED, Advice
from ..core.data.camera_frames import FrameError
from ..core.data.signing import CommandCheck, CommandSeal, signer_from
from ..core.envs.spec import EnvSpec
from ..core.experts.teleop import (
    TWIST_FIELDS,
    Command,
    TeleopExpert,
    array_command,
    joy_command,
    joy_misfit,
    twist_command,
)
from ..parameters import TELEOP_EXPERT_PARAMS
from . import messages
from .advise_msgs import (
    answer,
    fill_response,
    frames_refused,
    request_check,
    request_from_msg,
    request_refusal,
    sign_answer,
    unsigned_request,
)
from .env_info import EnvInfoWatcher, configured_spec
from .graph_trust import OnePublisher
from .params import choices_validator, declare, plain, reject_unknown_overrides
from .recording import introspect
from .spinning import run_node, steady_clock

# The answer must reach the learner before its advice_timeout_s ends.
ANSWER_MARGIN_S = 0.2
# The nodes that publish teleop_command in this package: taken from by default (command_publisher
# names another driver).
SHIPPED_DRIVERS = ('advice_console', 'keyboard_teleop')


class TeleopExpertNode(Node):
    def __init__(self, **kwargs):
        super().__init__('teleop_expert', **kwargs)
        reject_unknown_overrides(self, TELEOP_EXPERT_PARAMS)
        self.params = declare(self, TELEOP_EXPERT_PARAMS)
        self._check_mapping(self.params)
        self._take_the_key()
        self.add_on_set_parameters_callback(choices_validator(TELEOP_EXPERT_PARAMS))
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.expert = TeleopExpert(
            self.params['stale_after_s'],
            name=self.get_fully_qualified_name(),
            answer_change=self.params['answer_change'],
            settle_s=self.params['answer_settle_s'],
        )
        self.rejected_commands = 0
        self.answers = {'answered': 0, 'skipped': 0, 'timed_out': 0, 'declined': 0}
        self.reaction_times: list[float] = []  # seconds, per request the person answered or skipped
        self._lock = threading.Lock()  # commands and requests may come on different threads
        self._waiting: Future | None = None  # the open request's answer, once the person gives it
        # A command the person steered to answers once it held still (answer_settle_s), also when
        # no new command comes meanwhile (a Twist is sent only on a key press).
        self.create_timer(0.05, self._check_settled, clock=steady_clock())
        # The open request's window: its end (time.monotonic()), moved on while a STOP holds it.
        self._window_s = 0.0
        self._window_end = 0.0
        self._paused_at: float | None = None
        self._steady = steady_clock()
        source = self.params['source']
        if source == 'joy':
            self.create_subscription(Joy, 'joy', self._on_joy, 10)
        elif source == 'twist':
            self.create_subscription(Twist, 'cmd_vel', self._on_twist, 10)
        else:
            self.create_subscription(Float32MultiArray, 'teleop_command', self._on_array, 10)
        # Window mode answers from a coroutine, in its own callback group: a request awaiting
        # the person must not hold back the commands. Coroutine callbacks need an executor
        # that runs them (spinning.make_executor).
        self.coroutine_callbacks = self.params['answer_mode'] == 'window'
        service = self.create_service(
            Advise,
            'advise',
            self._on_request_in_window if self.coroutine_callbacks else self._on_request_now,
            callback_group=ReentrantCallbackGroup(),
        )
        introspect(service, self)  # every call on advise/_service_event (ros2 bag record, the learner's record)
        topic = {'joy': 'joy', 'twist': 'cmd_vel', 'array': 'teleop_command'}[source]
        # Commands are the person's only while one node publishes them: command_publisher if set;
        # for teleop_command, else the drivers that ship (in this node's namespace).
        expected = self.params['command_publisher']
        if not expected and source == 'array':
            ns = self.get_namespace().rstrip('/')
            expected = tuple(f'{ns}/{driver}' for driver in SHIPPED_DRIVERS)
        self.source_guard = OnePublisher(self, self.resolve_topic_name(topic), expected)
        self.get_logger().info(
            f"advising from '{topic}' ({source}); scales {self.params['scales']}; answer mode "
            f'{self.params["answer_mode"]}'
            + (f', window {self.params["answer_window_s"]:g} s' if self.params['answer_mode'] == 'window' else '')
        )
        self.env_info = EnvInfoWatcher(self, configured_spec(self.params), self._check_action_size)
        # The learner's word on each request: one it has resolved without this node's answer (the
        # episode ended, its timeout passed) is ended here too, so that no later key press lands
        # on it and nothing is logged as answered that the learner never used.
        self.ended_by_learner = 0
        self.person_pub = self.create_publisher(Float32MultiArray, messages.PERSON_COMMAND_TOPIC, 10)
        requests = self.create_subscription(
            AdviceRequestMsg, 'learner/advice_request', self._on_learner_request, messages.LATCHED_QOS
        )
        # Taken only while one node alone publishes it: a stranger's FAILED for the request on the
        # person's screen withdrew it, and its 'stopped' held every answer.
        self.request_guard = OnePublisher(self, requests.topic_name)

    def _check_action_size(self, spec: EnvSpec) -> None:
        """The mapping gives one value per entry of scales: the env must take as many."""
        n = len(self.params['scales'])
        if n != spec.action_size:
            raise ValueError(
                f"the mapping gives {n} action value(s) (parameter 'scales'), env {spec.name!r} takes "
                f'{spec.action_size}: set scales, offsets and axes (or twist_fields) for {spec.action_size}'
            )

    def _check_mapping(self, p) -> None:
        n = len(p['scales'])
        if len(p['offsets']) != n:
            raise ValueError(f"parameter 'offsets' has {len(p['offsets'])} values, 'scales' has {n}")
        if not all(math.isfinite(v) for v in (*p['scales'], *p['offsets'])):  # every answer would be NaN
            raise ValueError(f"parameters 'scales' {p['scales']} and 'offsets' {p['offsets']} must be finite")
        if p['source'] in ('joy', 'array') and any(a < 0 for a in p['axes']):
            raise ValueError(f"parameter 'axes' {p['axes']} holds a negative index")
        if p['source'] in ('joy', 'array') and len(p['axes']) != n:
            raise ValueError(f"parameter 'axes' has {len(p['axes'])} values, 'scales' has {n}")
        if p['source'] == 'twist':
            if len(p['twist_fields']) != n:
                raise ValueError(f"parameter 'twist_fields' has {len(p['twist_fields'])} values, 'scales' has {n}")
            unknown = [f for f in p['twist_fields'] if f not in TWIST_FIELDS]
            if unknown:
                raise ValueError(f"parameter 'twist_fields' has {unknown}; known: {TWIST_FIELDS}")

    def _on_set_parameters(self, changes) -> SetParametersResult:
        updated = dict(self.params)
        updated.update({c.name: plain(c.value) for c in changes if c.name in updated})
        try:
            self._check_mapping(updated)
        except ValueError as error:
            return SetParametersResult(successful=False, reason=str(error))
        self.params = updated
        self.expert.stale_after_s = updated['stale_after_s']
        self.expert.answer_change = updated['answer_change']
        self.expert.settle_s = updated['answer_settle_s']
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ the person's commands

    def _trusted(self) -> bool:
        refusal = self.source_guard.refusal()
        if refusal:
            self.rejected_commands += 1
            self.get_logger().error(f'commands refused: {refusal}{self._own_ui_hint()}', throttle_duration_sec=5.0)
        return not refusal

    def _own_ui_hint(self) -> str:
        """A UI of the person's own on teleop_command is refused until it is named: say how (before,
        the refusal named only the shipped drivers it expected)."""
        strangers = sorted(self.source_guard.publishing - set(self.source_guard.expected))
        if self.params['command_publisher'] or len(strangers) != 1:
            return ''
        return f' (your own UI? take its commands: -p command_publisher:={strangers[0]})'

    def _on_joy(self, msg: Joy) -> None:
        if not self._trusted():
            return
        p = self.params
        try:
            command = joy_command(
                list(msg.axes),
                list(msg.buttons),
                p['axes'],
                p['scales'],
                p['offsets'],
                p['require_enable_button'],
                p['enable_button'],
                p['answer_button'],
                p['skip_button'],
            )
        except ValueError as error:
            self.rejected_commands += 1
            self.get_logger().error(f"'joy': {error}", throttle_duration_sec=5.0)
            return
        buttons = {name: p[name] for name in ('enable_button', 'answer_button', 'skip_button')}
        if not p['require_enable_button']:
            del buttons['enable_button']
        misfit = joy_misfit(len(msg.axes), len(msg.buttons), p['axes'], buttons)
        if misfit:
            self.get_logger().warn(misfit, throttle_duration_sec=10.0)
        self._take(command)

    def _on_twist(self, msg: Twist) -> None:
        if not self._trusted():
            return
        p = self.params
        try:
            command = twist_command(
                lambda field: float(reduce(getattr, field.split('.'), msg)),
                p['twist_fields'],
                p['scales'],
                p['offsets'],
            )
        except ValueError as error:
            self.rejected_commands += 1
            self.get_logger().error(f"'cmd_vel': {error}", throttle_duration_sec=5.0)
            return
        self._take(command)

    def _on_array(self, msg: Float32MultiArray) -> None:
        if not self._trusted():
            return
        p = self.params
        try:
            fields = messages.read_fields(msg)
            if self.command_check is not None:
                refusal = self.command_check.refusal(
                    messages.command_values(fields), fields.get('counter'), fields.get('signature')
                )
                if refusal:
                    raise ValueError(f'command refused: {refusal}')
            command = array_command(fields, p['axes'], p['scales'], p['offsets'])
        except ValueError as error:
            self.rejected_commands += 1
            self.get_logger().error(f"'teleop_command': {error}", throttle_duration_sec=5.0)
            return
        self._take(command)

    def _take(self, command: Command) -> None:
        with self._lock:
            self._settle(self.expert.update(command))
        # On to the learner, which decides a takeover against its own action (mixed initiative).
        spec = self.env_info.spec
        if spec is not None and len(command.values) == spec.action_size:
            action = np.clip(command.values, spec.action_low, spec.action_high)
            self.person_pub.publish(
                messages.person_command_msg(action, command.enabled, command.take_over, self.person_seal)
            )

    # ------------------------------------------------------------------ requests

    def _take_the_key(self) -> None:
        """With key_file: teleop_command is taken only signed with it, person_command is signed on,
        and 'advise' answers only requests signed with it (a stranger's call would supersede the
        learner's open request), signing each answer. KeyFileError (a ValueError) refuses the node."""
        signer = signer_from(self.params['key_file'], self.get_logger().warning)
        if signer and self.params['source'] != 'array':
            raise ValueError(
                'key_file checks teleop_command (source array), which advice_console and keyboard_teleop sign; '
                f"'{self.params['source']}' comes from nodes that sign nothing: use SROS2 for it, or no key_file"
            )
        self.command_check = CommandCheck(signer) if signer else None
        self.person_seal = CommandSeal(signer) if signer else None
        self.request_check = request_check(signer)

    def _settle(self, advice: Advice | None) -> None:
        """Give the open request its answer (called with the lock held)."""
        if advice is None or self._waiting is None:
            return
        waiting, self._waiting = self._waiting, None
        waiting.set_result(advice)

    def _on_request_now(self, request: Advise.Request, response: Advise.Response) -> Advise.Response:
        unsigned = unsigned_request(request, response, self.request_check, self.expert.name, self.get_logger())
        if unsigned is not None:
            return unsigned
        refusal = request_refusal(request)
        if refusal:
            response = fill_response(response, Advice.decline(refusal, self.expert.name), self.expert.name)
        else:
            response = answer(self.expert, request, response, self.expert.name, self.get_logger())
        return sign_answer(response, request, self.request_check)

    async def _on_request_in_window(self, request: Advise.Request, response: Advise.Response) -> Advise.Response:
        unsigned = unsigned_request(request, response, self.request_check, self.expert.name, self.get_logger())
        if unsigned is not None:
            return unsigned
        return sign_answer(await self._in_window(request, response), request, self.request_check)

    async def _in_window(self, request: Advise.Request, response: Advise.Response) -> Advise.Response:
        """Open the request for the person, and answer with what they do within its window."""
        refusal = request_refusal(request)
        if refusal:  # declined at once: no person is alerted to a request no answer can fit
            return fill_response(response, Advice.decline(refusal, self.expert.name), self.expert.name)
        try:
            asked = request_from_msg(request)
        except FrameError as error:
            return fill_response(response, frames_refused(error, self.get_logger()), self.expert.name)
        window = self.params['answer_window_s']
        if request.timeout_s > 0:
            window = min(window, request.timeout_s - ANSWER_MARGIN_S)
        if window <= 0:
            advice = Advice.decline(
                f"the learner waits {request.timeout_s:.2f} s: no time for a person's answer", self.expert.name
            )
            return fill_response(response, advice, self.expert.name)
        future = Future()
        with self._lock:
            # A request still open is superseded: the learner has given up on it.
            self._settle(self.expert.withdraw('superseded by a newer request'))
            self.expert.open(asked)
            self._waiting = future
            self._window_s, self._window_end, self._paused_at = window, time.monotonic() + window, None
        self.get_logger().info(
            f'the learner asks for advice: episode {request.episode}, step {request.step}; answer within {window:.1f} s'
        )
        advice = await future
        self._report(advice, request)
        return fill_response(response, advice, self.expert.name)

    def _on_learner_request(self, msg: AdviceRequestMsg) -> None:
        with self._lock:
            pending = self.expert.pending
            if pending is None or (pending.request.episode, pending.request.step) != (msg.episode, msg.step):
                return
            if not self.request_guard.admits(self.get_logger(), "the learner's word on a request"):
                return
            if msg.outcome == AdviceRequestMsg.PENDING:
                self._hold_for_stop(msg.detail == 'stopped', pending)
                return
            self.ended_by_learner += 1
            reason = (
                'the episode ended first' if msg.detail == 'episode_ended' else f'the learner closed it ({msg.detail})'
            )
            self._settle(self.expert.withdraw(reason))

    def _check_settled(self) -> None:
        """Every 50 ms: a steered command that has settled answers; a window that passed ends."""
        with self._lock:
            if self._waiting is None:
                return
            self._settle(self.expert.settled())
            if self._waiting is not None and self._paused_at is None and time.monotonic() >= self._window_end:
                self._settle(self.expert.expire(self._window_s))

    def _hold_for_stop(self, stopped: bool, pending) -> None:
        """The learner says a STOP holds the open request (or has let it go): the window holds,
        and the seconds stopped are nobody's reaction time."""
        now = time.monotonic()
        self.expert.held = stopped  # no answer while stopped: the env would ignore it
        if stopped and self._paused_at is None:
            self._paused_at = now
        elif not stopped and self._paused_at is not None:
            held = now - self._paused_at
            self._window_end += held
            pending.opened += held
            if pending.steered is not None:
                pending.steered_at += held
            self._paused_at = None

    def _report(self, advice: Advice, request: Advise.Request) -> None:
        """Count and log what the person did, with their reaction time."""
        where = f'episode {request.episode}, step {request.step}'
        if advice.timed_out:
            self.answers['timed_out'] += 1
            self.get_logger().info(f'no answer for {where}: {advice.reason} (timeout)')
            return
        self.reaction_times.append(advice.response_time_s)
        if advice.advised:
            self.answers['answered'] += 1
            action = ', '.join(f'{v:+.2f}' for v in advice.action)
            self.get_logger().info(f'answered {where} after {advice.response_time_s:.2f} s: [{action}]')
        else:
            self.answers['skipped' if advice.reason == SKIPPED else 'declined'] += 1
            self.get_logger().info(f'declined {where} after {advice.response_time_s:.2f} s: {advice.reason}')


def main(args=None):
    run_node(TeleopExpertNode, args, name='teleop_expert')


if __name__ == '__main__':
    main()
