"""Layouts of the std_msgs/Float32MultiArray messages, built and checked in one place.

Each message labels its fields in ``layout.dim`` (label, size; stride = size), in order:

- observation (env -> learner):  obs[n], reward, terminated, truncated, episode, step[, success]
  One message carries a whole step, so observation, reward and flags are never
  paired across topics. step == 0 marks the first observation of an episode.
  success is optional: an env that judges success itself appends it (1.0 on the final
  step of a successful episode), and the learner then takes its verdict.
- action (learner -> env):       action[m], episode, step
  episode and step name the observation the action answers; the env ignores a
  tagged action for another step. A bare action[m] (no tag) is accepted too.
- teleop_command (a person's UI -> teleop_expert):  command[k], enabled, answer, skip
  command values in [-1, 1] (teleop_expert maps them with axes, scales and offsets);
  enabled, answer and skip are buttons, 1.0 while held: the deadman, "answer with my
  command" and "no advice". A bare command[k] (no labels) is accepted too.

The learner's own topics have message types with named fields (eqhrl_interfaces/msg):
episode_stats (EpisodeStats), gate_debug (GateDecision), advice_request (AdviceRequest);
they are built here too.

Episode and step are float32: exact up to 16,777,216.
"""

from __future__ import annotations

import array
import dataclasses
import functools
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import Float32MultiArray, MultiArrayDimension, MultiArrayLayout

from eqhrl_interfaces.msg import AdviceRequest, EpisodeStats, GateDecision

from ..core.data.summary import EpisodeSummary
from ..core.experts.teleop import COMMAND_FIELDS, REQUEST_FIELD
from .frame_msgs import stack_msgs

OBS_TAIL = ('reward', 'terminated', 'truncated', 'episode', 'step')
OBS_SUCCESS = 'success'  # the optional last field of an observation
ACTION_TAIL = ('episode', 'step')
# learner/advice_request: the outcome names and their AdviceRequest constants.
ADVICE_OUTCOMES = {
    'pending': AdviceRequest.PENDING,
    'given': AdviceRequest.GIVEN,
    'declined': AdviceRequest.DECLINED,
    'failed': AdviceRequest.FAILED,
    'taken': AdviceRequest.TAKEN,
}
OUTCOME_NAMES = {number: name for name, number in ADVICE_OUTCOMES.items()}


# learner/advice_request: the latest request stays available to a person's UI that starts later.
LATCHED_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
# Actions, episode statistics, gate decisions, a camera's frames: reliable, the last 10 kept.
RELIABLE_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
# Observations wait here while the learner computes: a real-time env at 15 Hz sends 20 during
# the first update (about 1.3 s), and at depth 10 the middleware delivered none of them.
# 100 small messages bound the backlog a flood can leave (tests/nodes/test_faults.py).
OBSERVATION_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)


class MessageError(ValueError):
    """A message that does not fit its layout; the text names what is wrong."""


@functools.lru_cache(maxsize=256)
def _layout(dims: tuple[tuple[str, int], ...]) -> MultiArrayLayout:
    # A layout is the same for every message of a topic: built once, shared (never mutated).
    return MultiArrayLayout(dim=[MultiArrayDimension(label=label, size=size, stride=size) for label, size in dims])


# The person's stop (std_msgs/Bool on ``/stop``): latched, so that an env node that starts or
# restarts while the robot is stopped stays stopped; absolute, so that one STOP reaches every
# env in the domain, actors' namespaced ones too (remap it to stop one team alone).
STOP_TOPIC = '/stop'
STOP_QOS = LATCHED_QOS


def rate_limited(action: np.ndarray, previous: np.ndarray, max_change: float) -> np.ndarray:
    """``action`` moved at most ``max_change`` (env units, per dimension) from ``previous``; 0: as is."""
    if max_change <= 0:
        return action
    return np.clip(action, previous - max_change, previous + max_change).astype(np.float32)


def build(fields: Sequence[tuple[str, Sequence[float]]]) -> Float32MultiArray:
    arrays = [np.atleast_1d(np.asarray(values, dtype=np.float32)).reshape(-1) for _, values in fields]
    msg = Float32MultiArray()
    msg.layout = _layout(tuple((label, len(a)) for (label, _), a in zip(fields, arrays)))
    # array('f') is the message's own storage type: assigned without a per-element check.
    msg.data = array.array('f', np.concatenate(arrays).tobytes())
    return msg


class OutgoingMessage:
    """One message of a fixed layout, serialized once; each step rewrites only its values.

    Why: ``publish(msg)`` converts the Python message, layout labels included, to C and
    serializes it on every call; ``publish(bytes)`` hands the middleware ready bytes.
    In the CDR encoding of a Float32MultiArray the data values come last (the sequence
    length, then 4-byte floats), so two messages of one layout differ only in that tail:
    ``fill`` writes the values there and returns the bytes. Subscribers receive the same
    message as before. The bytes are checked once, here, against the serializer; should
    a middleware encode differently, ``fill`` returns the message itself instead.
    """

    def __init__(self, dims: Sequence[tuple[str, int]]):
        dims = tuple((label, int(size)) for label, size in dims)
        self.head_size = dims[0][1]
        self.size = sum(size for _, size in dims)
        self.msg = Float32MultiArray(layout=_layout(dims), data=array.array('f', bytes(4 * self.size)))
        self._cdr = bytearray(serialize_message(self.msg))
        tail = len(self._cdr) - 4 * self.size
        # Writable numpy views: of the serialized tail, and of msg.data's own storage.
        self._cdr_values = np.frombuffer(self._cdr, dtype=np.float32, count=self.size, offset=tail)
        self._msg_values = np.frombuffer(self.msg.data, dtype=np.float32)
        self.serialized = self._tail_holds_the_values()

    def _tail_holds_the_values(self) -> bool:
        probe = np.arange(1, self.size + 1, dtype=np.float32)
        self._cdr_values[:] = probe
        try:
            decoded = deserialize_message(bytes(self._cdr), Float32MultiArray)
        except Exception:  # the bytes do not even decode: not the encoding assumed here
            return False
        return decoded.layout == self.msg.layout and np.array_equal(np.asarray(decoded.data), probe)

    def fill(self, head, *tail: float) -> bytes | Float32MultiArray:
        """The first field's values (``head``), then one value per remaining field;
        returns what to publish: the serialized message (or the message, see above)."""
        head = np.asarray(head, dtype=np.float32).reshape(-1)
        if head.shape[0] != self.head_size or self.head_size + len(tail) != self.size:
            raise MessageError(
                f'{head.shape[0]} + {len(tail)} values for a message of {self.head_size} + {self.size - self.head_size}'
            )
        values = self._cdr_values if self.serialized else self._msg_values
        values[: self.head_size] = head
        values[self.head_size :] = tail
        return bytes(self._cdr) if self.serialized else self.msg


Layout = tuple  # ((label, size), ...)


def observation_layouts(obs_dim: int) -> tuple[Layout, ...]:
    """The labelled layouts an observation message may have: without and with the optional
    success field (a bare array is read by position)."""
    plain = (('obs', obs_dim), *((label, 1) for label in OBS_TAIL))
    return (plain, (*plain, (OBS_SUCCESS, 1)))


def action_layouts(action_dim: int) -> tuple[Layout, ...]:
    """Labelled layouts of an action message: tagged with (episode, step), or the action alone."""
    return ((('action', action_dim), *((label, 1) for label in ACTION_TAIL)), (('action', action_dim),))


def check_layout(layout: MultiArrayLayout, allowed: Sequence[Layout], topic: str) -> None:
    """A labelled message must be labelled as ours; one without labels is read by position.

    Raises MessageError for any other labelling (labels in another order, other sizes, a
    data offset): reading it by position would take one field for another.
    """
    if not layout.dim and layout.data_offset == 0:
        return
    found = tuple((d.label, int(d.size)) for d in layout.dim)
    if layout.data_offset == 0 and found in allowed:
        return
    expected = ' or '.join(', '.join(f'{label}:{size}' for label, size in a) for a in allowed)
    raise MessageError(
        f"'{topic}': layout [{', '.join(f'{label}:{size}' for label, size in found)}]"
        f'{f" with data_offset {layout.data_offset}" if layout.data_offset else ""} '
        f'is not [{expected}] (nor unlabelled)'
    )


class SerializedReader:
    """The values of serialized Float32MultiArray messages, from a raw subscription.

    Why: rclpy builds a Python message (a layout object, an object per labelled field)
    for every message it delivers (tens of microseconds: docs/performance.md). A
    subscription with ``raw=True`` delivers the CDR bytes instead. The first message is
    deserialized in full; the bytes before its values (layout, data offset, value count)
    are kept. A later message that starts with the same bytes has the same layout and
    the same number of values, so its values are read from its tail. Any other message
    (another publisher's layout, another size) is deserialized in full, and its leading
    bytes are kept in turn.
    """

    def __init__(self, allowed_layouts: Sequence[Layout] = (), topic: str = ''):
        """``allowed_layouts``: the labelled layouts accepted (see check_layout); empty: any."""
        self._allowed = tuple(allowed_layouts)
        self._topic = topic
        self._head: Optional[bytes] = None  # leading bytes of the layout last seen
        self._count = 0  # and its number of values

    def values(self, data: bytes) -> np.ndarray:
        """The message's data values (read-only). Raises MessageError on bytes that do not decode
        or a labelling other than the allowed ones."""
        head = self._head
        if head is not None and len(data) == len(head) + 4 * self._count and data.startswith(head):
            return np.frombuffer(data, dtype=np.float32, offset=len(head))
        try:
            msg = deserialize_message(data, Float32MultiArray)
        except Exception as error:  # rclpy raises RMWError; any failure here is a bad message
            raise MessageError(f'not a Float32MultiArray ({len(data)} bytes): {error}') from error
        if self._allowed:
            check_layout(msg.layout, self._allowed, self._topic)
        values = np.asarray(msg.data, dtype=np.float32)
        start = len(data) - 4 * len(values)
        # Keep the leading bytes only if the tail really is the values (CDR as expected).
        if start >= 0 and data[start:] == values.tobytes():
            self._head, self._count = data[:start], len(values)
        return values


@dataclass(frozen=True)
class EnvStep:
    obs: np.ndarray
    reward: float
    terminated: bool
    truncated: bool
    episode: int
    step: int
    success: Optional[bool] = None  # the env's verdict, where it reports one

    @property
    def done(self) -> bool:
        return self.terminated or self.truncated


def observation_msg(
    obs, reward: float, terminated: bool, truncated: bool, episode: int, step: int, success: Optional[bool] = None
):
    fields = [
        ('obs', obs),
        ('reward', [reward]),
        ('terminated', [float(terminated)]),
        ('truncated', [float(truncated)]),
        ('episode', [episode]),
        ('step', [step]),
    ]
    if success is not None:
        fields.append((OBS_SUCCESS, [float(success)]))
    return build(fields)


def observation_out(obs_dim: int, with_success: bool = False) -> OutgoingMessage:
    """The env's observation message, refilled each step with ``fill(obs, *OBS_TAIL values[, success])``."""
    return OutgoingMessage(observation_layouts(obs_dim)[int(with_success)])


def _values(msg) -> np.ndarray:
    """A message's data values; ``msg`` is a Float32MultiArray or its values already."""
    return msg if isinstance(msg, np.ndarray) else np.asarray(msg.data, dtype=np.float32)


def parse_observation(msg, obs_dim: int, topic: str = 'observation') -> EnvStep:
    """An observation message (or its values, from a SerializedReader) as an EnvStep."""
    if not isinstance(msg, np.ndarray):
        check_layout(msg.layout, observation_layouts(obs_dim), topic)
    data = _values(msg)
    expected = obs_dim + len(OBS_TAIL)
    if data.shape[0] not in (expected, expected + 1):
        raise MessageError(
            f"'{topic}': {data.shape[0]} values, expected {expected} (obs[{obs_dim}] + {', '.join(OBS_TAIL)}) "
            f'or {expected + 1} (+ {OBS_SUCCESS})'
        )
    if not np.isfinite(data).all():
        bad = [i for i in range(len(data)) if not np.isfinite(data[i])]
        raise MessageError(f"'{topic}': non-finite value(s) at index {bad}")
    obs = data[:obs_dim].copy()
    reward, terminated, truncated, episode, step = data[obs_dim:expected].tolist()
    flags = [('terminated', terminated), ('truncated', truncated), *_success_flag(data, expected)]
    _check_meaning(topic, [('episode', episode), ('step', step)], flags)
    success = bool(data[expected] > 0.5) if data.shape[0] > expected else None
    return EnvStep(obs, float(reward), terminated > 0.5, truncated > 0.5, int(episode), int(step), success)


# Episode and step travel as float32, exact for whole numbers up to 2^24: beyond, or negative, or
# with a fraction, a number is no episode's or step's (before, int() floored 2.5 to 2 unsaid).
MAX_COUNTER = 2**24


def _success_flag(data: np.ndarray, expected: int) -> list:
    return [(OBS_SUCCESS, float(data[expected]))] if data.shape[0] > expected else []


def _check_meaning(topic: str, counters, flags=()) -> None:
    """MessageError unless each counter is a whole number in [0, 2^24] and each flag 0 or 1."""
    for name, value in counters:
        if not (0 <= value <= MAX_COUNTER and float(value).is_integer()):
            raise MessageError(f"'{topic}': {name} {value:g} is not a whole number in [0, {MAX_COUNTER:,}]")
    for name, value in flags:
        if value not in (0.0, 1.0):
            raise MessageError(f"'{topic}': {name} {value:g} is not 0 or 1")


def action_msg(action, episode: Optional[int] = None, step: Optional[int] = None):
    fields = [('action', action)]
    if episode is not None:
        fields += [('episode', [episode]), ('step', [step])]
    return build(fields)


def action_out(action_dim: int) -> OutgoingMessage:
    """The learner's tagged action message, refilled with ``fill(action, episode, step)``."""
    return OutgoingMessage((('action', action_dim), *((label, 1) for label in ACTION_TAIL)))


def parse_action(msg, action_dim: int, topic: str = 'action'):
    """An action message (or its values) as (action, (episode, step) or None).
    Raises MessageError on size, NaN or a labelling other than ours."""
    if not isinstance(msg, np.ndarray):
        check_layout(msg.layout, action_layouts(action_dim), topic)
    data = _values(msg)
    if data.shape[0] not in (action_dim, action_dim + len(ACTION_TAIL)):
        raise MessageError(
            f"'{topic}': {data.shape[0]} values, expected {action_dim} (or {action_dim + 2} with episode and step)"
        )
    if not np.isfinite(data).all():
        raise MessageError(f"'{topic}': non-finite value(s) {data.tolist()}")
    tag = None
    if data.shape[0] == action_dim + len(ACTION_TAIL):
        _check_meaning(topic, zip(ACTION_TAIL, data[action_dim:].tolist()))
        tag = (int(data[action_dim]), int(data[action_dim + 1]))
    return data[:action_dim].copy(), tag


def stats_msg(summary: EpisodeSummary) -> EpisodeStats:
    """learner/episode_stats: the summary's fields by name (EpisodeStats mirrors EpisodeSummary)."""
    return EpisodeStats(**dataclasses.asdict(summary))


# The person's command as teleop_expert passes it on to the learner for a takeover: 'action'
# (env units, mapped and clipped), 'deadman' and 'take_over' (1.0 while held); with key_file,
# 'counter' and 'signature' after them, as teleop_command carries them.
PERSON_COMMAND_TOPIC = 'person_command'
PERSON_COMMAND_FIELDS = ('action', 'deadman', 'take_over')


def person_command_msg(action, deadman: bool, take_over: bool, seal=None) -> Float32MultiArray:
    """person_command, signed with ``seal`` (a core.data.signing.CommandSeal) when given."""
    values = ([float(v) for v in action], [float(deadman)], [float(take_over)])
    fields = list(zip(PERSON_COMMAND_FIELDS, values))
    if seal is not None:
        counter, signature = seal.seal(signed_values(dict(fields), PERSON_COMMAND_FIELDS))
        fields += [('counter', counter), ('signature', signature)]
    return build(fields)


def command_msg(
    command: Sequence[float], enabled: bool, answer: bool, skip: bool, seal=None, request=None, take_over=False
) -> Float32MultiArray:
    """teleop_command as keyboard_teleop and advice_console publish it (COMMAND_FIELDS), then the
    (episode, step) of the request the person's screen shows (``request``, if any), and with a
    core.data.signing.CommandSeal its 'counter' and 'signature' fields after them."""
    values = ([float(v) for v in command], [float(enabled)], [float(answer)], [float(skip)])
    fields = list(zip(COMMAND_FIELDS, values))
    if request is not None:
        fields.append((REQUEST_FIELD, [float(request[0]), float(request[1])]))
    if take_over:
        fields.append(('take_over', [1.0]))
    if seal is not None:
        counter, signature = seal.seal(command_values(dict(fields)))
        fields += [('counter', counter), ('signature', signature)]
    return build(fields)


def command_values(fields: dict) -> list:
    """The values a command's signature covers: its COMMAND_FIELDS and request, in order, as float32."""
    return signed_values(fields, (*COMMAND_FIELDS, REQUEST_FIELD, 'take_over'))


def signed_values(fields: dict, names: Sequence[str]) -> list:
    """The values of ``fields`` named in ``names``, in that order, as float32: what a signature covers."""
    import numpy as np

    return np.asarray([v for name in names for v in fields.get(name, ())], dtype=np.float32).tolist()


def person_command(msg: Float32MultiArray, check=None) -> tuple[np.ndarray, bool, bool]:
    """A person_command message (PERSON_COMMAND_FIELDS) as (action, deadman, take_over); KeyError
    or ValueError says what is wrong with it. With ``check`` (a core.data.signing.CommandCheck:
    key_file), one not signed with the key, or a replay, is refused too."""
    fields = read_fields(msg)
    if check is not None:
        refusal = check.refusal(
            signed_values(fields, PERSON_COMMAND_FIELDS), fields.get('counter'), fields.get('signature')
        )
        if refusal:
            raise ValueError(refusal)
    action = np.asarray(fields['action'], dtype=np.float32)
    if not np.isfinite(action).all():
        raise ValueError('a non-finite action')
    return action, bool(fields.get('deadman', [0.0])[0]), bool(fields.get('take_over', [0.0])[0])


def read_fields(msg: Float32MultiArray) -> dict:
    """{label: [values]} of a labelled message; an unlabelled one is all 'command'. A layout
    whose sizes do not add up to the data raises MessageError."""
    data = list(msg.data)
    if not msg.layout.dim:
        return {'command': data}
    if sum(dim.size for dim in msg.layout.dim) != len(data):
        raise MessageError(
            f'layout sizes add up to {sum(dim.size for dim in msg.layout.dim)}, the message has {len(data)} values'
        )
    out, offset = {}, 0
    for dim in msg.layout.dim:
        out[dim.label] = data[offset : offset + dim.size]
        offset += dim.size
    return out


def parse_fields(msg: Float32MultiArray) -> dict:
    """{label: value or list} from a labelled message (for tests and tools)."""
    out, offset = {}, 0
    for dim in msg.layout.dim:
        values = list(msg.data[offset : offset + dim.size])
        out[dim.label] = values[0] if dim.size == 1 else values
        offset += dim.size
    return out


def gate_msg(episode: int, step: int, decision) -> GateDecision:
    """learner/gate_debug: where the decision was made, then each field GateDecision.msg shares with
    the core's GateDecision, by name."""
    kinds = GateDecision.get_fields_and_field_types()
    values = {name: getattr(decision, name) for name in kinds if name not in ('episode', 'step')}
    convert = {'boolean': bool, 'float': float, 'double': float}
    return GateDecision(
        episode=int(episode), step=int(step), **{name: convert[kinds[name]](v) for name, v in values.items()}
    )


def advice_request_msg(
    outcome: str,
    request,
    timeout_s: float,
    detail: str = '',
    human: bool = False,
    response_time_s: float = 0.0,
    given_action=(),
    wheel: bool = False,
    steps_driven: int = 0,
) -> AdviceRequest:
    """learner/advice_request: ``request`` (core AdviceRequest, its frames included) and what
    came of it so far (``given_action``: the action used, env units, when it was given; ``wheel``: a request for
    the wheel, ``steps_driven`` by the person so far)."""
    return AdviceRequest(
        wheel=bool(wheel),
        steps_driven=int(steps_driven),
        given_action=np.asarray(given_action, dtype=np.float32).tolist(),
        outcome=ADVICE_OUTCOMES[outcome],
        detail=detail,
        human=bool(human),
        response_time_s=float(response_time_s),
        episode=int(request.episode),
        step=int(request.step),
        discrepancy=float(request.discrepancy),
        entropy=float(request.entropy),
        timeout_s=float(timeout_s),
        observation=np.asarray(request.observation, dtype=np.float32).tolist(),
        proposed_action=np.asarray(request.proposed_action, dtype=np.float32).tolist(),
        frames=stack_msgs(request.pixels),
    )


# Expert names and reasons come from other nodes: cap them before they reach a log line, a count,
# or the person's page or terminal.
EXPERT_NAME_MAX = 64
EXPERT_NAMES_KEPT = 8
REASON_MAX = 200


def printable_text(text: str, limit: int, ascii_only: bool = False) -> str:
    """``text`` as one safe line of at most ``limit`` characters: anything not printable (escape
    sequences, line breaks), and with ``ascii_only`` anything not ASCII, becomes '?'."""
    text = ''.join(c if c.isprintable() and (c.isascii() or not ascii_only) else '?' for c in (text or '')[: limit + 1])
    return text if len(text) <= limit else text[: limit - 3] + '...'


def printable_name(name: str) -> str:
    """``name`` as one safe log token: printable ASCII only, at most EXPERT_NAME_MAX characters."""
    return printable_text(name, EXPERT_NAME_MAX, ascii_only=True) or '(unnamed)'
