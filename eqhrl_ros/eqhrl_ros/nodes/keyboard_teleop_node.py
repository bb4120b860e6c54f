"""keyboard_teleop: advise the learner from a terminal, no joystick needed.

Keys act at once. The node publishes the current command on ``teleop_command``
(std_msgs/Float32MultiArray: command values in [-1, 1], then the enabled, answer and skip
buttons; see nodes/messages.py) at ``rate_hz`` and on every key, for a teleop_expert with
``source: array``, and shows when the learner is asking for advice (from
``learner/advice_request``). A key that changes the command answers an open request with
it, Enter answers with the command as it is, x skips. q or Ctrl-C quits and restores the
terminal.
"""

from __future__ import annotations

import os
import select
import sys
import termios
import time
import tty

import numpy as np
from rclpy.node import Node
from std_msgs.msg import Float32MultiArray

from eqhrl_interfaces.msg import AdviceRequest

from ..core.data.signing import CommandSeal, signer_from
from ..core.envs.spec import EnvSpec
from ..parameters import KEYBOARD_PARAMS
from . import messages
from .console_intake import request_shown
from .env_info import EnvInfoWatcher, configured_spec
from .graph_trust import subscribe_from_one
from .params import declare, reject_unknown_overrides
from .spinning import run_node, steady_clock

KEYS = {'a': (0, -1), 'd': (0, +1), 'w': (1, +1), 's': (1, -1)}
AXIS_KEYS = ('a/d', 'w/s')  # one pair of keys per action dimension
CLEAR, HOME, REVERSE, RESET = '\x1b[2J', '\x1b[H', '\x1b[7m', '\x1b[0m'
HIDE_CURSOR, SHOW_CURSOR = '\x1b[?25l', '\x1b[?25h'


class KeyboardTeleop(Node):
    def __init__(self, fd: int, out, **kwargs):
        super().__init__('keyboard_teleop', **kwargs)
        reject_unknown_overrides(self, KEYBOARD_PARAMS)
        self.params = declare(self, KEYBOARD_PARAMS)
        signer = signer_from(self.params['key_file'], self.get_logger().warning)
        self.seal = CommandSeal(signer) if signer else None
        self.fd, self.out = fd, out
        # The action size: the dimensions parameter, else from env_id or the env's env_info.
        self.command = np.zeros(self.params['dimensions'], dtype=np.float32)
        self.sending = True
        self.quit = False
        self.answers = 0  # presses of Enter and x (shown, so that the person sees a key landed)
        self.skips = 0
        self.request = None  # the latest advice_request fields
        self.wheel_protocol = False  # the learner asks for the wheel: t is the deadman (a toggle)
        self.holding = False  # t pressed: the person holds the wheel
        self.request_seen = 0.0
        self.action_size = None  # the env's, once known: a request's actions must be of it
        self.dropped = 0  # the learner's requests out of meaning (console_intake), not shown
        self.publisher = self.create_publisher(Float32MultiArray, 'teleop_command', 10)
        # A stranger's beside the learner's: none shown.
        self.request_guard = subscribe_from_one(
            self, AdviceRequest, 'learner/advice_request', self._on_request, messages.LATCHED_QOS
        )
        self.env_info = EnvInfoWatcher(self, configured_spec(self.params), self._on_env)
        steady = steady_clock()  # keys are read and sent whatever ROS time does (use_sim_time)
        self.create_timer(1.0 / self.params['rate_hz'], self._publish, clock=steady)
        self.create_timer(0.02, self._read_keys, clock=steady)
        self.create_timer(0.2, self.draw, clock=steady)
        self.draw()

    def _on_env(self, spec: EnvSpec) -> None:
        self.action_size = spec.action_size
        dimensions = self.params['dimensions']
        if dimensions > spec.action_size:
            raise ValueError(f'dimensions is {dimensions}, env {spec.name!r} takes {spec.action_size} action value(s)')
        if dimensions == 0:
            self.command = np.zeros(min(spec.action_size, len(AXIS_KEYS)), dtype=np.float32)
            self.draw()

    def _on_request(self, msg: AdviceRequest) -> None:
        try:  # checked by meaning, as the person's page checks it: a NaN or endless wait is no countdown
            request_shown(msg, self.action_size)
        except ValueError as error:
            self.dropped += 1
            self.get_logger().warning(
                f'a message on learner/advice_request dropped, not shown: {error} ({self.dropped} dropped so far)',
                throttle_duration_sec=5.0,
            )
            return
        before = self.request
        new = before is None or (before.episode, before.step) != (msg.episode, msg.step)
        self.request = msg
        self.request_seen = time.monotonic()
        if msg.wheel:
            # The learner asks for the wheel (advice_protocol wheel): from now on this terminal's
            # deadman is t, a toggle (a terminal hears no key releases). When a request ends, the
            # learner has the wheel again: the deadman is released here too. A new request releases
            # it as well: one held since before the request does not take it (the learner waits for
            # a press), and the screen said YOU DRIVE while the learner drove.
            self.wheel_protocol = True
            if msg.outcome != AdviceRequest.TAKEN and (msg.outcome != AdviceRequest.PENDING or new):
                self.holding = False
        self.draw()

    @property
    def enabled(self) -> bool:
        """The deadman as sent: always held for one-action answers, t toggles it for the wheel."""
        return self.holding or not self.wheel_protocol

    def _publish(self, answer: bool = False, skip: bool = False) -> None:
        if self.sending and len(self.command):
            # The request on the screen (drawn when it came), so a key meant for it never lands on a newer one.
            shown = self.request
            request = (
                (shown.episode, shown.step) if shown is not None and shown.outcome == AdviceRequest.PENDING else None
            )
            self.publisher.publish(messages.command_msg(self.command, self.enabled, answer, skip, self.seal, request))

    def _read_keys(self) -> None:
        while select.select([self.fd], [], [], 0)[0]:
            data = os.read(self.fd, 32)
            if not data:
                self.quit = True
                break
            for key in data.decode(errors='ignore'):
                self.on_key(key)
        if self.quit:
            self.context.try_shutdown()

    def on_key(self, key: str) -> None:
        key = key.lower()
        if key in KEYS and KEYS[key][0] < len(self.command):
            index, sign = KEYS[key]
            now = self.command[index]  # against the command's sign: to 0 first (a quick reversal)
            self.command[index] = 0.0 if now * sign < 0 else np.clip(now + sign * self.params['step'], -1.0, 1.0)
        elif key == ' ':
            self.command[:] = 0.0
        elif key == 't' and self.wheel_protocol:
            self.holding = not self.holding  # take the wheel, or hand it back
        elif key == 'p':
            self.sending = not self.sending
        elif key in ('q', '\x03'):
            self.quit = True
        elif key in ('\r', '\n', 'x') and self.sending and len(self.command):
            # A press: the button held in one message, released in the next (teleop_expert
            # acts on the press).
            answer = key != 'x'
            self.answers += answer
            self.skips += not answer
            self._publish(answer=answer, skip=not answer)
        self._publish()
        self.draw()

    def draw(self) -> None:
        n = len(self.command)
        lines = [
            'eqhrl_ros keyboard teleop: you are the expert',
            '',
            '  a / d : action[0] - / +' + ('      w / s : action[1] + / -' if n > 1 else ''),
            '  Enter : answer with this command     x : skip (no advice)',
            '  space : zero        p : pause/resume sending        q : quit'
            + ('        t : take the wheel / hand it back' if self.wheel_protocol else ''),
            '',
            f'  command: [{", ".join(f"{v:+.2f}" for v in self.command)}]   '
            + (
                f'sending at {self.params["rate_hz"]:g} Hz'
                if self.sending
                else 'PAUSED (the expert declines: no fresh command)'
            ),
            '',
        ]
        request = self.request
        keys = ', '.join(AXIS_KEYS[:n])  # the keys of this env's action values only
        if not n:
            lines.append('  waiting for env_info from the env (or set the dimensions parameter)')
        elif request and request.wheel and request.outcome in (AdviceRequest.PENDING, AdviceRequest.TAKEN):
            if self.holding:
                lines.append(f'{REVERSE}  >>> YOU DRIVE (asked): steer with {keys}; t hands back <<<  {RESET}')
            elif request.outcome == AdviceRequest.TAKEN:  # until the learner says how it ended
                lines.append('  you handed the wheel back: the learner drives')
            else:
                left = max(0.0, request.timeout_s - (time.monotonic() - self.request_seen))
                lines.append(
                    f'{REVERSE}  >>> THE LEARNER ASKS YOU TO TAKE THE WHEEL: press t, then steer '
                    f'({left:.1f} s left) <<<  {RESET}'
                )
        elif request and request.outcome == AdviceRequest.PENDING:
            waited = time.monotonic() - self.request_seen
            lines.append(
                f'{REVERSE}  >>> THE LEARNER ASKS FOR ADVICE: episode {request.episode}, '
                f'step {request.step}, {waited:.1f} s of {request.timeout_s:.1f} s <<<  {RESET}'
            )
            lines.append(f'  move ({keys}) or press Enter to answer, x to skip')
        elif request:
            last = messages.OUTCOME_NAMES.get(request.outcome, '?')
            if request.human:
                last += f' after {request.response_time_s:.1f} s'
            lines.append(f'  learner: no request pending (last one: {last})')
        else:
            lines.append('  learner: no request yet')
        if self.holding and not (
            request and request.wheel and request.outcome in (AdviceRequest.PENDING, AdviceRequest.TAKEN)
        ):
            # Unasked, the deadman alone drives nothing: a takeover needs the learner's takeover_threshold.
            lines.append(
                '  t held (the deadman): unasked, you drive only once your command departs from the '
                "learner's action by its takeover_threshold (0: never)"
            )
        self.out.write(HOME + CLEAR + '\r\n'.join(lines) + '\r\n')
        self.out.flush()


def main(args=None):
    fd = sys.stdin.fileno()
    if not os.isatty(fd):
        print('keyboard_teleop: needs a terminal (stdin is not a tty)', file=sys.stderr)
        raise SystemExit(1)
    saved = termios.tcgetattr(fd)
    try:
        tty.setcbreak(fd)  # keys without Enter, no echo; Ctrl-C still signals
        sys.stdout.write(HIDE_CURSOR)
        run_node(lambda: KeyboardTeleop(fd, sys.stdout), args, name='keyboard_teleop')
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)  # the terminal as we found it
        sys.stdout.write(SHOW_CURSOR + '\n')
        sys.stdout.flush()


if __name__ == '__main__':
    main()
