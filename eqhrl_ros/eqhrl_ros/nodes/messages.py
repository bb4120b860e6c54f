"""Layouts of the std_msgs/Float32MultiArray messages, built and checked in one place.

Each message labels its fields in ``layout.dim`` (label, size; stride = size), in order:

- observation (env -> learner):  obs[n], reward, terminated, truncated, episode, step
  One message carries a whole step, so observation, reward and flags are never
  paired across topics. step == 0 marks the first observation of an episode.
- action (learner -> env):       action[m], episode, step
  episode and step name the observation the action answers; the env ignores a
  tagged action for another step. A bare action[m] (no tag) is accepted too.
- episode_stats (learner):       see STATS_FIELDS.
- gate_debug (learner):          see GATE_FIELDS.
- advice_request (learner):      outcome, episode, step, discrepancy, entropy, timeout_s,
  observation[n], proposed_action[m]; outcome 0 while the learner waits (see ADVICE_OUTCOMES).

Episode and step are float32: exact up to 16,777,216.
"""

from __future__ import annotations

import array
import functools
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
from std_msgs.msg import Float32MultiArray, MultiArrayDimension, MultiArrayLayout

OBS_TAIL = ('reward', 'terminated', 'truncated', 'episode', 'step')
ACTION_TAIL = ('episode', 'step')
STATS_FIELDS = ('episode', 'return', 'length', 'advice_asked', 'advice_given', 'advice_human',
                'advice_declined', 'advice_failed', 'success', 'total_steps', 'alpha')
# learner/advice_request: what the learner is asking a person right now.
ADVICE_OUTCOMES = {'pending': 0, 'given': 1, 'declined': 2, 'failed': 3}
ADVICE_REQUEST_TAIL = ('outcome', 'episode', 'step', 'discrepancy', 'entropy', 'timeout_s')
GATE_FIELDS = ('episode', 'step', 'fire', 'ask', 'respond', 'discrepancy', 'entropy',
               'd_threshold', 'e_threshold')


class MessageError(ValueError):
    """A message that does not fit its layout; the text names what is wrong."""


@functools.lru_cache(maxsize=256)
def _layout(dims: tuple[tuple[str, int], ...]) -> MultiArrayLayout:
    # A layout is the same for every message of a topic: built once, shared (never mutated).
    return MultiArrayLayout(dim=[MultiArrayDimension(label=label, size=size, stride=size)
                                 for label, size in dims])


def build(fields: Sequence[tuple[str, Sequence[float]]]) -> Float32MultiArray:
    arrays = [np.atleast_1d(np.asarray(values, dtype=np.float32)).reshape(-1) for _, values in fields]
    msg = Float32MultiArray()
    msg.layout = _layout(tuple((label, len(a)) for (label, _), a in zip(fields, arrays)))
    # array('f') is the message's own storage type: assigned without a per-element check.
    msg.data = array.array('f', np.concatenate(arrays).tobytes())
    return msg


class OutgoingMessage:
    """One message of a fixed layout, written in place before each publish.

    Why: a per-step topic (observation, action) would otherwise build a new message,
    its layout and its data array every step: 12-16 us each on a 2-core machine,
    about 6% of an env step through the topics with updates off. Writing into the
    same message costs about 1 us. Reuse is safe because ``publish`` serializes the
    message before it returns; a subscriber never sees this object.
    """

    def __init__(self, dims: Sequence[tuple[str, int]]):
        dims = tuple((label, int(size)) for label, size in dims)
        self.head_size = dims[0][1]
        self.size = sum(size for _, size in dims)
        self.msg = Float32MultiArray(layout=_layout(dims), data=array.array('f', bytes(4 * self.size)))
        # A writable numpy view of msg.data's own storage (array('f') exports its buffer).
        self._values = np.frombuffer(self.msg.data, dtype=np.float32)

    def fill(self, head, *tail: float) -> Float32MultiArray:
        """The first field's values (``head``), then one value per remaining field."""
        head = np.asarray(head, dtype=np.float32).reshape(-1)
        if head.shape[0] != self.head_size or self.head_size + len(tail) != self.size:
            raise MessageError(f'{head.shape[0]} + {len(tail)} values for a message of '
                               f'{self.head_size} + {self.size - self.head_size}')
        self._values[:self.head_size] = head
        self._values[self.head_size:] = tail
        return self.msg


@dataclass(frozen=True)
class EnvStep:
    obs: np.ndarray
    reward: float
    terminated: bool
    truncated: bool
    episode: int
    step: int

    @property
    def done(self) -> bool:
        return self.terminated or self.truncated


def observation_msg(obs, reward: float, terminated: bool, truncated: bool, episode: int, step: int):
    return build([('obs', obs), ('reward', [reward]), ('terminated', [float(terminated)]),
                  ('truncated', [float(truncated)]), ('episode', [episode]), ('step', [step])])


def observation_out(obs_dim: int) -> OutgoingMessage:
    """The env's observation message, refilled each step with ``fill(obs, *OBS_TAIL values)``."""
    return OutgoingMessage((('obs', obs_dim), *((label, 1) for label in OBS_TAIL)))


def parse_observation(msg: Float32MultiArray, obs_dim: int, topic: str = 'observation') -> EnvStep:
    data = np.asarray(msg.data, dtype=np.float32)
    expected = obs_dim + len(OBS_TAIL)
    if data.shape[0] != expected:
        raise MessageError(f"'{topic}': {data.shape[0]} values, expected {expected} "
                           f"(obs[{obs_dim}] + {', '.join(OBS_TAIL)})")
    if not np.isfinite(data).all():
        bad = [i for i in range(len(data)) if not np.isfinite(data[i])]
        raise MessageError(f"'{topic}': non-finite value(s) at index {bad}")
    obs = data[:obs_dim].copy()
    reward, terminated, truncated, episode, step = data[obs_dim:].tolist()
    return EnvStep(obs, float(reward), terminated > 0.5, truncated > 0.5, int(episode), int(step))


def action_msg(action, episode: Optional[int] = None, step: Optional[int] = None):
    fields = [('action', action)]
    if episode is not None:
        fields += [('episode', [episode]), ('step', [step])]
    return build(fields)


def action_out(action_dim: int) -> OutgoingMessage:
    """The learner's tagged action message, refilled with ``fill(action, episode, step)``."""
    return OutgoingMessage((('action', action_dim), *((label, 1) for label in ACTION_TAIL)))


def parse_action(msg: Float32MultiArray, action_dim: int, topic: str = 'action'):
    """Returns (action, (episode, step) or None). Raises MessageError on size or NaN."""
    data = np.asarray(msg.data, dtype=np.float32)
    if data.shape[0] not in (action_dim, action_dim + len(ACTION_TAIL)):
        raise MessageError(f"'{topic}': {data.shape[0]} values, expected {action_dim} "
                           f"(or {action_dim + 2} with episode and step)")
    if not np.isfinite(data).all():
        raise MessageError(f"'{topic}': non-finite value(s) {data.tolist()}")
    tag = None
    if data.shape[0] == action_dim + len(ACTION_TAIL):
        tag = (int(data[action_dim]), int(data[action_dim + 1]))
    return data[:action_dim].copy(), tag


def stats_msg(summary) -> Float32MultiArray:
    values = [summary.episode, summary.episode_return, summary.length, summary.advice_asked,
              summary.advice_given, summary.advice_human, summary.advice_declined, summary.advice_failed,
              float(summary.success), summary.total_steps, summary.alpha]
    return build(list(zip(STATS_FIELDS, ([v] for v in values))))


def parse_fields(msg: Float32MultiArray) -> dict:
    """{label: value or list} from a labelled message (for tests and tools)."""
    out, offset = {}, 0
    for dim in msg.layout.dim:
        values = list(msg.data[offset:offset + dim.size])
        out[dim.label] = values[0] if dim.size == 1 else values
        offset += dim.size
    return out


def gate_msg(episode: int, step: int, decision) -> Float32MultiArray:
    values = [episode, step, float(decision.fire), float(decision.ask), float(decision.respond),
              decision.discrepancy, decision.entropy, decision.d_threshold, decision.e_threshold]
    return build(list(zip(GATE_FIELDS, ([v] for v in values))))


def advice_request_msg(outcome: str, request, timeout_s: float) -> Float32MultiArray:
    return build([('outcome', [ADVICE_OUTCOMES[outcome]]), ('episode', [request.episode]),
                  ('step', [request.step]), ('discrepancy', [request.discrepancy]),
                  ('entropy', [request.entropy]), ('timeout_s', [timeout_s]),
                  ('observation', request.observation), ('proposed_action', request.proposed_action)])
