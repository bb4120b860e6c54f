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
from sensor_msgs.msg import CompressedImage

from eqhrl_interfaces.msg import EpisodeStats, PolicyWeights, TransitionAck, TransitionBatch

from ..core.data.signing import UNSIGNED, Signer
from ..core.data.summary import EpisodeSummary
from ..core.data.transitions import TransitionBatch as Batch
from ..core.data.transitions import batch_fields, batch_from_fields

TRANSITIONS_TOPIC = '/transitions'
WEIGHTS_TOPIC = '/weights'
# Reliable, and deep enough that an actor's backlog sent at once after the trainer (re)appears
# is not overwritten in the writer's history before it is acknowledged.
TRANSITIONS_QOS = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE)
# The trainer's side: the middleware keeps the buffers of the reader's history for the reader's
# life, as large as the largest message it held, so its depth bounds what a flood of huge batches
# from a stranger costs (refused at once, but only once taken from that history). A batch that
# finds it full is lost on the way, and sent again (selective repeat).
TRANSITIONS_READER_QOS = QoSProfile(depth=50, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE)
# The latest weights only, kept for actors that start (or restart) later.
WEIGHTS_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
# Batches an actor publishes per flush tick (0.1 s): a backlog goes out over several ticks, each
# burst within the trainer's reader depth.
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
        bytes(bytearray(msg.sources)),
        *(_stats_bytes(e) for e in msg.episodes),
        struct.pack('<I', msg.frame_stack),
        *(frame.format.encode() + b'\0' + bytes(frame.data) for frame in msg.frames),
        np.asarray(msg.observation_frames, dtype='<u4').tobytes(),
        np.asarray(msg.next_frames, dtype='<u4').tobytes(),
    ]


def weights_parts(msg: PolicyWeights) -> list:
    tensors = msg.tensors.tobytes() if hasattr(msg.tensors, 'tobytes') else bytes(msg.tensors)
    return [struct.pack('<Qii', msg.episodes, msg.stamp.sec, msg.stamp.nanosec), tensors]


def sign_batch(msg: TransitionBatch, signer: Optional[Signer]) -> TransitionBatch:
    if signer is not None:
        msg.signature = array.array('B', signer.sign('transitions', msg.actor, msg.sequence, batch_parts(msg)))
    return msg


def ack_parts(msg: TransitionAck) -> list:
    missing = np.asarray(msg.missing, dtype='<i8').tobytes()
    return [
        msg.actor.encode(),
        msg.actor_run.encode(),
        struct.pack('<qq', msg.saved_through, msg.highest_received),
        missing,
        struct.pack('<?', msg.run_ended),
    ]


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
        return UNSIGNED
    if isinstance(msg, PolicyWeights):
        ok = signer.verify(signature, 'weights', msg.trainer_id, msg.version, weights_parts(msg))
    elif isinstance(msg, TransitionAck):
        ok = signer.verify(signature, 'ack', msg.trainer_id, msg.received_through, ack_parts(msg))
    else:
        ok = signer.verify(signature, 'transitions', msg.actor, msg.sequence, batch_parts(msg))
    return '' if ok else 'its signature is not made with this key_file (another key, or altered on the way)'


def batch_msg(batch: Batch, action_low, action_high) -> TransitionBatch:
    fields = batch_fields(batch, action_low, action_high)
    for name in ('action_low', 'action_high', 'observations', 'actions', 'rewards', 'next_observations'):
        fields[name] = _floats(fields[name])
    fields['episodes'] = [EpisodeStats(**e) for e in fields['episodes']]
    fields['sources'] = array.array('B', fields['sources'])
    fields['frames'] = [CompressedImage(format='png', data=data) for data in fields['frames']]
    for name in ('observation_frames', 'next_frames'):
        fields[name] = array.array('I', fields[name])
    return TransitionBatch(**fields)


def batch_bytes(msg: TransitionBatch) -> int:
    """About the memory a received batch holds (its arrays and episode rows)."""
    floats = len(msg.observations) + len(msg.next_observations) + len(msg.actions) + len(msg.rewards)
    frames = sum(len(f.data) for f in msg.frames) + 4 * (len(msg.observation_frames) + len(msg.next_frames))
    return 4 * floats + len(msg.terminated) + len(msg.advised) + 128 * len(msg.episodes) + len(msg.actor) + 256 + frames


# A received message into the core's batch: the message's fields are read by name.
batch_from_msg = batch_from_fields


def weights_msg(trainer_id: str, version: int, episodes: int, stamp, tensors: bytes) -> PolicyWeights:
    return PolicyWeights(
        trainer_id=trainer_id,
        version=int(version),
        episodes=int(episodes),
        stamp=stamp,
        tensors=array.array('B', tensors),
    )


def ack_msg(
    trainer_id: str, actor: str, state, highest: int, missing, signer: Optional[Signer], run_ended: bool = False
) -> TransitionAck:
    """The trainer's acknowledgement of an actor's stream (``state``: transitions.ActorSequence;
    ``highest`` and ``missing``: Trainer.missing); ``run_ended``: its max_episodes reached."""
    msg = TransitionAck(
        trainer_id=trainer_id,
        actor=actor,
        actor_run=state.run,
        received_through=int(state.received_through),
        saved_through=int(state.saved_through),
        highest_received=int(max(highest, state.received_through)),
        missing=[int(s) for s in missing],
        run_ended=bool(run_ended),
    )
    return sign_ack(msg, signer)


def run_ended_msg(trainer_id: str, actor: str, run: str, signer: Optional[Signer]) -> TransitionAck:
    """The ended run's answer to a batch of an actor's run the trainer never stored (it came
    after the end): nothing of it is held."""
    msg = TransitionAck(
        trainer_id=trainer_id,
        actor=actor,
        actor_run=run,
        received_through=-1,
        saved_through=-1,
        highest_received=-1,
        missing=[],
        run_ended=True,
    )
    return sign_ack(msg, signer)
