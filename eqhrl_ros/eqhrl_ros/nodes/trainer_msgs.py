"""The actor nodes' and the trainer's topics: names, QoS, and conversions to and from the
core's TransitionBatch and the networks' bytes (eqhrl_interfaces TransitionBatch, TransitionAck,
PolicyWeights).

Both topics are absolute (``/transitions``, ``/weights``): actors usually run in namespaces of
their own (one env each) and all talk to one trainer. Remap them (``-r /weights:=/team/weights``)
to run several trainers in one ROS domain.
"""

from __future__ import annotations

import array
import dataclasses
import struct
from typing import Optional

import numpy as np
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from eqhrl_interfaces.msg import EpisodeStats, PolicyWeights, TransitionAck, TransitionBatch

from ..core.data.signing import Signer
from ..core.data.summary import EpisodeSummary
from ..core.data.transitions import TransitionBatch as Batch

TRANSITIONS_TOPIC = '/transitions'
WEIGHTS_TOPIC = '/weights'
# Reliable, and deep enough that an actor's backlog sent at once after the trainer (re)appears
# is not overwritten in the writer's history before it is acknowledged.
TRANSITIONS_QOS = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE)
# The latest weights only, kept for actors that start (or restart) later.
WEIGHTS_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
# Batches an actor publishes per call: a backlog goes out over several calls, within the QoS depth.
SEND_AT_ONCE = 20
# The trainer's acknowledgements: on the (remapped) transitions topic's name with this suffix.
ACK_SUFFIX = '_ack'
ACK_QOS = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE)


def ack_topic(transitions_topic: str) -> str:
    """The acknowledgements' topic beside a resolved transitions topic (a remap moves both)."""
    return transitions_topic + ACK_SUFFIX


_STATS_FIELDS = tuple(f.name for f in dataclasses.fields(EpisodeSummary))


def _floats(values) -> array.array:
    out = array.array('f')
    out.frombytes(np.ascontiguousarray(values, dtype=np.float32).tobytes())
    return out


def _f32(values) -> bytes:
    return np.asarray(values, dtype='<f4').tobytes()


def _stats_bytes(stats) -> bytes:
    """An EpisodeStats (or EpisodeSummary) field by field, as the signature covers it."""
    out = b''
    for name in _STATS_FIELDS:
        value = getattr(stats, name)
        out += struct.pack('<?', value) if isinstance(value, bool) else struct.pack('<d', float(value))
    return out


def batch_parts(msg: TransitionBatch) -> list:
    """The content of a batch, in bytes, as its signature covers it (everything but the signature)."""
    return [
        msg.actor_run.encode(),
        struct.pack('<QI', msg.oldest_kept, msg.observation_size),
        _f32(msg.action_low),
        _f32(msg.action_high),
        _f32(msg.observations),
        _f32(msg.actions),
        _f32(msg.rewards),
        _f32(msg.next_observations),
        bytes(bytearray(bool(v) for v in msg.terminated)),
        bytes(bytearray(bool(v) for v in msg.advised)),
        *(_stats_bytes(e) for e in msg.episodes),
    ]


def weights_parts(msg: PolicyWeights) -> list:
    tensors = msg.tensors.tobytes() if hasattr(msg.tensors, 'tobytes') else bytes(msg.tensors)
    return [struct.pack('<Qii', msg.episodes, msg.stamp.sec, msg.stamp.nanosec), tensors]


def sign_batch(msg: TransitionBatch, signer: Optional[Signer]) -> TransitionBatch:
    if signer is not None:
        msg.signature = array.array('B', signer.sign('transitions', msg.actor, msg.sequence, batch_parts(msg)))
    return msg


def ack_parts(msg: TransitionAck) -> list:
    return [msg.actor.encode(), msg.actor_run.encode(), struct.pack('<q?', msg.saved_through, msg.rewind)]


def sign_ack(msg: TransitionAck, signer: Optional[Signer]) -> TransitionAck:
    if signer is not None:
        msg.signature = array.array('B', signer.sign('ack', msg.trainer_id, msg.received_through, ack_parts(msg)))
    return msg


def sign_weights(msg: PolicyWeights, signer: Optional[Signer]) -> PolicyWeights:
    if signer is not None:
        msg.signature = array.array('B', signer.sign('weights', msg.trainer_id, msg.version, weights_parts(msg)))
    return msg


def signature_refusal(msg, signer: Optional[Signer]) -> str:
    """'' when ``msg`` (a TransitionBatch, TransitionAck or PolicyWeights) may be taken: no key is set, or its
    signature is this key's over its content; else why not."""
    if signer is None:
        return ''
    signature = bytes(msg.signature)
    if not signature:
        return 'it is unsigned and this node has a key_file'
    if isinstance(msg, PolicyWeights):
        ok = signer.verify(signature, 'weights', msg.trainer_id, msg.version, weights_parts(msg))
    elif isinstance(msg, TransitionAck):
        ok = signer.verify(signature, 'ack', msg.trainer_id, msg.received_through, ack_parts(msg))
    else:
        ok = signer.verify(signature, 'transitions', msg.actor, msg.sequence, batch_parts(msg))
    return '' if ok else 'its signature is not made with this key_file (another key, or altered on the way)'


def batch_msg(batch: Batch, action_low, action_high) -> TransitionBatch:
    return TransitionBatch(
        actor=batch.actor,
        sequence=int(batch.sequence),
        actor_run=batch.run,
        oldest_kept=int(batch.sequence if batch.oldest_kept is None else batch.oldest_kept),
        observation_size=int(batch.observations.shape[1]),
        action_low=_floats(action_low),
        action_high=_floats(action_high),
        observations=_floats(batch.observations),
        actions=_floats(batch.actions),
        rewards=_floats(batch.rewards),
        next_observations=_floats(batch.next_observations),
        terminated=[bool(v) for v in batch.terminated],
        advised=[bool(v) for v in batch.advised],
        episodes=[EpisodeStats(**dataclasses.asdict(s)) for s in batch.episodes],
    )


def batch_bytes(msg: TransitionBatch) -> int:
    """About the memory a received batch holds (its arrays and episode rows)."""
    floats = len(msg.observations) + len(msg.next_observations) + len(msg.actions) + len(msg.rewards)
    return 4 * floats + len(msg.terminated) + len(msg.advised) + 128 * len(msg.episodes) + len(msg.actor) + 256


class BatchError(ValueError):
    """A TransitionBatch whose sizes do not fit together."""


def batch_from_msg(msg: TransitionBatch) -> tuple[Batch, np.ndarray, np.ndarray]:
    """(the core's batch, action_low, action_high). Sizes that do not add up raise BatchError;
    values are checked by the trainer (Trainer.receive)."""
    obs_dim = int(msg.observation_size)
    action_dim = len(msg.action_low)
    n = len(msg.rewards)
    if obs_dim < 1 or action_dim < 1 or len(msg.action_high) != action_dim:
        raise BatchError(
            f'observation_size {obs_dim}, action_low {len(msg.action_low)} and action_high '
            f'{len(msg.action_high)} values do not describe spaces'
        )
    sizes = {
        'observations': (len(msg.observations), n * obs_dim),
        'next_observations': (len(msg.next_observations), n * obs_dim),
        'actions': (len(msg.actions), n * action_dim),
        'terminated': (len(msg.terminated), n),
        'advised': (len(msg.advised), n),
    }
    for name, (got, expected) in sizes.items():
        if got != expected:
            raise BatchError(f'{name} has {got} values, {n} transitions need {expected}')
    batch = Batch(
        actor=msg.actor,
        sequence=int(msg.sequence),
        observations=np.frombuffer(msg.observations, dtype=np.float32).reshape(n, obs_dim),
        actions=np.frombuffer(msg.actions, dtype=np.float32).reshape(n, action_dim),
        rewards=np.frombuffer(msg.rewards, dtype=np.float32),
        next_observations=np.frombuffer(msg.next_observations, dtype=np.float32).reshape(n, obs_dim),
        terminated=np.asarray(msg.terminated, dtype=bool),
        advised=np.asarray(msg.advised, dtype=bool),
        episodes=[EpisodeSummary(**{name: getattr(e, name) for name in _STATS_FIELDS}) for e in msg.episodes],
        run=msg.actor_run,
        oldest_kept=int(msg.oldest_kept),
    )
    return batch, np.asarray(msg.action_low, dtype=np.float32), np.asarray(msg.action_high, dtype=np.float32)


def weights_msg(trainer_id: str, version: int, episodes: int, stamp, tensors: bytes) -> PolicyWeights:
    return PolicyWeights(
        trainer_id=trainer_id,
        version=int(version),
        episodes=int(episodes),
        stamp=stamp,
        tensors=array.array('B', tensors),
    )


def ack_msg(trainer_id: str, actor: str, state, rewind: bool, signer: Optional[Signer]) -> TransitionAck:
    """The trainer's acknowledgement of an actor's stream (``state``: transitions.ActorSequence)."""
    msg = TransitionAck(
        trainer_id=trainer_id,
        actor=actor,
        actor_run=state.run,
        received_through=int(state.received_through),
        saved_through=int(state.saved_through),
        rewind=bool(rewind),
    )
    return sign_ack(msg, signer)
