"""A camera's frames in a TransitionBatch (core/data/transitions.py, BatchFrames): each frame
once, each transition's stack by index, lossless there and back, and a message's frames checked
by meaning before any is decoded (the record, prior data and the actors' link read them)."""

import re
from types import SimpleNamespace

import numpy as np
import pytest

from eqhrl_ros.core.data import camera_frames
from eqhrl_ros.core.data.transitions import BatchError, BatchFrames, TransitionBatch, batch_fields, batch_from_fields

K, H, W, C = 3, 16, 18, 3


def episode(n: int, seed: int = 0):
    """n steps' stacks as gymnasium's FrameStackObservation gives them (the first frame repeated)
    and the frame each step led to."""
    frames = np.random.default_rng(seed).integers(0, 256, (n + 1, H, W, C), dtype=np.uint8)
    stacks = np.stack([frames[[max(t - j, 0) for j in range(K - 1, -1, -1)]] for t in range(n)])
    return frames, stacks, frames[1:]


def message(batch: TransitionBatch):
    """The batch as a message read back from a record: its fields as attributes, frames as
    CompressedImage-like objects."""
    fields = batch_fields(batch, [-1.0], [1.0])
    fields['frames'] = [SimpleNamespace(format='png', data=data) for data in fields['frames']]
    fields['episodes'] = []
    return SimpleNamespace(**fields)


def batch_with(frames) -> TransitionBatch:
    n = len(frames.next_frames)
    zeros = np.zeros((n, 2), np.float32)
    return TransitionBatch(
        'actor', 0, zeros, np.zeros((n, 1), np.float32), np.zeros(n, np.float32), zeros,
        np.zeros(n, bool), np.arange(n) % 2 == 0, frames=frames,
    )  # fmt: skip


def test_an_episodes_frames_are_held_once_and_its_stacks_come_back_pixel_for_pixel():
    frames, stacks, following = episode(10)
    held = BatchFrames.of(stacks, following)
    assert np.array_equal(held.frames, frames)  # n + 1 frames for n steps, in order, each once
    assert held.observation_frames.tolist()[:3] == [[0, 0, 0], [0, 0, 1], [0, 1, 2]]
    back = batch_from_fields(message(batch_with(held)))[0].frames
    assert np.array_equal(back.observation_stacks(), stacks)
    assert np.array_equal(back.next_stacks()[:-1], stacks[1:])  # the next stack is the next step's stack
    assert np.array_equal(back.next_stacks()[:, -1], following)


def test_a_batch_without_a_camera_carries_no_frames():
    batch = batch_with(BatchFrames.of(*episode(2)[1:]))
    batch.frames = None
    fields = batch_fields(batch, [-1.0], [1.0])
    assert (fields['frame_stack'], fields['frames'], fields['observation_frames']) == (0, [], [])
    assert batch_from_fields(message(batch))[0].frames is None


def png(array) -> SimpleNamespace:
    return SimpleNamespace(format='png', data=camera_frames.png_bytes(array[None]))


def bad(**change):
    msg = message(batch_with(BatchFrames.of(*episode(4)[1:])))
    for name, value in change.items():
        setattr(msg, name, value)
    return msg


@pytest.mark.parametrize(
    'msg, reason',
    [
        (bad(frame_stack=0), 'frames without a frame_stack'),
        (bad(frame_stack=17), 'frame_stack 17 is not in [1, 16]'),
        (bad(next_frames=[0, 1, 2]), 'observation_frames has 12 and next_frames 3 values; 4 transitions of stacks'),
        (bad(next_frames=[0, 1, 2, 9]), 'a frame index outside the 5 frames'),
        (bad(next_frames=[0, 1, 2, -1]), 'a frame index outside the 5 frames'),
        (bad(frames=[png(np.zeros((H, W, C), np.uint8))] * 17), '17 frames for 4 transitions of stacks of 3'),
        (bad(frames=[SimpleNamespace(format='png', data=b'not a png')] * 5), 'frame 0: compressed frame does not'),
        (bad(frames=[png(np.zeros((H, W, C), np.uint8))] * 4 + [png(np.zeros((H, W + 1, C), np.uint8))]),
         'frame 4 is (16, 19, 3), frame 0 (16, 18, 3): one camera has one size'),
    ],
)  # fmt: skip
def test_frames_that_do_not_fit_their_transitions_are_refused_saying_why(msg, reason):
    with pytest.raises(BatchError, match=re.escape(reason)):
        batch_from_fields(msg)
