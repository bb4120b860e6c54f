"""Limits on the connections a small web server holds, so that idle or half-open ones never lock
a person out of their page (advice_console), and what the server logs of clients' mistakes. No ROS here.

Each accepted TCP connection goes through ``GuardedProtocol``, which hands every event to the
web server's own protocol (aiohttp's) and tells ``ConnectionGuard`` what it saw:
- at most ``max_connections`` connections at once, and ``max_per_client`` from one address;
- a connection that has not sent a whole request header (up to the blank line) within
  ``header_timeout_s`` is closed: idle and half-open connections do not stay;
- when a limit is reached, the oldest connection still without a whole header gives way to the
  new one (a page load sends its header at once); failing that, the oldest websocket (an open
  page's, or a client's holding one open), so that a person who opens the page always gets in,
  however many websockets others hold; only when every connection held is a plain request in
  progress is the new connection refused. (A client that reconnects in a loop can push a page
  out in turn: off loopback the token keeps strangers out.)
Refusals and closures are counted and logged at most once per ``log_every_s``.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import OrderedDict
from typing import Callable, Optional

from aiohttp.http_exceptions import HttpProcessingError

HEADER_END = b'\r\n\r\n'
MAX_HEADER_BYTES = 16 * 1024  # aiohttp refuses longer headers itself; past this the guard stops looking


class ConnectionGuard:
    def __init__(
        self,
        max_connections: int,
        max_per_client: int,
        header_timeout_s: float,
        log: Callable[[str], None] = print,
        log_every_s: float = 10.0,
    ):
        self.max_connections = int(max_connections)
        self.max_per_client = int(max_per_client)
        self.header_timeout_s = float(header_timeout_s)
        self._log, self._log_every_s, self._logged_at = log, log_every_s, float('-inf')
        self.open: OrderedDict = OrderedDict()  # GuardedProtocol -> client address, oldest first
        self.refused = self.evicted = self.timed_out = 0
        self._unsaid = 0

    def _say(self, what: str) -> None:
        self._unsaid += 1
        now = time.monotonic()
        if now - self._logged_at >= self._log_every_s:
            self._log(
                f'{what} ({self._unsaid} such events since the last line; {len(self.open)} connections held, '
                f'limits {self.max_connections} in all and {self.max_per_client} per client)'
            )
            self._logged_at, self._unsaid = now, 0

    def admit(self, connection: 'GuardedProtocol', client: str) -> bool:
        """Whether a new connection from ``client`` may stay, making room when it can."""
        crowds = (
            (lambda: [c for c, a in self.open.items() if a == client], self.max_per_client),
            (lambda: list(self.open), self.max_connections),
        )
        for members, limit in crowds:
            crowd = members()  # as it is now: the limit before may have made room already
            if len(crowd) >= limit:
                idle = next((c for c in crowd if not c.header_seen), None)
                kind = 'without a request'
                if idle is None:
                    idle, kind = next((c for c in crowd if c.websocket), None), '(the oldest websocket)'
                if idle is None:
                    self.refused += 1
                    self._say(f'a connection from {client} refused: every connection held is in use')
                    return False
                self.evicted += 1
                self._say(f'a connection from {self.open.get(idle)} {kind} closed to make room')
                idle.close()
                # Its connection_lost comes on a later turn of the loop: it no longer counts from now,
                # or a burst of new connections would be let in beyond the limit meanwhile.
                self.open.pop(idle, None)
        self.open[connection] = client
        return True

    def release(self, connection: 'GuardedProtocol') -> None:
        self.open.pop(connection, None)

    def header_overdue(self, connection: 'GuardedProtocol') -> None:
        self.timed_out += 1
        self._say(f'a connection from {self.open.get(connection)} closed: no whole request within the header timeout')
        connection.close()


class GuardedProtocol(asyncio.Protocol):
    """One connection: events go to ``inner`` (the web server's protocol) once admitted."""

    def __init__(self, guard: ConnectionGuard, inner_factory: Callable[[], asyncio.Protocol]):
        self.guard, self._inner_factory = guard, inner_factory
        self.inner: Optional[asyncio.Protocol] = None
        self.transport: Optional[asyncio.Transport] = None
        self.header_seen = False
        self.websocket = False  # its request asked for a websocket (a page's updates)
        self._head = b''
        self._timer: Optional[asyncio.TimerHandle] = None

    def connection_made(self, transport) -> None:
        self.transport = transport
        peer = transport.get_extra_info('peername')
        client = str(peer[0]) if peer else '?'
        if not self.guard.admit(self, client):
            transport.abort()
            return
        self._timer = asyncio.get_running_loop().call_later(
            self.guard.header_timeout_s, self.guard.header_overdue, self
        )
        self.inner = self._inner_factory()
        if isinstance(getattr(self.inner, 'logger', None), ServerLog):  # aiohttp's handler: its log names the client
            self.inner.logger = self.inner.logger.of_client(client)
        self.inner.connection_made(transport)

    def data_received(self, data: bytes) -> None:
        if not self.header_seen:
            self._head = (self._head + data)[-MAX_HEADER_BYTES:]
            if HEADER_END in self._head or len(self._head) >= MAX_HEADER_BYTES:
                self.header_seen = True  # from here on, aiohttp's own timeouts and heartbeats apply
                self.websocket = b'upgrade: websocket' in self._head.lower()
                self._head = b''
                if self._timer is not None:
                    self._timer.cancel()
        if self.inner is not None:
            self.inner.data_received(data)

    def eof_received(self):
        return self.inner.eof_received() if self.inner is not None else None

    def pause_writing(self) -> None:
        if self.inner is not None:
            self.inner.pause_writing()

    def resume_writing(self) -> None:
        if self.inner is not None:
            self.inner.resume_writing()

    def connection_lost(self, exc) -> None:
        if self._timer is not None:
            self._timer.cancel()
        self.guard.release(self)
        if self.inner is not None:
            self.inner.connection_lost(exc)

    def close(self) -> None:
        if self.transport is not None:
            self.transport.abort()


class ServerLog:
    """aiohttp's server logger for the page. A request the client got wrong (a header over 8 KiB,
    bytes that are not HTTP) was a traceback in the node's log each time, so any client could fill
    the log; it is now one line in the guard's rate-limited log. An error of the page's own code
    keeps its traceback (aiohttp's own logger)."""

    def __init__(self, guard: ConnectionGuard, client: str = ''):
        self.guard, self.client = guard, client
        self.own = logging.getLogger('aiohttp.server')

    def of_client(self, client: str) -> ServerLog:
        """This log for one connection: aiohttp before 3.10 (Ubuntu 24.04's 3.9) does not name
        the client in its line, which is what tells the person where a bad request came from."""
        return ServerLog(self.guard, client)

    def debug(self, *args, **kwargs) -> None:
        pass

    def exception(self, message: str, *args, exc_info=None, **kwargs) -> None:
        if not isinstance(exc_info, HttpProcessingError):
            self.own.exception(message, *args, exc_info=exc_info, **kwargs)
            return
        text = message % args if args else message
        if self.client and ' from ' not in text:
            text = f'{text} from {self.client}'
        reason = (str(exc_info.message) or type(exc_info).__name__).splitlines()[0][:120]
        self.guard._say(f'{text} refused ({exc_info.code}): {reason}')
