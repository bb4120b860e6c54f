"""advice_console: the person's page in a browser, for teleop_expert (source: array).

This node is the ROS side; the page and its web server, with the security that keeps strangers
off it, are console_server.py. Over one websocket per open page it sends
- to the page: the env's frames (JPEG, from the image topic), the learner's requests
  (``learner/advice_request``) with a camera learner's frames asked about (PNG, as it reads
  them), episode statistics (``learner/episode_stats``), the env's spaces (``env_info``),
  the learner's advising parameters and whether advice is open now
  (core/algorithm/advice_window.py, computed from those parameters and statistics);
- from the page: the person's command, deadman, answer and skip (keyboard or gamepad),
  published on ``teleop_command`` exactly as keyboard_teleop publishes it, and parameter
  sets on the learner (pause advice, budget), range-checked by the learner itself.

Whoever reaches the page can steer the robot: it binds to localhost unless ``host`` says
otherwise, and then a ``token`` is required in the page's address.
"""

from __future__ import annotations

import math
import threading
import time
from socket import gethostname
from typing import Optional

from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from sensor_msgs.msg import Image
from std_msgs.msg import Bool, Float32MultiArray, String

from eqhrl_interfaces.msg import AdviceRequest, EpisodeStats

from ..core.algorithm.advice_window import advice_window
from ..core.algorithm.config import advice_protocol, check_value
from ..core.data.signing import CommandSeal, signer_from
from ..core.envs.spec import EnvSpec
from ..parameters import CONSOLE_PARAMS, LEARNER_CONFIG_PARAMS, LEARNER_NODE_PARAMS, TELEOP_EXPERT_PARAMS
from . import messages
from .console_camera import LearnerCamera
from .console_intake import parameters_shown, request_shown, stats_shown
from .console_server import AskedFrames, ConsoleServer, host_allowed, host_name, is_loopback, page_token, page_url  # noqa: F401
from .env_info import EnvInfoWatcher, configured_spec, shown
from .graph_trust import subscribe_from_one, subscribe_stop
from .params import declare, reject_unknown_overrides
from .spinning import run_node, steady_clock
from .teleop_expert_node import ANSWER_MARGIN_S

# The learner parameters the page shows and may set.
LEARNER_CONTROLS = ('advice_enabled', 'advising_budget', 'advising_budget_s')
LEARNER_TABLES = (LEARNER_CONFIG_PARAMS, LEARNER_NODE_PARAMS)  # what the values read from the learner are checked by
# Read, not set: what the page says about the run's end, how a request asks and when steering takes over.
LEARNER_SHOWN = (*LEARNER_CONTROLS, 'max_episodes', 'mode')
# Read apart: a learner without them (an older one, a stand-in) still gets the rest of the page.
LEARNER_PROTOCOL = ('advice_protocol', 'takeover_threshold')
LEARNER_CAMERA = ('camera', 'camera_transport', 'camera_publisher')  # the camera the page shows live
DRIVERS = ('learner', 'person_asked', 'person_unasked')  # learner/driver (nodes/person_wheel.py)
RECENT_KEPT = 8  # requests ended, shown on the page (one ended 30 ms before the next is still seen)
# teleop_expert's: how long the person has per request and how a command becomes an action.
TELEOP_SETTINGS = ('answer_window_s', 'axes', 'scales', 'offsets')
# A page's input older than this is not the person's any more (the tab was closed or hidden).
INPUT_STALE_S = 1.0
EPISODES_KEPT = 10_000


class PageInput:
    """What the person's page says now: the command in [-1, 1] and the deadman."""

    def __init__(self):
        self.command: list[float] = []
        self.deadman = False
        self.request = None  # (episode, step) of the request the page showed at that input
        self.take_over = False  # T held: take over unasked
        self.received = 0.0  # time.monotonic() of the page's latest input


class AdviceConsole(Node):
    def __init__(self, **kwargs):
        super().__init__('advice_console', **kwargs)
        reject_unknown_overrides(self, CONSOLE_PARAMS)
        self.params = p = declare(self, CONSOLE_PARAMS)
        self.token = page_token(p)  # never logged: /rosout is the graph's
        if not is_loopback(p['host']) and not self.token:
            raise ValueError(
                f'host {p["host"]!r} lets other machines reach the page, and whoever reaches it can steer '
                'the robot: set a token_file (the page is then opened with ?token=<its content>)'
            )
        self.allowed_names = {
            'localhost',
            gethostname().lower(),
            p['host'].lower(),
            *(n.strip().lower() for n in (p['allowed_hosts'] or []) if n.strip()),
        }
        signer = signer_from(
            p['key_file'], self.get_logger().warning
        )  # KeyFileError (a ValueError): refused at start-up
        self.seal = CommandSeal(signer) if signer else None
        self.lock = threading.Lock()
        self._changed = threading.Condition(self.lock)
        self.version = 0  # bumped on every change the page must see
        self.spec: Optional[EnvSpec] = None
        self.request: Optional[dict] = None
        self.request_seen = 0.0
        self.episodes: list[dict] = []
        self.person_s_open: dict = {}  # (episode, step) -> the person's seconds on a request, not yet in stats
        self.recent: list[dict] = []  # the latest requests that ended, newest last
        self.driver = 'learner'  # who drives now (learner/driver)
        self.driver_since = time.monotonic()
        self.takeover_s_open: dict = {}  # episode -> seconds of unasked takeovers, not yet in stats
        self.learner_params: dict = {}
        self.frame: Optional[Image] = None
        self.frame_number = 0
        self.asked: Optional[AskedFrames] = None  # a camera learner's frames of the latest request with frames
        self.asked_number = 0
        self.learner_camera = LearnerCamera(self, self._on_camera_frame)  # follows the learner's camera parameters
        self._camera_said = 0.0  # time.monotonic() the page was last told of refused camera frames
        self.input = PageInput()
        self.pages = 0  # open websockets
        self.dropped = 0  # the learner's messages out of meaning (console_intake), not shown
        self.published = 0

        self.publisher = self.create_publisher(Float32MultiArray, 'teleop_command', 10)
        # The person's STOP: latched, so that an env node that (re)starts while stopped stays stopped.
        self.stopped = False
        self.stop_pub = self.create_publisher(Bool, messages.STOP_TOPIC, messages.STOP_QOS)
        self.stop_guard = subscribe_stop(self, self._on_stop)  # as the envs take it: the page shows what holds
        # What the page shows of the learner and the env: never a stranger's beside theirs.
        self.shown_from_one = [
            subscribe_from_one(self, AdviceRequest, 'learner/advice_request', self._on_request, messages.LATCHED_QOS),
            subscribe_from_one(self, EpisodeStats, 'learner/episode_stats', self._on_stats, 100),
            subscribe_from_one(self, String, 'learner/driver', self._on_driver, messages.LATCHED_QOS),
            subscribe_from_one(self, Image, p['image_topic'], self._on_frame, 2),
        ]
        self.env_info = EnvInfoWatcher(self, configured_spec(p), self._on_env)
        self.learner_client = AsyncParameterClient(self, p['learner_node'])
        self.teleop_client = AsyncParameterClient(self, p['teleop_node'])
        self.teleop: dict = {}
        steady = steady_clock()
        self.create_timer(1.0 / p['rate_hz'], self._publish_held, clock=steady)
        self.create_timer(1.0, self._refresh_learner_params, clock=steady)

        self.server = ConsoleServer(self, p, self.allowed_names, self.get_logger().warning)
        self.server.start()
        self._say_where()

    @property
    def guard(self):
        return self.server.guard

    @property
    def port(self) -> int:
        return self.server.port

    @property
    def url(self) -> str:
        return page_url(self.params['host'], self.port, self.token)

    def _say_where(self) -> None:
        """The page's address in the log, its token as a placeholder: the log goes to /rosout."""
        if not self.token:
            self.get_logger().info(f'the person opens {self.url} (whoever reaches it can steer the robot)')
            return
        where = 'token_file' if self.params['token_file'] else 'the token parameter'
        self.get_logger().info(
            f'the person opens {page_url(self.params["host"], self.port, "<token>")}, <token> as in {where}'
        )
        if not self.params['token_file']:
            self.get_logger().warning(
                'the token parameter can be read by any node on the ROS graph (ros2 param get /advice_console '
                'token): give it in a token_file instead'
            )

    # ------------------------------------------------------------------ ROS side

    def _bump(self) -> None:
        self.version += 1
        self._changed.notify_all()

    def _on_env(self, spec: EnvSpec) -> None:
        with self.lock:
            self.spec = spec
            self.input.command = [0.0] * spec.action_size
            self._follow_camera()
            self._bump()

    def _on_request(self, msg: AdviceRequest) -> None:
        try:
            request = request_shown(msg, self.spec.action_size if self.spec is not None else None)
        except ValueError as why:
            self._drop('learner/advice_request', why)
            return
        # Decoded and encoded before the lock: the page waits for nothing.
        asked = AskedFrames.of_request(msg, self.asked, self.get_logger())
        with self.lock:
            if asked is not None and asked != self.asked:
                self.asked, self.asked_number = asked, self.asked_number + 1
            self.request = request
            self.request_seen = time.monotonic()
            done = msg.outcome not in (AdviceRequest.PENDING, AdviceRequest.TAKEN)
            if done:
                self.recent = [*self.recent, self.request][-RECENT_KEPT:]
            if done and msg.human:  # its seconds checked by request_shown
                # The person's seconds on this request, until its episode's statistics count them:
                # the page's budget in seconds runs down request by request, not episode by episode.
                self.person_s_open[(msg.episode, msg.step)] = float(msg.response_time_s)
            self._bump()

    def _on_stats(self, msg: EpisodeStats) -> None:
        try:
            episode = stats_shown(msg)
        except ValueError as why:
            self._drop('learner/episode_stats', why)
            return
        with self.lock:
            self.episodes.append(episode)
            del self.episodes[:-EPISODES_KEPT]
            self.person_s_open = {k: s for k, s in self.person_s_open.items() if k[0] > msg.episode}
            self.takeover_s_open = {k: s for k, s in self.takeover_s_open.items() if k > msg.episode}
            self._bump()

    def _drop(self, topic: str, why: ValueError) -> None:
        self.dropped += 1
        self.get_logger().warning(
            f'a message on {topic} dropped, not shown on the page: {why} ({self.dropped} dropped so far)',
            throttle_duration_sec=5.0,
        )

    def _on_driver(self, msg: String) -> None:
        with self.lock:
            driver = msg.data if msg.data in DRIVERS else 'learner'
            now = time.monotonic()
            if self.driver == 'person_unasked':  # a takeover's seconds, until its episode's stats count them
                episode = self._episode_now()
                self.takeover_s_open[episode] = self.takeover_s_open.get(episode, 0.0) + now - self.driver_since
            self.driver, self.driver_since = driver, now
            self._bump()

    def _episode_now(self) -> int:
        return self.episodes[-1]['episode'] + 1 if self.episodes else 0

    def counting_down(self) -> bool:
        """(with the lock held) A request is open or the person drives: the page's clocks run."""
        open_request = self.request is not None and self.request['outcome'] in ('pending', 'taken')
        return open_request or self.driver != 'learner'

    def person_seconds_open(self) -> float:
        """(with the lock held) The person's seconds not yet in episode statistics: requests ended
        since, unasked takeovers, and the open request or takeover, running now."""
        now = time.monotonic()
        running = 0.0
        request = self.request
        if request is not None and request['outcome'] in ('pending', 'taken') and request['wheel']:
            if request['detail'] != 'stopped':
                running = now - self.request_seen + request['response_time_s']
        if self.driver == 'person_unasked':
            running += now - self.driver_since
        return sum(self.person_s_open.values()) + sum(self.takeover_s_open.values()) + running

    def _on_frame(self, msg: Image) -> None:
        with self.lock:
            self.frame = msg
            self.frame_number += 1
            self._changed.notify_all()

    def _publish_held(self) -> None:
        """Keep the person's command fresh on teleop_command while a page is open and live."""
        with self.lock:
            live = self.pages and self.input.command and time.monotonic() - self.input.received < INPUT_STALE_S
            if live:
                self._publish(False, False)

    def _publish(self, answer: bool, skip: bool) -> None:
        """(with the lock held) The page's command and buttons, as keyboard_teleop sends them."""
        enabled = self.input.deadman or not self.params['require_deadman']
        self.publisher.publish(
            messages.command_msg(
                self.input.command, enabled, answer, skip, self.seal, self.input.request, self.input.take_over
            )
        )
        self.published += 1

    def _refresh_learner_params(self) -> None:
        if self.teleop_client.services_are_ready():
            self.teleop_client.get_parameters(list(TELEOP_SETTINGS)).add_done_callback(self._on_teleop_settings)
        if not self.learner_client.services_are_ready():
            return
        for names in (LEARNER_SHOWN, LEARNER_PROTOCOL, LEARNER_CAMERA):
            future = self.learner_client.get_parameters(list(names))
            future.add_done_callback(lambda f, names=names: self._on_learner_params(f, names))

    def _on_teleop_settings(self, future) -> None:
        read = parameters_shown(future, TELEOP_SETTINGS, self.params['teleop_node'], (TELEOP_EXPERT_PARAMS,), self)
        if set(read) != set(TELEOP_SETTINGS):
            return
        with self.lock:
            if read != self.teleop:
                self.teleop = read
                self._bump()

    def _on_learner_params(self, future, names: tuple) -> None:
        read = parameters_shown(future, names, self.params['learner_node'], LEARNER_TABLES, self)  # {}: gone, or odd
        if not read:
            return
        with self.lock:
            known = {name: value for name, value in self.learner_params.items() if name not in names}
            if {**known, **read} != self.learner_params:
                self.learner_params = {**known, **read}
                self._follow_camera()
                self._bump()

    def _follow_camera(self) -> None:
        """(with the lock held) Show the camera the learner reads, once its parameters and env_info
        name it (none for a learner without one, or one the env does not announce)."""
        learner, spec = self.learner_params, self.spec
        name = learner.get('camera') or ''
        cameras = {c.name: c for c in spec.cameras} if spec is not None else {}
        self.learner_camera.follow(
            cameras.get(name), learner.get('camera_transport', 'raw'), learner.get('camera_publisher', '')
        )

    def _on_camera_frame(self, refused: bool) -> None:
        """A frame to send; a refusal, said on the page within a second (not once a frame: a flood)."""
        with self.lock:
            now = time.monotonic()
            if refused and now - self._camera_said >= 1.0:
                self._camera_said = now
                self._bump()
            self._changed.notify_all()

    # ------------------------------------------------------------------ the page's input

    def _on_stop(self, msg: Bool) -> None:
        with self.lock:
            if bool(msg.data) != self.stopped:
                self.stopped = bool(msg.data)
                self._bump()

    def set_stop(self, stopped: bool) -> Optional[str]:
        """STOP (or release it): published at once, latched, for every env node on the graph. A
        release while another node publishes /stop is not made (the envs would refuse it): why not."""
        if not stopped and self.stop_guard.refusal():
            return f'not released, the robot stays stopped: {self.stop_guard.refusal()}'
        with self.lock:
            self.stopped = stopped
            self._bump()
        self.stop_pub.publish(Bool(data=stopped))
        self.get_logger().warn('STOP pressed on the page' if stopped else 'stop released on the page')

    def take_input(self, data: dict) -> Optional[str]:
        """A message from the page; returns an error text for the page, or None."""
        kind = data.get('type')
        if kind == 'stop':
            if not isinstance(data.get('stopped'), bool):
                return 'stop needs stopped: true or false'
            return self.set_stop(data['stopped'])
        if kind == 'input':
            with self.lock:
                size = len(self.input.command)
                command = data.get('command')
                if not isinstance(command, list) or len(command) != size:
                    return f'command must be a list of {size} numbers'
                try:
                    values = [float(v) for v in command]
                except (TypeError, ValueError, OverflowError):  # OverflowError: an integer of 400 digits
                    return 'command must hold numbers'
                if not all(math.isfinite(v) for v in values):
                    return 'command must be finite'
                self.input.command = [min(1.0, max(-1.0, v)) for v in values]
                self.input.deadman = data.get('deadman') is True
                self.input.take_over = data.get('take_over') is True
                seen = data.get('request')  # [episode, step] of the request on the person's screen
                ok = isinstance(seen, list) and len(seen) == 2 and all(type(v) is int and 0 <= v < 2**31 for v in seen)
                self.input.request = tuple(seen) if ok else None
                self.input.received = time.monotonic()
                answer, skip = data.get('answer') is True, data.get('skip') is True
                if answer or skip:
                    self._publish(answer, skip)  # the press, then its release
                self._publish(False, False)
            return None
        if kind == 'set':
            return 'parameter sets are answered asynchronously'  # handled by the websocket loop
        return f'unknown message type {kind!r}'

    def state(self) -> dict:
        """(with the lock held) Everything the page shows, as JSON-able data."""
        spec = self.spec
        request = dict(self.request) if self.request else None
        if request and request['outcome'] in ('pending', 'taken'):
            request['waited_s'] = 0.0 if request['detail'] == 'stopped' else time.monotonic() - self.request_seen
        learner = self.learner_params
        return {
            'type': 'state',
            'version': self.version,
            'env': None
            if spec is None
            else {
                'name': shown(spec.name),
                'action_low': [float(v) for v in spec.action_low],
                'action_high': [float(v) for v in spec.action_high],
                'action_labels': list(spec.action_labels or []),
            },
            'request': request,
            # What the learner saw at the latest request with frames (the PNG goes as its own message).
            'asked_frames': self.asked.shown() if self.asked else None,
            'camera': self.learner_camera.shown(),  # the learner's camera, live (its frames go apart)
            'episodes': self.episodes[-500:],
            'learner': self.learner_params,
            'advice_window': self.advice_window(),
            'require_deadman': self.params['require_deadman'],
            'stopped': self.stopped,
            # The person's seconds of episodes whose statistics have not come yet, the open ones' included.
            'person_s_open': self.person_seconds_open(),
            'recent': self.recent,
            'driver': self.driver,
            # How a request asks (the learner's advice_protocol for this env's pace); null until known.
            'protocol': advice_protocol(learner['advice_protocol'], spec.realtime)
            if spec is not None and learner.get('advice_protocol') in ('auto', 'answer', 'wheel')
            else None,
            # Steering away takes over only where the learner's threshold is on (the legend says so).
            'takeover_threshold': learner.get('takeover_threshold'),
            # The page counts down this window and draws each action as teleop_expert maps it.
            'teleop': dict(self.teleop, answer_margin_s=ANSWER_MARGIN_S) if self.teleop else None,
            'command': list(self.input.command),
            'key_step': self.params['step'],
        }

    def advice_window(self) -> Optional[dict]:
        """(with the lock held) Whether advice is open now, as the learner decides it
        (advice_window.py), from its parameters and its finished episodes; None until known."""
        learner = self.learner_params
        if not {'mode', 'advising_budget', 'advising_budget_s'} <= learner.keys():
            return None
        last = self.episodes[-1] if self.episodes else None
        episode = last['episode'] + 1 if last else 0  # the episode running now
        spent = (last['human_time_total_s'] if last else 0.0) + self.person_seconds_open()
        window = advice_window(
            learner['mode'], learner['advising_budget'], learner['advising_budget_s'], episode, spent
        )
        return window.to_dict()

    def set_learner_parameter(self, name: str, value) -> tuple[bool, str]:
        """Set one of LEARNER_CONTROLS on the learner (from the web thread); (ok, reason)."""
        if name not in LEARNER_CONTROLS:
            return False, f'{name!r} is not one of {LEARNER_CONTROLS}'
        if name == 'advice_enabled' and not isinstance(value, bool):
            return False, 'advice_enabled must be true or false'
        if name == 'advising_budget':
            if isinstance(value, bool) or not isinstance(value, int):
                return False, 'advising_budget must be an integer'
            try:
                check_value('advising_budget', value)  # the learner's own range, before any ROS call
            except ValueError as error:
                return False, str(error)
        if name == 'advising_budget_s':
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                return False, 'advising_budget_s must be a number of seconds'
            try:
                value = check_value('advising_budget_s', float(value))
            except (ValueError, OverflowError) as error:
                return False, str(error)
        if not self.learner_client.services_are_ready():
            return False, f'no learner parameter service at {self.params["learner_node"]}'
        try:
            future = self.learner_client.set_parameters([Parameter(name, value=value)])
        except Exception as error:  # a value rclpy cannot carry: said to the page, never raised
            return False, f'{name} = {value!r:.40} cannot be set: {error}'
        deadline = time.monotonic() + 5.0
        while not future.done() and time.monotonic() < deadline:
            time.sleep(0.01)
        if not future.done():
            return False, 'the learner did not answer within 5 s'
        result = future.result().results[0]
        if result.successful:
            with self.lock:
                self.learner_params[name] = value
                self._bump()
        return result.successful, result.reason

    def destroy_node(self) -> None:
        self.server.stop()
        super().destroy_node()


def main(args=None):
    run_node(AdviceConsole, args, name='advice_console')


if __name__ == '__main__':
    main()
