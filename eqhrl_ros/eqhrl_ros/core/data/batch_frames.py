"""A camera's frames in a batch of transitions (TransitionBatch.frames): each frame held once, each
transition's stack and next frame by index, as the fields of eqhrl_interfaces/msg/TransitionBatch
carry them (PNG), and read back from a message checked by meaning before any frame is decoded."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import camera_frames

# Most pixels the frames of one batch may decode to (about 800 MB of RGB): a 1,000-step episode
# of 84x84 frames holds 7 M; a message that declares more is refused before decoding.
MAX_BATCH_FRAME_PIXELS = 2**28


@dataclass
class BatchFrames:
    """A camera's frames of a batch: each frame once, uint8 (m, H, W, C), and per transition the
    indexes of its observation's stack (n, k), oldest first, and of its next observation's newest
    frame (n,). The next observation's stack is the observation's less its oldest, then that frame."""

    frames: np.ndarray
    observation_frames: np.ndarray
    next_frames: np.ndarray

    @classmethod
    def of(cls, stacks, next_frames) -> 'BatchFrames':
        """From each transition's observation stack [k, H, W, C] and next newest frame [H, W, C]:
        a frame that comes again (the stacks overlap) is held once."""
        held: dict[bytes, int] = {}
        frames: list = []

        def index(frame) -> int:
            key = np.ascontiguousarray(frame).tobytes()
            if key not in held:
                held[key] = len(frames)
                frames.append(frame)
            return held[key]

        observation = [[index(f) for f in stack] for stack in stacks]
        following = [index(f) for f in next_frames]
        return cls(np.stack(frames), np.asarray(observation, np.int64), np.asarray(following, np.int64))

    @property
    def stack(self) -> int:
        return self.observation_frames.shape[1]

    def observation_stacks(self) -> np.ndarray:
        """(n, k, H, W, C): each transition's observation stack."""
        return self.frames[self.observation_frames]

    def next_stacks(self) -> np.ndarray:
        """(n, k, H, W, C): each transition's next observation stack."""
        stacks = self.observation_stacks()
        return np.concatenate([stacks[:, 1:], self.frames[self.next_frames][:, None]], axis=1)


def frame_fields(frames: 'BatchFrames | None') -> dict:
    if frames is None:
        return {'frame_stack': 0, 'frames': [], 'observation_frames': [], 'next_frames': []}
    return {
        'frame_stack': frames.stack,
        'frames': [camera_frames.png_bytes(frame[None]) for frame in frames.frames],  # lossless, once each
        'observation_frames': frames.observation_frames.ravel().tolist(),
        'next_frames': frames.next_frames.tolist(),
    }


def frames_from(msg, n: int, refusal=ValueError) -> 'BatchFrames | None':
    """A message's frames (``n`` transitions), checked by meaning before any is decoded (``refusal``,
    the batch's error class, says what does not fit): a stack in [1, MAX_FRAME_STACK],
    an index per stack place and next frame, each naming a frame there, no more frames than the
    transitions can read, PNG or JPEG of one size, MAX_BATCH_FRAME_PIXELS in all."""
    stack = int(getattr(msg, 'frame_stack', 0))
    compressed = list(getattr(msg, 'frames', ()))
    observation = np.asarray(list(getattr(msg, 'observation_frames', ())), np.int64)
    following = np.asarray(list(getattr(msg, 'next_frames', ())), np.int64)
    if stack == 0:
        if len(compressed) or len(observation) or len(following):
            raise refusal('frames without a frame_stack')
        return None
    if not 1 <= stack <= camera_frames.MAX_FRAME_STACK:
        raise refusal(f'frame_stack {stack} is not in [1, {camera_frames.MAX_FRAME_STACK}]')
    if len(observation) != n * stack or len(following) != n:
        raise refusal(
            f'observation_frames has {len(observation)} and next_frames {len(following)} values; '
            f'{n} transitions of stacks of {stack} need {n * stack} and {n}'
        )
    if not 1 <= len(compressed) <= n * (stack + 1):
        raise refusal(f'{len(compressed)} frames for {n} transitions of stacks of {stack}')
    indexes = np.concatenate([observation, following])
    if n and (int(indexes.min()) < 0 or int(indexes.max()) >= len(compressed)):
        raise refusal(f'a frame index outside the {len(compressed)} frames')
    decoded: list[np.ndarray] = []
    pixels = 0
    for frame in compressed:
        # Each frame's declared size is held to what is left of the batch's pixels before it is decoded.
        left = min(camera_frames.MAX_FRAME_PIXELS, MAX_BATCH_FRAME_PIXELS - pixels)
        try:
            array = camera_frames.decode_compressed(frame.data, max_pixels=left)
        except camera_frames.FrameError as error:
            raise refusal(f'frame {len(decoded)}: {error}') from None
        if decoded and array.shape != decoded[0].shape:
            raise refusal(f'frame {len(decoded)} is {array.shape}, frame 0 {decoded[0].shape}: one camera has one size')
        pixels += array.shape[0] * array.shape[1]
        decoded.append(array)
    return BatchFrames(np.stack(decoded), observation.reshape(n, stack), following)
