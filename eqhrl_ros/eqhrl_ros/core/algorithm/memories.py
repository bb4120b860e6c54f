"""The learner's two replay memories: D, and D_advising for the advised transitions (Section 3.3).

With a camera (observations.CameraObservation), both are FrameReplay memories (each frame held
once, as uint8; data/frame_replay.py), and an update's batches are made flat as the networks
read them, after DrQ-v2's random shift of every frame stack (pad SHIFT_PAD pixels, drawn from the
'replay' stream after the batch itself)."""

from __future__ import annotations

import os
from typing import cast

import numpy as np
import torch

from ..data.frame_replay import FrameBatch, FrameReplay, frame_bytes
from ..data.replay import Minibatch, ReplayBuffer, checked_transition, row_width
from .config import LearnerConfig, asks_for_advice
from .image_encoder import random_shift
from .streams import RandomStreams

SHIFT_PAD = 4  # DrQ-v2's pad at 84x84 (Section 3.1)


def advice_capacity_with_frames(capacity: int, stack: int) -> int:
    """D_advising's capacity with a camera: each advised step holds stack + 1 frames, so it keeps
    capacity // (stack + 1) of them, and its frames take no more memory than D's."""
    return max(1, capacity // (stack + 1))


def frames_bytes_with_advice(capacity: int, frame_shape: tuple, stack: int) -> int:
    """Bytes of D's and D_advising's frames together, at replay_capacity ``capacity``."""
    advice = advice_capacity_with_frames(capacity, stack) * (stack + 1) * int(np.prod(frame_shape))
    return frame_bytes(capacity, frame_shape) + advice


def physical_memory_bytes() -> int:
    """This machine's memory (0 where the system does not say)."""
    try:
        return os.sysconf('SC_PAGE_SIZE') * os.sysconf('SC_PHYS_PAGES')
    except (ValueError, OSError, AttributeError):
        return 0


def check_replay_fits(capacity: int, needed: int, what: str) -> None:
    """A ValueError, before anything is allocated, when D and D_advising (``needed`` bytes at
    replay_capacity ``capacity``; ``what`` they hold) could not fit in this machine's memory, with
    the capacity that would take half of it. Before, a large observation at the default capacity
    (CarRacing's 27,648 values: 221 GB) ended the node in an allocation's traceback."""
    memory = physical_memory_bytes()
    if memory and needed > memory:
        fits = int(memory / 2 / (needed / capacity))
        raise ValueError(
            f'replay_capacity {capacity:,} with {what} needs {needed / 1e9:.1f} GB for D and D_advising; '
            f'this machine has {memory / 1e9:.1f} GB (replay_capacity {fits:,} would take half of it)'
        )


class ReplayMemories:
    """D and D_advising, what goes into each, and an update's batches from both."""

    def __init__(self, config: LearnerConfig, observation, action_dim: int, streams: RandomStreams, device):
        self.config = config
        self.observation = observation
        self.streams = streams
        self.device = device
        camera = observation.camera
        self.replay: ReplayBuffer | FrameReplay
        self.advice_replay: ReplayBuffer | FrameReplay
        if camera is None:
            needed = 2 * config.replay_capacity * row_width(observation.dim, action_dim) * 4  # float32, both full size
            check_replay_fits(config.replay_capacity, needed, f'observations of {observation.dim:,} values')
            self.replay = ReplayBuffer(config.replay_capacity, observation.dim, action_dim)  # D
            self.advice_replay = ReplayBuffer(config.replay_capacity, observation.dim, action_dim)  # D_advising
        else:
            state_dim, shape, stack = observation.state_dim, camera.frame_shape, camera.stack
            capacity, advice_capacity = (
                config.replay_capacity,
                advice_capacity_with_frames(config.replay_capacity, stack),
            )
            frames = f'{"x".join(map(str, shape))} frames'
            check_replay_fits(capacity, frames_bytes_with_advice(capacity, shape, stack), frames)
            self.replay = FrameReplay(capacity, shape, stack, state_dim, action_dim)
            # Advised steps come one by one: each with its whole stack (stack + 1 frames a transition).
            self.advice_replay = FrameReplay(advice_capacity, shape, stack, state_dim, action_dim, isolated=True)
        self._episode_starts = True  # the next transition stored opens an episode (a camera's D)

    @property
    def keeps_advice(self) -> bool:
        """Whether advised transitions also go to D_advising (QASAC, EQSAC and the like, with dual_replay)."""
        return asks_for_advice(self.config.mode) and self.config.dual_replay

    def check(self, obs, normalized_action, reward: float, next_obs) -> None:
        """A transition as store() checks it, stored nowhere (ValueError if it is bad)."""
        if self.observation.camera is None:
            checked_transition(obs, normalized_action, reward, next_obs, self.observation.dim, self.replay_action_dim)
            return
        state, next_state = self.observation.parts(obs)[0], self.observation.parts(next_obs)[0]
        checked_transition(state, normalized_action, reward, next_state, len(state), self.replay_action_dim)

    @property
    def replay_action_dim(self) -> int:
        memory = self.replay
        return memory.vectors.action_dim if isinstance(memory, FrameReplay) else memory.action_dim

    def store(self, obs, normalized_action, reward: float, next_obs, terminated: bool, advised: bool) -> None:
        """(s_t, a_t, r_t, s_{t+1}) into D, and into D_advising when advised (QASAC, EQSAC).
        ``normalized_action`` in [-1, 1]. A bad transition raises ValueError."""
        if self.observation.camera is not None:
            self._store_frames(obs, normalized_action, reward, next_obs, terminated, advised)
            return
        cast(ReplayBuffer, self.replay).add(obs, normalized_action, reward, next_obs, terminated)
        if advised and self.keeps_advice:
            cast(ReplayBuffer, self.advice_replay).add(obs, normalized_action, reward, next_obs, terminated)

    def _store_frames(self, obs, action, reward: float, next_obs, terminated: bool, advised: bool) -> None:
        state, pixels = self.observation.parts(obs)
        next_state, next_pixels = self.observation.parts(next_obs)
        checked_transition(state, action, reward, next_state, len(state), self.replay_action_dim)
        replay = self.replay
        assert isinstance(replay, FrameReplay)
        if self._episode_starts:  # the episode's first frame: its first stacks repeat it
            replay.start_episode(pixels[-1])
            self._episode_starts = False
        replay.add(state, action, reward, next_pixels[-1], next_state, terminated)
        if advised and self.keeps_advice:
            advice = self.advice_replay
            assert isinstance(advice, FrameReplay)
            advice.add_stacked(state, action, reward, pixels, next_pixels[-1], next_state, terminated)

    def store_framed(
        self, state, normalized_action, reward: float, next_state, terminated: bool, advised: bool,
        stack, next_frame, follows: bool,
    ) -> None:  # fmt: skip
        """A camera's transition that came from elsewhere (an actor's batch): the state vectors,
        the stack acted on (k, H, W, C) and the frame that followed. ``follows``: it goes on from
        the transition this memory stored last (its stack is that one's less the oldest frame,
        then that one's next frame), so D holds only its next frame; else D holds its whole
        stack, as for an episode's start: batches of several actors arrive interleaved."""
        replay = self.replay
        assert isinstance(replay, FrameReplay), 'store_framed is for a learner with a camera'
        action = np.asarray(normalized_action, dtype=np.float32)
        if follows and not self._episode_starts:
            replay.add(state, action, reward, next_frame, next_state, terminated)
        else:
            replay.add_stacked(state, action, reward, stack, next_frame, next_state, terminated)
        self._episode_starts = False
        if advised and self.keeps_advice:
            advice = self.advice_replay
            assert isinstance(advice, FrameReplay)
            advice.add_stacked(state, action, reward, stack, next_frame, next_state, terminated)

    def episode_ended(self) -> None:
        """The episode ended (or was abandoned): the next transition stored opens another."""
        self._episode_starts = True

    def add_prior(
        self, observations, normalized_actions, rewards, next_observations, terminated, pixels=None, next_pixels=None
    ) -> int:
        """Earlier runs' advised and person-initiated transitions, as prior data (RLPD, HIL-SERL):
        into D, and into D_advising where this mode has it. Actions in [-1, 1]. With a camera,
        ``pixels`` and ``next_pixels`` hold each one's stacks (n, k, H, W, C): they come one by one,
        not as episodes, so D too holds each with its whole stack. Each row is checked as store()
        checks it (ValueError names the first bad one; the rows before it stay)."""
        if self.observation.camera is not None:
            return self._add_prior_frames(observations, normalized_actions, rewards, next_observations, terminated,
                                          pixels, next_pixels)  # fmt: skip
        rows = 0
        for obs, action, reward, next_obs, done in zip(
            observations, normalized_actions, rewards, next_observations, terminated
        ):
            self.store(obs, np.clip(action, -1.0, 1.0), float(reward), next_obs, bool(done), advised=True)
            rows += 1
        return rows

    def _add_prior_frames(self, observations, actions, rewards, next_observations, terminated, pixels, next_pixels):
        if pixels is None or next_pixels is None or len(pixels) != len(rewards) or len(next_pixels) != len(rewards):
            raise ValueError("prior data for a learner with a camera needs each transition's frame stacks")
        memories = [self.replay, *([self.advice_replay] if self.keeps_advice else [])]
        rows = 0
        for values in zip(observations, actions, rewards, next_observations, terminated, pixels, next_pixels):
            obs, action, reward, next_obs, done, stack, next_stack = values
            state = self.observation.parts({'state': obs, 'pixels': stack})[0]
            next_state = self.observation.parts({'state': next_obs, 'pixels': next_stack})[0]
            action = np.clip(action, -1.0, 1.0)
            for memory in memories:
                assert isinstance(memory, FrameReplay)
                memory.add_stacked(state, action, float(reward), stack, next_stack[-1], next_state, bool(done))
            rows += 1
        self._episode_starts = True  # the run's own first transition opens an episode after them
        return rows

    def ready(self) -> bool:
        """D holds learning_starts transitions: every step from now on updates."""
        return len(self.replay) >= self.config.learning_starts

    def sample(self) -> tuple[Minibatch, Minibatch | None]:
        """An update's batches: from D, and from D_advising (EQSAC and QASAC, Section 3.3; None
        while it is empty or in mode sac), sampled with replacement while it holds fewer than
        the batch asks for; ``advice_batch: proportional``: D_advising's share of the batch."""
        cfg, generator = self.config, self.streams['replay']
        batch = self._flat(self.replay.sample(cfg.batch_size, generator))
        if not asks_for_advice(cfg.mode) or len(self.advice_replay) == 0:
            return batch, None
        size = cfg.batch_size
        if cfg.advice_batch == 'proportional':  # an ablation
            size = max(1, round(cfg.batch_size * len(self.advice_replay) / len(self.replay)))
        advice = self.advice_replay.sample(size, generator, replacement=len(self.advice_replay) < size)
        return batch, self._flat(advice)

    def _flat(self, sampled: Minibatch | FrameBatch) -> Minibatch:
        """A batch on the learner's device as the update reads it: a camera's frame stacks
        shifted (each its own offset) and laid flat after the state, as CameraObservation.flat."""
        if isinstance(sampled, Minibatch):
            return sampled.to(self.device)
        generator, vectors = self.streams['replay'], sampled.vectors

        def flat(state, frames):
            shifted = random_shift(frames, SHIFT_PAD, generator)
            return torch.cat([state, shifted.flatten(1).float()], dim=1)

        return Minibatch(
            flat(vectors.obs, sampled.frames),
            vectors.action,
            vectors.reward,
            flat(vectors.next_obs, sampled.next_frames),
            vectors.terminated,
        ).to(self.device)
