"""A replay memory for camera frames that stores each frame once (issue 49, item 3).

A transition from a camera is (stack of the last k frames, action, reward, next stack). Stored
naively, every frame would be held 2k times (k times in obs, k in next_obs). Here each frame an
env step produces is held once, in a ring of uint8 frames, and a transition holds only the
index of its next frame; both stacks are gathered by index at sampling time:

    obs      = frames[j-k .. j-1]      next_obs = frames[j-k+1 .. j]

clamped at the episode's first frame, so that a stack at an episode's start repeats its reset
frame (as DrQ-v2's frame stacking does at reset). An episode's reset frame is stored by
``start_episode``; each ``add`` stores the step's next frame.

The bound is the frame ring: ``capacity`` transitions and ``frame_slots = capacity +
capacity // 10`` frames (one frame per step and one per episode start: episodes of 10 steps
or more keep every transition's frames). Memory: frame_slots * C*H*W bytes plus the vector
part (a ReplayBuffer). 100,000 transitions of 84x84 RGB frames stacked by 3:
110,000 * 21,168 bytes = 2.33 GB (``frame_bytes`` computes it). A transition whose oldest
frame has been overwritten (possible only with episodes shorter than 10 steps) is not
sampled.

``isolated``: for transitions that do not come as whole episodes (D_advising holds only the
advised steps), each is stored with its whole stack (``add_stacked``): stack + 1 frames a
transition, ``capacity * (stack + 1)`` frame slots.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from .replay import Minibatch, ReplayBuffer, checked_transition

FRAME_RESERVE = 10  # frame_slots = capacity + capacity // FRAME_RESERVE: one episode start per 10 steps


def frame_slots(capacity: int) -> int:
    return capacity + capacity // FRAME_RESERVE


def frame_bytes(capacity: int, frame_shape: tuple[int, int, int]) -> int:
    """Bytes of a FrameReplay's frames: its frame_slots frames of C*H*W uint8 (the stack depth
    costs nothing: stacks are gathered by index)."""
    return frame_slots(capacity) * int(np.prod(frame_shape))


@dataclass
class FrameBatch:
    """A batch of transitions with camera stacks: the vector part as a Minibatch, and the
    stacks as uint8 [B, k*C, H, W] (k stacked frames of C channels, oldest first)."""

    vectors: Minibatch
    frames: torch.Tensor
    next_frames: torch.Tensor


class FrameReplay:
    """Transitions (frame stack and vector, action, reward, next frame stack and vector,
    terminated), each frame held once."""

    def __init__(
        self,
        capacity: int,
        frame_shape: tuple[int, int, int],
        stack: int,
        vector_dim: int,
        action_dim: int,
        isolated: bool = False,
    ):
        """``frame_shape``: (channels, height, width) of one frame, as a convolution reads it.
        ``isolated``: transitions come one by one, not as episodes (D_advising holds only the
        advised steps), each stored with its whole stack by ``add_stacked``: stack + 1 frames a
        transition."""
        if stack < 1:
            raise ValueError(f'frame stack must be >= 1, got {stack}')
        if len(frame_shape) != 3 or min(frame_shape) < 1:
            raise ValueError(f'frame_shape must be (channels, height, width) >= 1, got {frame_shape}')
        self.vectors = ReplayBuffer(capacity, vector_dim, action_dim)
        self.capacity, self.stack, self.isolated = self.vectors.capacity, int(stack), bool(isolated)
        channels, height, width = (int(n) for n in frame_shape)
        self.frame_shape = (channels, height, width)
        self.slots = self.capacity * (self.stack + 1) if isolated else frame_slots(self.capacity)
        self.frames = np.zeros((self.slots, *self.frame_shape), np.uint8)
        # Per frame (by absolute index, at slot index % slots): its episode's first frame.
        self.episode_first = np.zeros(self.slots, np.int64)
        # Per transition (at the ReplayBuffer's row): the absolute index of its next frame.
        self.next_frame = np.zeros(self.capacity, np.int64)
        self.frames_written = 0  # absolute index of the next frame to write
        self.first = -1  # absolute index of the current episode's first frame; -1 before any

    def __len__(self) -> int:
        return len(self.vectors)

    def empty(self) -> 'FrameReplay':
        """A new, empty memory of the same sizes (to load a saved one into, checked, first)."""
        vectors = self.vectors
        return FrameReplay(
            self.capacity, self.frame_shape, self.stack, vectors.obs_dim, vectors.action_dim, self.isolated
        )

    def saved_bytes_limit(self) -> int:
        """The most bytes its state_dict() can hold: the vector part, every frame slot, the indices."""
        return self.vectors.saved_bytes_limit() + self.frames.nbytes + 8 * (self.slots + self.capacity)

    def checked_frame(self, frame) -> np.ndarray:
        """``frame`` as (C, H, W) uint8, from (H, W, C) (a camera's layout, sensor_msgs/Image),
        or a ValueError that says what was wrong."""
        frame = np.asarray(frame)
        if frame.dtype != np.uint8:
            raise ValueError(f'a frame must be uint8, got {frame.dtype}')
        channels, height, width = self.frame_shape
        if frame.shape != (height, width, channels):
            raise ValueError(
                f'frame has shape {frame.shape}, this memory holds (H, W, C) = {(height, width, channels)}'
            )
        return frame.transpose(2, 0, 1)

    def _write_frame(self, frame: np.ndarray, first: int) -> int:
        n = self.frames_written
        self.frames[n % self.slots] = frame
        self.episode_first[n % self.slots] = first
        self.frames_written = n + 1
        return n

    def start_episode(self, frame) -> None:
        """The episode's reset frame: the stacks of its first transitions repeat it."""
        frame = self.checked_frame(frame)
        self.first = self.frames_written
        self._write_frame(frame, self.first)

    def add(self, vector, action, reward: float, next_frame, next_vector, terminated: bool) -> None:
        """One step: its vectors, action, reward and the frame it led to. The frame stack it
        started from is the episode's frames so far. Nothing is stored if any part is bad."""
        if self.first < 0:
            raise ValueError('start_episode(frame) must come before the first add of an episode')
        next_frame = self.checked_frame(next_frame)
        row = self.vectors.position
        self.vectors.add(vector, action, reward, next_vector, terminated)  # raises before any write
        self.next_frame[row] = self._write_frame(next_frame, self.first)

    def add_stacked(self, vector, action, reward: float, frames, next_frame, next_vector, terminated: bool) -> None:
        """One step stored with the whole stack it started from (``frames``: [k, H, W, C],
        oldest first), not relying on the steps before it. Nothing is stored if any part is bad."""
        frames = np.asarray(frames)
        if frames.ndim != 4 or frames.shape[0] != self.stack:
            raise ValueError(f'a stack of {self.stack} frames (k, H, W, C) was expected, got shape {frames.shape}')
        checked = [self.checked_frame(frame) for frame in frames]
        self.checked_frame(next_frame)
        checked_transition(vector, action, reward, next_vector, self.vectors.obs_dim, self.vectors.action_dim)
        self.first = self.frames_written
        for frame in checked:
            self._write_frame(frame, self.first)
        self.add(vector, action, reward, next_frame, next_vector, terminated)

    def _valid(self, rows: np.ndarray) -> np.ndarray:
        """Whether each row's frames are all still held: its next frame (else the slot's
        episode start belongs to a later frame), and the oldest of its obs stack."""
        j = self.next_frame[rows]
        kept_from = self.frames_written - self.slots
        oldest = np.maximum(j - self.stack, self.episode_first[j % self.slots])
        return (j >= kept_from) & (oldest >= kept_from)

    def _stack(self, j: np.ndarray, first: np.ndarray) -> np.ndarray:
        """Frames j-k+1 .. j for each j, clamped at its episode's first frame: [B, k*C, H, W]."""
        offsets = np.arange(self.stack - 1, -1, -1)
        index = np.maximum(j[:, None] - offsets[None, :], first[:, None]) % self.slots
        stacked = self.frames[index]  # [B, k, C, H, W]
        return stacked.reshape(len(j), self.stack * self.frame_shape[0], *self.frame_shape[1:])

    def sample(self, batch_size: int, generator: torch.Generator, replacement: bool = True) -> FrameBatch:
        """Uniform over the transitions whose frames are all held; with replacement by default
        (without: needs ``batch_size`` transitions; a row whose frames are gone is redrawn with)."""
        if len(self) == 0:
            raise ValueError('cannot sample from an empty replay memory')
        if replacement:
            rows = torch.randint(len(self), (batch_size,), generator=generator).numpy()
        else:
            rows = torch.randperm(len(self), generator=generator)[:batch_size].numpy()
        bad = ~self._valid(rows)
        for _ in range(100):  # redraw the few whose frames are gone (episodes under 10 steps)
            if not bad.any():
                break
            rows[bad] = torch.randint(len(self), (int(bad.sum()),), generator=generator).numpy()
            bad = ~self._valid(rows)
        else:
            raise ValueError('almost no stored transition still has its frames (episodes far shorter than 10 steps)')
        j = self.next_frame[rows]
        first = self.episode_first[j % self.slots]
        vectors = self.vectors.gather(torch.from_numpy(rows))
        frames = torch.from_numpy(self._stack(j - 1, first))
        next_frames = torch.from_numpy(self._stack(j, first))
        return FrameBatch(vectors, frames, next_frames)

    def state_dict(self) -> dict:
        """The vector part, the frames held (oldest first) and the indices, for save_replay."""
        held = min(self.frames_written, self.slots)
        order = np.arange(self.frames_written - held, self.frames_written)
        return {
            'vectors': self.vectors.state_dict(),
            'frames': torch.from_numpy(self.frames[order % self.slots].copy()),
            'episode_first': torch.from_numpy(self.episode_first[order % self.slots].copy()),
            'next_frame': torch.from_numpy(self.next_frame[: len(self)].copy()),
            'frames_written': self.frames_written,
            'first': self.first,
            'stack': self.stack,
            'isolated': self.isolated,
        }

    def load_state_dict(self, state: dict) -> None:
        """Checked by meaning before anything is replaced: shapes, dtype, and every index
        pointing at a frame the state holds."""
        frames, first_of = state['frames'], state['episode_first'].numpy()
        written, first = int(state['frames_written']), int(state['first'])
        if frames.dtype != torch.uint8 or tuple(frames.shape[1:]) != self.frame_shape:
            raise ValueError(
                f'saved frames are {frames.dtype} {tuple(frames.shape)}, expected uint8 (n, *{self.frame_shape})'
            )
        held = frames.shape[0]
        if held > self.slots or held != min(written, self.slots) or first_of.shape != (held,):
            raise ValueError(f'saved memory holds {held} frames of {written} written; it keeps {self.slots}')
        oldest = written - held
        if held and not ((first_of <= np.arange(oldest, written)) & (first_of >= 0)).all():
            raise ValueError('saved frames name an episode start after themselves')
        if int(state['stack']) != self.stack or bool(state.get('isolated', False)) != self.isolated:
            raise ValueError(
                f'saved memory stacks {state["stack"]} frames (isolated: {bool(state.get("isolated", False))}), '
                f'this one {self.stack} (isolated: {self.isolated})'
            )
        next_frame = state['next_frame'].numpy()
        if next_frame.shape != (int(state['vectors']['size']),):
            raise ValueError(
                f'saved memory has {next_frame.shape[0]} frame indices for {state["vectors"]["size"]} rows'
            )
        if next_frame.size and not ((next_frame >= 1) & (next_frame < written)).all():
            raise ValueError('a saved transition points at a frame never written')
        # The current episode may have begun before the oldest frame held (an episode longer than the ring).
        if not (first < 0 and written == 0) and not 0 <= first < written:
            raise ValueError(f'saved episode start {first} is not a frame written')
        self.vectors.load_state_dict(state['vectors'])  # checks the vector part; raises before the frames
        self.frames[np.arange(oldest, written) % self.slots] = frames.numpy()
        self.episode_first[np.arange(oldest, written) % self.slots] = first_of
        self.next_frame[: next_frame.shape[0]] = next_frame
        self.frames_written, self.first = written, first
