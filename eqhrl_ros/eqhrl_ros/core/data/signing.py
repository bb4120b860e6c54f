"""A shared key for one deployment: who sent a message, where SROS2 is not to be had. No ROS here.

With ``key_file`` set on its nodes, the trainer signs its weights, each actor its transition
batches and the person's input drivers (advice_console, keyboard_teleop) their commands; each
receiver refuses what is unsigned or signed with another key. The signature is an HMAC-SHA256
(Python's hmac and hashlib) over the message's kind, its sender, its sequence number and its
content, so that a stranger on the graph can neither forge a message nor move one to another
sender or sequence number (a replayed message carries a sequence number already passed).

This is integrity and authenticity only: anyone on the graph still reads everything, and
whoever holds the key file is trusted. SROS2 (DDS security) encrypts and controls access too;
use it where the middleware has its security plugins (a regular ROS 2 install).
"""

from __future__ import annotations

import hashlib
import hmac
import os
import stat
import struct
from pathlib import Path
from typing import Iterable, Optional

MIN_KEY_BYTES = 16
MAX_KEY_BYTES = 4096
SIGNATURE_BYTES = 32  # SHA-256


class KeyFileError(ValueError):
    """A key file that cannot serve: missing, unreadable, too short or too long."""


def read_key(path, what: str = 'key file') -> bytes:
    """The secret in ``path`` (surrounding whitespace stripped), or KeyFileError saying why not."""
    path = Path(path)
    try:
        info = path.stat()
        if info.st_size > MAX_KEY_BYTES:
            raise KeyFileError(f'{what} {path}: {info.st_size} bytes; a secret is {MIN_KEY_BYTES} to {MAX_KEY_BYTES}')
        key = path.read_bytes().strip()
    except OSError as error:
        raise KeyFileError(f'{what} {path}: cannot be read ({error.strerror or error})') from None
    if len(key) < MIN_KEY_BYTES:
        raise KeyFileError(
            f'{what} {path}: {len(key)} bytes; at least {MIN_KEY_BYTES} (e.g. '
            f"python3 -c 'import secrets; print(secrets.token_hex(32))' > {path.name})"
        )
    return key


def key_readable_by_others(path) -> bool:
    """Whether users other than the owner may read the key file (it should be chmod 600)."""
    return bool(Path(path).stat().st_mode & (stat.S_IRGRP | stat.S_IROTH))


def new_key_file(path) -> Path:
    """Write a fresh random key (64 hex characters) readable by its owner only."""
    path = Path(path)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, 'w') as f:
        f.write(os.urandom(32).hex() + '\n')
    return path


class Signer:
    """Signs and checks messages with one deployment's key."""

    def __init__(self, key: bytes):
        if len(key) < MIN_KEY_BYTES:
            raise KeyFileError(f'a key needs at least {MIN_KEY_BYTES} bytes')
        self._key = bytes(key)

    @classmethod
    def from_file(cls, path) -> 'Signer':
        return cls(read_key(path))

    def sign(self, kind: str, sender: str, sequence: int, parts: Iterable[bytes]) -> bytes:
        mac = hmac.new(self._key, digestmod=hashlib.sha256)
        for part in (kind.encode(), sender.encode(), struct.pack('<Q', sequence % 2**64), *parts):
            mac.update(struct.pack('<Q', len(part)))  # each part's length first: no two splits agree
            mac.update(part)
        return mac.digest()

    def verify(self, signature: bytes, kind: str, sender: str, sequence: int, parts: Iterable[bytes]) -> bool:
        return len(signature) == SIGNATURE_BYTES and hmac.compare_digest(
            bytes(signature), self.sign(kind, sender, sequence, parts)
        )


def signer_from(path: str, warn=None) -> Optional[Signer]:
    """A Signer for a key_file parameter ('' : none, messages go unsigned and unchecked); ``warn``
    (a node's logger.warning) is told when other users may read the key file."""
    if not path:
        return None
    signer = Signer.from_file(path)
    if warn is not None and key_readable_by_others(path):
        warn(f'the key file {path} is readable by other users of this machine, who could sign as this '
             f'deployment: chmod 600 {path}')  # fmt: skip
    return signer


# The person's commands travel as std_msgs/Float32MultiArray (teleop_command): the counter and
# the signature go in labelled fields of their own, as values float32 holds exactly.
COUNTER_SPLIT = 2**24  # counter = high * 2^24 + low, both exact in float32
REPLAY_WINDOW_S = 30.0
UNSIGNED = 'it is unsigned and this node has a key_file'


def to_exact_floats(signature: bytes) -> list:
    """32 bytes as 16 integers below 2^16 (exact in float32)."""
    return [float(int.from_bytes(signature[i : i + 2], 'little')) for i in range(0, len(signature), 2)]


def from_exact_floats(values) -> bytes:
    if any(not (0 <= v < 2**16 and float(v).is_integer()) for v in values):
        return b''
    return b''.join(int(v).to_bytes(2, 'little') for v in values)


def _command_bytes(values) -> bytes:
    return struct.pack(f'<{len(values)}f', *values)


class CommandSeal:
    """Signs one sender's stream of commands. Each carries a counter: the time in ms, or one more
    than the last (two in one ms), so that the receiver can refuse a replayed command."""

    def __init__(self, signer: Signer, clock=None):
        import time

        self._signer, self._clock, self._last = signer, clock or time.time, 0

    def seal(self, values) -> tuple[list, list]:
        """(counter field, signature field) for a command whose values are ``values``."""
        self._last = max(self._last + 1, int(self._clock() * 1000))
        signature = self._signer.sign('command', '', self._last, [_command_bytes(values)])
        return [float(self._last // COUNTER_SPLIT), float(self._last % COUNTER_SPLIT)], to_exact_floats(signature)


class CommandCheck:
    """The receiver's side of CommandSeal: a command is taken when its signature is the key's,
    its counter is past the last one taken and within REPLAY_WINDOW_S of this machine's clock."""

    def __init__(self, signer: Signer, clock=None):
        import time

        self._signer, self._clock, self._last = signer, clock or time.time, 0

    def refusal(self, values, counter, signature) -> str:
        if not counter or not signature:
            return UNSIGNED
        if len(counter) != 2 or any(not (0 <= c < COUNTER_SPLIT and float(c).is_integer()) for c in counter):
            return 'its counter is not one a sender makes'
        n = int(counter[0]) * COUNTER_SPLIT + int(counter[1])
        if not self._signer.verify(from_exact_floats(signature), 'command', '', n, [_command_bytes(values)]):
            return 'its signature is not made with this key_file (another key, or altered on the way)'
        if n <= self._last:
            return 'it repeats an earlier command (a replay)'
        if abs(n / 1000 - self._clock()) > REPLAY_WINDOW_S:
            return f"its time is more than {REPLAY_WINDOW_S:g} s from this machine's (a replay, or clocks apart)"
        self._last = n
        return ''


# A signed request and its answer (the Advise service): the answer's signature covers the request's
# counter and signature, so that it is taken for that very request only.


class RequestSeal:
    """The asking side: each request carries a counter (this machine's time in ms, or one more than
    the last) and a signature over it and the request's parts; an answer is taken only when signed
    with the key for that request, so that a stranger can neither answer nor pass off an answer to
    another request as this one's."""

    def __init__(self, signer: Signer, kind: str, clock=None):
        import time

        self._signer, self._kind, self._clock, self._last = signer, kind, clock or time.time, 0

    def seal(self, parts: list) -> tuple[int, bytes]:
        """(counter, signature) for a request whose content is ``parts``."""
        self._last = max(self._last + 1, int(self._clock() * 1000))
        return self._last, self._signer.sign(f'{self._kind} request', '', self._last, parts)

    def answer_refusal(self, counter: int, request_signature: bytes, parts: list, signature: bytes) -> str:
        """'' when the answer whose content is ``parts`` is signed with the key for this request."""
        if not signature:
            return UNSIGNED
        if not self._signer.verify(
            bytes(signature), f'{self._kind} answer', '', counter, [bytes(request_signature), *parts]
        ):
            return 'its signature is not made with this key_file for this request (another key or request, or altered)'
        return ''


class RequestCheck:
    """The serving side: a request is answered only when it is signed with the key, dated within
    REPLAY_WINDOW_S of this machine's clock, and not one already answered (a replay: anyone on the
    graph reads the requests); its answer is signed for it (``seal_answer``)."""

    def __init__(self, signer: Signer, kind: str, clock=None):
        import time

        self._signer, self._kind, self._clock = signer, kind, clock or time.time
        self._seen: dict[bytes, int] = {}  # signature -> counter, of the requests taken in the window

    def refusal(self, counter: int, parts: list, signature: bytes) -> str:
        """'' when the request may be answered (and it is then marked as taken); else why not."""
        signature = bytes(signature)
        if not counter or not signature:
            return UNSIGNED
        if not self._signer.verify(signature, f'{self._kind} request', '', counter, parts):
            return 'its signature is not made with this key_file (another key, or altered on the way)'
        now_ms, window_ms = self._clock() * 1000, REPLAY_WINDOW_S * 1000
        if abs(counter - now_ms) > window_ms:
            return f"its time is more than {REPLAY_WINDOW_S:g} s from this machine's (a replay, or clocks apart)"
        # Older ones cannot pass the time check again: only the window's need keeping.
        self._seen = {seen: c for seen, c in self._seen.items() if c >= now_ms - window_ms}
        if signature in self._seen:
            return 'it repeats a request already taken (a replay)'
        self._seen[signature] = counter
        return ''

    def seal_answer(self, counter: int, request_signature: bytes, parts: list) -> bytes:
        return self._signer.sign(f'{self._kind} answer', '', counter, [bytes(request_signature), *parts])
