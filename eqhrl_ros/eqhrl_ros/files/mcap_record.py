"""A run's record as one MCAP file (the `ros2` profile: CDR messages, `ros2msg` schemas), written
with the ``mcap`` package so that it works without rosbag2, and read back without ROS.

What goes in is chosen by the node that records (nodes/recording.py): messages as they were on
the wire, and the transitions the run stored. Foxglove opens the file, and so does
``ros2 bag info``/``play`` where rosbag2's MCAP storage plugin is installed.

A kill -9 loses at most what arrived since the last flush: the writer closes its chunk every
``flush_period_s`` (1 s by default), and read_record() reads a file cut short up to its last
whole chunk (`mcap recover` from the mcap CLI rewrites such a file whole, with its index).
"""

from __future__ import annotations

import dataclasses
import re
import struct
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Optional

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import MCAP0_MAGIC, CompressionType, Writer
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import serialize_dynamic

from ..core.data.transitions import BatchError, batch_from_fields
from ..core.runs.records import RECORD_FILES

RECORD_NAME = 'record.mcap'
FLUSH_PERIOD_S = 1.0
# ros2 bag's separator between a message definition and each type it uses.
_SEPARATOR = '=' * 80
_PRIMITIVES = {
    'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16', 'int32', 'uint32',
    'int64', 'uint64', 'string', 'wstring',
}  # fmt: skip


class RecordError(ValueError):
    """A record that cannot be read or does not fit (one line for the user)."""


def record_path(folder: Path, resume: bool) -> Path:
    """record.mcap in a run's folder; a resumed run adds record-1.mcap, record-2.mcap, ... (an
    MCAP file is finished with its index and not appended to)."""
    folder = Path(folder)
    path = folder / RECORD_NAME
    n = 0
    while resume and path.exists():
        n += 1
        path = folder / f'record-{n}.mcap'
    return path


def record_files(run_or_file) -> list[Path]:
    """The MCAP files of a run folder, in the order they were written, or the one file given."""
    path = Path(run_or_file)
    if path.is_dir():
        # Below the folder too: an experiment's folder holds one run per algorithm and seed.
        files = sorted(path.rglob(RECORD_FILES), key=lambda p: (str(p.parent), len(p.name), p.name))
        if not files:
            raise RecordError(f'{path}: no record*.mcap in or below this folder (was it made with record: true?)')
        return files
    if not path.exists():
        raise RecordError(f'{path}: no such file or folder')
    # Any other file would read as a record cut short before its first message: a mistyped name
    # (a CSV, a checkpoint) would seed nothing and say only that it was cut short.
    with open(path, 'rb') as stream:
        if stream.read(len(MCAP0_MAGIC)) != MCAP0_MAGIC:
            raise RecordError(f"{path}: not an MCAP file (it does not begin with MCAP's magic bytes)")
    return [path]


# ---------------------------------------------------------------------- message definitions


def _share_text(package: str, kind: str, name: str) -> str:
    from .paths import share_dir

    path = share_dir(package) / kind / f'{name}.{kind}'
    try:
        return path.read_text()
    except OSError as error:
        raise RecordError(f'no definition of {package}/{kind}/{name} ({path}: {error.strerror})') from error


def _definition_parts(type_name: str) -> tuple[str, str, str]:
    """('pkg', 'msg' or 'srv', 'Name') of 'pkg/msg/Name', 'pkg/Name' or a service's part
    ('pkg/srv/Name_Request', '_Response', '_Event')."""
    parts = type_name.split('/')
    if len(parts) == 2:
        return parts[0], 'msg', parts[1]
    if len(parts) == 3:
        return parts[0], parts[1], parts[2]
    raise RecordError(f'{type_name!r} is not a ROS type name')


def _own_text(package: str, kind: str, name: str) -> str:
    """A type's .msg text; for a service's Request, Response and Event, the text rosidl gives them."""
    if kind == 'srv':
        service, _, part = name.rpartition('_')
        request, _, response = _share_text(package, 'srv', service).partition('\n---')
        if part == 'Request':
            return request
        if part == 'Response':
            return response.lstrip('\n')
        if part == 'Event':
            return (
                'service_msgs/ServiceEventInfo info\n'
                f'{package}/{service}_Request[<=1] request\n'
                f'{package}/{service}_Response[<=1] response\n'
            )
        raise RecordError(f'{package}/srv/{name} is not a part of a service')
    return _share_text(package, kind, name)


def _used_types(text: str, package: str) -> list[str]:
    """The non-primitive field types of a definition, as 'pkg/Name'."""
    used = []
    for line in text.splitlines():
        line = line.split('#', 1)[0].strip()
        if not line:
            continue
        type_token = line.split()[0]  # constants are always of a primitive type: skipped below
        base = type_token.split('[', 1)[0].split('<=', 1)[0]
        if base in _PRIMITIVES:
            continue
        used.append(base if '/' in base else f'{package}/{base}')
    return used


def message_definition(type_name: str) -> str:
    """The full `ros2msg` text of a type, as ros2 bag stores it: its own definition, then each
    type it uses once, after a line of '=' and 'MSG: pkg/Name'."""
    package, kind, name = _definition_parts(type_name)
    text = _own_text(package, kind, name)
    seen, pending, parts = set(), _used_types(text, package), []
    while pending:
        used = pending.pop(0)
        if used in seen:
            continue
        seen.add(used)
        used_package, used_name = used.split('/')
        if used_name.endswith(('_Request', '_Response')):
            used_text = _own_text(used_package, 'srv', used_name)
        else:
            used_text = _own_text(used_package, 'msg', used_name)
        parts.append(f'{_SEPARATOR}\nMSG: {used}\n{used_text}')
        pending += _used_types(used_text, used_package)
    return '\n'.join([text.rstrip('\n'), *parts]) + '\n'


# ---------------------------------------------------------------------- writing


class McapRecord:
    """One MCAP file, written from any thread: messages as CDR bytes (write) or as fields
    (write_fields, encoded here from the definition, for callers without rclpy)."""

    def __init__(self, path, flush_period_s: float = FLUSH_PERIOD_S, metadata: Optional[dict] = None):
        self.path = Path(path)
        self._file = open(self.path, 'wb')
        self._writer = Writer(self._file, compression=CompressionType.ZSTD)
        self._writer.start(profile='ros2', library='eqhrl_ros')
        if metadata:
            self._writer.add_metadata('eqhrl_ros', {k: str(v) for k, v in metadata.items()})
        self._lock = threading.Lock()
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, tuple[int, str]] = {}
        self._encoders: dict[str, object] = {}
        self._sequence: dict[str, int] = {}
        self.flush_period_s = flush_period_s
        self._flushed = time.monotonic()
        self.messages = 0
        self.closed = False

    def _channel(self, topic: str, type_name: str) -> int:
        known = self._channels.get(topic)
        if known is not None:
            if known[1] != type_name:
                raise RecordError(f'{topic} is recorded as {known[1]}, not {type_name}')
            return known[0]
        schema = self._schemas.get(type_name)
        if schema is None:
            schema = self._writer.register_schema(
                type_name, SchemaEncoding.ROS2, message_definition(type_name).encode()
            )
            self._schemas[type_name] = schema
        channel = self._writer.register_channel(topic, MessageEncoding.CDR, schema)
        self._channels[topic] = (channel, type_name)
        return channel

    def write(self, topic: str, type_name: str, data: bytes, time_ns: Optional[int] = None) -> None:
        """A serialized (CDR) message of ``type_name`` ('pkg/msg/Name') on ``topic``."""
        now = time.time_ns() if time_ns is None else time_ns
        with self._lock:
            if self.closed:
                return
            channel = self._channel(topic, type_name)
            sequence = self._sequence.get(topic, 0)
            self._sequence[topic] = sequence + 1
            self._writer.add_message(channel, log_time=now, data=bytes(data), publish_time=now, sequence=sequence)
            self.messages += 1
            if time.monotonic() - self._flushed >= self.flush_period_s:
                self._flush()

    def write_fields(self, topic: str, type_name: str, fields: dict, time_ns: Optional[int] = None) -> None:
        """A message given as its fields (nested messages as dicts)."""
        with self._lock:
            encoder = self._encoders.get(type_name)
            if encoder is None:
                encoders = serialize_dynamic(type_name, message_definition(type_name))
                encoder = self._encoders[type_name] = next(iter(encoders.values()))
        self.write(topic, type_name, encoder(_plain(fields)), time_ns)

    def _flush(self) -> None:
        self._writer.flush()  # closes the chunk: a kill -9 from now on keeps it
        self._flushed = time.monotonic()

    def flush(self) -> None:
        with self._lock:
            if not self.closed:
                self._flush()

    def close(self) -> None:
        """Writes the index and summary (a file closed so opens at once in every reader)."""
        with self._lock:
            if self.closed:
                return
            self.closed = True
            try:
                self._writer.finish()
            finally:
                self._file.close()


def _plain(value):
    """numpy arrays as lists, in dicts and lists too (mcap_ros2's encoder takes sequences only)."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    return value


# ---------------------------------------------------------------------- reading


@dataclass
class RecordedMessage:
    topic: str
    type_name: str
    message: object  # the decoded message: fields as attributes
    log_time_ns: int


@dataclass
class RecordContents:
    """Every message read, in the file's order, and whether the file ended whole."""

    messages: list = field(default_factory=list)
    complete: bool = True
    problem: str = ''

    def on(self, topic_suffix: str) -> list:
        return [m for m in self.messages if m.topic.endswith(topic_suffix)]


_SERVICE_PARTS = re.compile(r'\b([A-Za-z][A-Za-z0-9]*)_(Request|Response|Event)\b')


def _without_service_underscores(schema):
    """mcap_ros2's parser refuses the names rosidl gives a service's parts (Advise_Event); the
    CDR layout does not depend on names, so such a schema is decoded as AdviseEvent."""
    if not _SERVICE_PARTS.search(schema.data.decode()):
        return schema
    return dataclasses.replace(
        schema,
        name=_SERVICE_PARTS.sub(r'\1\2', schema.name).replace('/srv/', '/msg/'),
        data=_SERVICE_PARTS.sub(r'\1\2', schema.data.decode()).encode(),
    )


def iter_record(path) -> Iterator[RecordedMessage]:
    """The messages of one MCAP file in the order written. A file cut short (a kill -9) yields
    everything up to its last whole chunk, then raises RecordError saying so."""
    decoders = DecoderFactory()
    cache: dict[int, object] = {}
    with open(path, 'rb') as stream:
        reader = NonSeekingReader(stream, validate_crcs=True)
        try:
            for schema, channel, message in reader.iter_messages(log_time_order=False):
                decode = cache.get(channel.schema_id)
                if decode is None:
                    decode = cache[channel.schema_id] = decoders.decoder_for(
                        channel.message_encoding, _without_service_underscores(schema)
                    )
                yield RecordedMessage(channel.topic, schema.name, decode(message.data), message.log_time)
        except (McapError, EOFError, ValueError, OSError, struct.error) as error:
            raise RecordError(f'{path}: cut short ({type(error).__name__}: {error})') from error


def read_record(path) -> RecordContents:
    """All of one file (see iter_record); a file cut short gives what it holds, complete=False."""
    contents = RecordContents()
    try:
        for message in iter_record(path):
            contents.messages.append(message)
    except RecordError as error:
        contents.complete, contents.problem = False, str(error)
    return contents


# ---------------------------------------------------------------------- prior data

TRANSITION_BATCH = 'eqhrl_interfaces/msg/TransitionBatch'


@dataclass
class Prior:
    """The advised and person-initiated transitions of earlier runs (advised = true in their
    TransitionBatch messages), actions in [-1, 1], and where they came from."""

    observations: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    next_observations: np.ndarray
    terminated: np.ndarray
    files: list
    cut_short: list  # files that ended before their index (read up to their last whole chunk)
    # A camera learner's: each transition's observation and next observation stacks, uint8
    # (n, k, H, W, C); None without a camera.
    pixels: Optional[np.ndarray] = None
    next_pixels: Optional[np.ndarray] = None

    def __len__(self) -> int:
        return len(self.rewards)


def _checked_frames(path, batch, camera) -> None:
    """A batch's frames fit the learner's camera (CameraSpec; None: no camera), or RecordError."""
    frames = batch.frames
    if camera is None and frames is not None:
        raise RecordError(f'{path}: recorded with a camera; this learner has none')
    if camera is None or not len(batch):
        return
    if frames is None:
        raise RecordError(f'{path}: recorded without a camera; this learner reads one')
    height, width, channels = frames.frames.shape[1:]
    if (frames.stack, height, width, channels) != (camera.stack, camera.height, camera.width, camera.channels):
        raise RecordError(
            f'{path}: recorded with {frames.stack} frames of {width}x{height}x{channels}; this learner reads '
            f'{camera.stack} of {camera.width}x{camera.height}x{camera.channels}'
        )


def load_prior(sources, observation_size: int, action_low, action_high, camera=None) -> Prior:
    """Every advised transition in the records of ``sources`` (run folders, searched below, or
    .mcap files), with its frames for a learner with a ``camera`` (core.envs.spec.CameraSpec). A
    record made on other spaces or another camera is refused with RecordError (one line)."""
    low, high = (np.asarray(v, dtype=np.float32).ravel() for v in (action_low, action_high))
    parts, files, cut_short = [], [], []
    for source in sources:
        for path in record_files(source):
            files.append(path)
            contents = read_record(path)
            if not contents.complete:
                cut_short.append(path)
            for recorded in contents.messages:
                if recorded.type_name != TRANSITION_BATCH:
                    continue
                try:
                    batch, batch_low, batch_high = batch_from_fields(recorded.message)
                except BatchError as error:
                    raise RecordError(f'{path}: a TransitionBatch on {recorded.topic} is malformed: {error}') from error
                if batch.observations.shape[1] != observation_size or batch_low.shape != low.shape:
                    raise RecordError(
                        f'{path}: recorded on observations of {batch.observations.shape[1]} and actions of '
                        f'{batch_low.size} values; this env has {observation_size} and {low.size}'
                    )
                if not (np.allclose(batch_low, low) and np.allclose(batch_high, high)):
                    raise RecordError(
                        f'{path}: recorded with actions in [{batch_low.tolist()}, {batch_high.tolist()}]; '
                        f'this env has [{low.tolist()}, {high.tolist()}]'
                    )
                _checked_frames(path, batch, camera)
                keep = batch.advised
                if not keep.any():
                    continue
                frames = batch.frames if camera is not None else None
                parts.append(
                    (
                        batch.observations[keep],
                        batch.actions[keep],
                        batch.rewards[keep],
                        batch.next_observations[keep],
                        batch.terminated[keep],
                        *((frames.observation_stacks()[keep], frames.next_stacks()[keep]) if frames else ()),
                    )
                )
    if not parts:
        columns = [np.zeros((0, observation_size), np.float32), np.zeros((0, low.size), np.float32)]
        columns += [np.zeros(0, np.float32), columns[0], np.zeros(0, bool)]
        if camera is not None:
            columns += [np.zeros((0, *camera.stack_shape), np.uint8)] * 2
    else:
        columns = [np.concatenate(column) for column in zip(*parts)]
    return Prior(*columns[:5], files=files, cut_short=cut_short, pixels=_at(columns, 5), next_pixels=_at(columns, 6))


def _at(columns: list, index: int):
    return columns[index] if len(columns) > index else None
