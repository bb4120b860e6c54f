"""The advice console's web server: one page and its websocket, served by aiohttp in a thread
of its own with its own asyncio loop, and everything that keeps strangers off it.

Whoever reaches the page can steer the robot. So every request must name in its ``Host``
header an address or a name this console serves (an IP address, localhost, this machine's name,
or one of ``allowed_hosts``), so that a web site whose name is made to resolve to this machine
(DNS rebinding) is refused; a ``token``, where set, is required in the page's address; a
websocket from a page of another origin is refused, so a web site open in the same browser
cannot steer; and connections are limited in number, in total and per client, with idle or
half-open ones closed (connection_guard.py), so that a flood of them cannot lock the person out.

The ROS side (advice_console_node.py) is the ``console``: the server reads its state() under its
lock when its version changes, hands it the page's input (take_input) and parameter sets
(set_learner_parameter), and sends three kinds of image, each a binary message led by one byte
that says which (IMAGE_KINDS): the env's rendering (JPEG), the frames a camera learner asked
about (one PNG, AskedFrames) and the learner's camera live (PNG, lossless, at its size).
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import errno
import hmac
import ipaddress
import json
import math
import threading
import time
from importlib import resources
from typing import Optional

import numpy as np
from aiohttp import WSMsgType, web
from sensor_msgs.msg import Image

from ..core.data import camera_frames
from ..core.data.signing import read_key
from .connection_guard import ConnectionGuard, GuardedProtocol, ServerLog
from .frame_msgs import frame_of, stack_of

MAX_PAGE_MESSAGE = 4096  # bytes; the page sends small JSON only
STOPPING = 'advice_console is stopping'  # what the page shows when the console goes
# The first byte of an image sent to the page: which image it is (console.js reads the same).
IMAGE_KINDS = {'env': b'E', 'asked': b'A', 'camera': b'C'}
# What the browser is told with every response: only the page's own script runs (markup from
# another node that got into the page would not run), it talks to this server only, no other site
# may frame it (a framed STOP or RESUME under a decoy: clickjacking), and the token in its address
# is never sent on as a referrer.
PAGE_HEADERS = {
    'Content-Security-Policy': (
        "default-src 'none'; script-src 'self'; connect-src 'self'; img-src 'self' blob: data:; "
        "style-src 'self' 'unsafe-inline'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'"
    ),
    'X-Frame-Options': 'DENY',
    'X-Content-Type-Options': 'nosniff',
    'Referrer-Policy': 'no-referrer',
}


def page_token(params: dict) -> str:
    """The secret the page's address must carry: token_file's content, or the token parameter
    ('': none). ValueError (a start-up refusal) when both are given or the file cannot be one."""
    if params['token'] and params['token_file']:
        raise ValueError('give token or token_file, not both')
    if not params['token_file']:
        return params['token']
    secret = read_key(params['token_file'], 'token file')
    try:
        return secret.decode('ascii')
    except UnicodeDecodeError:
        raise ValueError(
            f'token file {params["token_file"]}: the token must be ASCII text (it goes in an address)'
        ) from None


def page_url(host: str, port: int, token: str) -> str:
    shown_host = f'[{host}]' if ':' in host else host
    return f'http://{shown_host}:{port}/' + (f'?token={token}' if token else '')


def is_loopback(host: str) -> bool:
    if host == 'localhost':
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def host_name(host_header: str) -> str:
    """The name or address of a Host header, without the port ('[::1]:8080' -> '::1')."""
    host = host_header.strip().lower()
    if host.startswith('['):
        return host[1 : host.index(']')] if ']' in host else host
    return host.rsplit(':', 1)[0] if host.count(':') == 1 else host


def host_allowed(host_header: str, names) -> bool:
    """A Host header a page of this console can carry: an IP address (a browser that was given
    the address itself, which DNS rebinding cannot produce), or one of ``names``."""
    host = host_name(host_header)
    try:
        ipaddress.ip_address(host)
        return True
    except ValueError:
        return host in names


@dataclasses.dataclass(frozen=True)
class AskedFrames:
    """The frames a camera learner asked about, as the page shows them: one lossless PNG, the
    stack side by side, oldest left, each pixel as the learner reads it."""

    episode: int
    step: int
    stack: int
    height: int
    width: int
    channels: int
    png: bytes

    @classmethod
    def of(cls, episode: int, step: int, pixels: np.ndarray) -> 'AskedFrames':
        k, height, width, channels = pixels.shape
        return cls(int(episode), int(step), k, height, width, channels, camera_frames.png_bytes(pixels))

    @classmethod
    def of_request(cls, msg, shown: Optional['AskedFrames'], logger) -> Optional['AskedFrames']:
        """A learner/advice_request's frames as the page shows them, or None: none, or those of the
        request ``shown`` already (a request is published again as it resolves). Frames that cannot
        be one stack (another node's bytes) are logged, and change nothing."""
        if not msg.frames or (shown is not None and (shown.episode, shown.step) == (msg.episode, msg.step)):
            return None
        try:
            return cls.of(msg.episode, msg.step, stack_of(msg.frames))
        except camera_frames.FrameError as error:
            logger.warning(f"a request's frames refused: {error}", throttle_duration_sec=5.0)
            return None

    def shown(self) -> dict:
        """What the page says of them (the PNG goes apart, once)."""
        encoding = camera_frames.SENT_ENCODINGS[self.channels]
        return {
            'episode': self.episode,
            'step': self.step,
            'stack': self.stack,
            'height': self.height,
            'width': self.width,
            'encoding': encoding,
        }


def jpeg(frame: Image, quality: int) -> Optional[bytes]:
    """A sensor_msgs/Image as JPEG bytes (None for a frame core.data.camera_frames refuses)."""
    try:
        pixels = frame_of(frame)
    except camera_frames.FrameError:
        return None
    return camera_frames.jpeg_bytes(pixels, quality)


def _static(name: str) -> str:
    return resources.files('eqhrl_ros').joinpath('web', name).read_text()


def page_json(state) -> str:
    """The state as JSON a browser parses: a number that is not finite becomes null (JSON has no
    NaN, and a page's JSON.parse refused the whole state that held one: the page froze). What the
    console takes is checked by meaning first (console_intake.py); this is the last guard, for
    what it reads besides (the learner's and teleop_expert's parameters)."""

    def finite(value):
        if isinstance(value, float):
            return value if math.isfinite(value) else None
        if isinstance(value, dict):
            return {key: finite(v) for key, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [finite(v) for v in value]
        return value

    return json.dumps(finite(state), allow_nan=False)


async def _add_page_headers(request: web.Request, response: web.StreamResponse) -> None:
    response.headers.update(PAGE_HEADERS)


class ConsoleServer:
    """The page's HTTP server for ``console`` (module docstring); ``start()`` raises OSError when
    it cannot serve (the port taken, the host unknown)."""

    def __init__(self, console, params: dict, allowed_names: set, log_warning):
        self.console = console
        self.params = params
        self.allowed_names = allowed_names
        self.guard = ConnectionGuard(
            params['max_connections'], params['max_connections_per_client'], params['header_timeout_s'], log_warning
        )
        self.port = 0
        self._loop = asyncio.new_event_loop()
        self._runner: Optional[web.AppRunner] = None
        self._server = None
        self._server_ready = threading.Event()
        self._server_error: Optional[BaseException] = None
        self._sockets: set = set()  # (web thread only) closed at shutdown
        self._thread = threading.Thread(target=self._serve, name='advice_console_http', daemon=True)

    def start(self) -> None:
        self._thread.start()
        self._server_ready.wait(10.0)
        if self._server_error is not None:
            taken = getattr(self._server_error, 'errno', None) == errno.EADDRINUSE
            raise OSError(
                f'cannot serve on {self.params["host"]}:{self.params["port"]}: {self._server_error}'
                + (
                    " (a second robot's page? give each its own: -p port:=8081, or port:=0 for any free one)"
                    if taken
                    else ''
                )
            )

    def _serve(self) -> None:
        asyncio.set_event_loop(self._loop)
        try:
            self._loop.run_until_complete(self._start_server())
        except BaseException as error:  # the port is taken, the host is unknown: said at start-up
            self._server_error = error
            self._server_ready.set()
            return
        self._server_ready.set()
        self._loop.run_forever()

    async def _start_server(self) -> None:
        app = web.Application(client_max_size=MAX_PAGE_MESSAGE, middlewares=[self._check_host])
        app.router.add_get('/', self._page)
        app.router.add_get('/console.js', self._script)
        app.router.add_get('/ws', self._websocket)
        app.on_response_prepare.append(_add_page_headers)
        # A short keep-alive: a connection that made its request and then idles gives its place back.
        self._runner = web.AppRunner(app, access_log=None, keepalive_timeout=5.0, logger=ServerLog(self.guard))
        await self._runner.setup()
        server = self._runner.server
        self._server = await self._loop.create_server(
            lambda: GuardedProtocol(self.guard, server), self.params['host'], self.params['port']
        )
        self.port = self._server.sockets[0].getsockname()[1]  # the port given, or the one chosen for port 0

    @web.middleware
    async def _check_host(self, request: web.Request, handler):
        if not host_allowed(request.host, self.allowed_names):
            # DNS rebinding: another site's name resolved to this machine. Its page must not load.
            raise web.HTTPForbidden(
                text=f'advice_console: {host_name(request.host)!r} is not a name this console serves '
                '(open it by its address, or add the name to allowed_hosts)'
            )
        return await handler(request)

    def _authorized(self, request: web.Request) -> bool:
        token = self.console.token
        # As bytes: compare_digest raises TypeError on a str beyond ASCII (a guess of ?token=%C3%A9).
        given = request.query.get('token', '').encode('utf-8', 'surrogateescape')
        return not token or hmac.compare_digest(given, token.encode())

    async def _page(self, request: web.Request) -> web.Response:
        if not self._authorized(request):
            raise web.HTTPForbidden(text='advice_console: a token is required (?token=...)')
        return web.Response(text=_static('console.html'), content_type='text/html')

    async def _script(self, request: web.Request) -> web.Response:
        # The script holds no secret and steers nothing by itself: served without the token.
        return web.Response(text=_static('console.js'), content_type='application/javascript')

    async def _websocket(self, request: web.Request) -> web.WebSocketResponse:
        if not self._authorized(request):
            raise web.HTTPForbidden(text='advice_console: a token is required (?token=...)')
        origin = request.headers.get('Origin')
        if origin is not None and origin != f'{request.scheme}://{request.host}':
            # A page of another site, open in the same browser, must not steer the robot.
            raise web.HTTPForbidden(text=f'advice_console: websocket from another origin ({origin}) refused')
        socket = web.WebSocketResponse(max_msg_size=MAX_PAGE_MESSAGE, heartbeat=10.0)
        await socket.prepare(request)
        self._sockets.add(socket)
        with self.console.lock:
            self.console.pages += 1
        sender = asyncio.ensure_future(self._send_updates(socket))
        try:
            async for message in socket:
                if message.type != WSMsgType.TEXT:
                    continue
                await self._on_page_message(socket, message.data)
        finally:
            sender.cancel()
            self._sockets.discard(socket)
            with self.console.lock:
                self.console.pages -= 1
        return socket

    async def _on_page_message(self, socket: web.WebSocketResponse, text: str) -> None:
        try:
            data = json.loads(text)
            if not isinstance(data, dict):
                raise ValueError('not an object')
        except (ValueError, RecursionError):  # RecursionError: '[[[[…]]]]', nested deeper than json reads
            await socket.send_json({'type': 'error', 'error': 'messages must be JSON objects'})
            return
        if data.get('type') == 'set':
            ok, reason = await self._loop.run_in_executor(
                None, self.console.set_learner_parameter, data.get('name'), data.get('value')
            )
            await socket.send_json(
                {'type': 'set_result', 'name': data.get('name'), 'value': data.get('value'), 'ok': ok, 'reason': reason}
            )
            return
        error = self.console.take_input(data)
        if error:
            await socket.send_json({'type': 'error', 'error': error})

    async def _send_updates(self, socket: web.WebSocketResponse) -> None:
        """State when it changes (and 5 times a second while a request is open or the person
        drives, for the countdowns); frames at most image_rate_hz."""
        sent_version, sent_frame, last_frame_time, last_state_time, sent_asked = -1, 0, 0.0, 0.0, 0
        sent_camera, last_camera_time = 0, 0.0
        frame_period = 1.0 / self.params['image_rate_hz']
        while not socket.closed:
            now = time.monotonic()
            console = self.console
            with console.lock:
                live = console.counting_down()
                state = None
                if console.version != sent_version or (live and now - last_state_time > 0.2):
                    state, sent_version, last_state_time = console.state(), console.version, now
                frame = None
                if console.frame_number != sent_frame and now - last_frame_time >= frame_period:
                    frame, sent_frame, last_frame_time = console.frame, console.frame_number, now
                asked = None
                if console.asked_number != sent_asked and console.asked is not None:
                    asked, sent_asked = console.asked.png, console.asked_number
                camera, seen = console.learner_camera.latest, console.learner_camera.number
                if camera is None or seen == sent_camera or now - last_camera_time < frame_period:
                    camera = None
                else:
                    sent_camera, last_camera_time = seen, now
            if asked is not None:  # before the state that captions it
                await socket.send_bytes(IMAGE_KINDS['asked'] + asked)
            if camera is not None:
                png = await self._loop.run_in_executor(None, camera_frames.png_bytes, camera[None])
                await socket.send_bytes(IMAGE_KINDS['camera'] + png)
            if state is not None:
                await socket.send_str(page_json(state))
            if frame is not None:
                data = await self._loop.run_in_executor(None, jpeg, frame, self.params['jpeg_quality'])
                if data:
                    await socket.send_bytes(IMAGE_KINDS['env'] + data)
            await asyncio.sleep(0.03)

    def stop(self) -> None:
        """Close the pages (they show \"disconnected\" and retry), the server and its thread."""
        if self._loop.is_running():

            async def stop():
                for page in list(self._sockets):  # the page shows "disconnected" and retries
                    # Said first as a message: the close frame's reason is lost where aiohttp's own
                    # end of the handler closes first (3.9, Ubuntu 24.04's python3-aiohttp: code 1000).
                    with contextlib.suppress(ConnectionError, RuntimeError):
                        await page.send_json({'type': 'stopping', 'reason': STOPPING})
                    await page.close(code=1001, message=STOPPING.encode())
                if getattr(self, '_server', None) is not None:
                    self._server.close()
                if self._runner is not None:
                    await self._runner.cleanup()

            try:
                asyncio.run_coroutine_threadsafe(stop(), self._loop).result(timeout=5.0)
            except Exception:  # already stopping: the thread is a daemon either way
                pass
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(timeout=5.0)
        if not self._thread.is_alive() and not self._loop.is_closed():
            self._loop.close()
