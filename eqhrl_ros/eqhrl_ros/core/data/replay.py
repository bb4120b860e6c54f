"""Replay memories D and D_advising (Algorithm 1, Section 3.3)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import torch


@dataclass
class Minibatch:
    obs: torch.Tensor
    action: torch.Tensor  # normalised to [-1, 1]
    reward: torch.Tensor
    next_obs: torch.Tensor
    terminated: torch.Tensor  # 1.0 where the episode ended by termination (no bootstrap)

    def to(self, device: torch.device) -> 'Minibatch':
        """The batch on ``device`` (itself when it is there already: no copy on CPU)."""
        if self.obs.device == device:
            return self
        return Minibatch(*(getattr(self, name).to(device) for name in BATCH_COLUMNS))

    def columns(self) -> tuple:
        """The columns in BATCH_COLUMNS order, as update.algorithm1_update reads them:
        contiguous (a compiled program is specialised to its inputs' layout, and these are
        column views of the buffer's rows)."""
        return tuple(getattr(self, name).contiguous() for name in BATCH_COLUMNS)


# A batch's columns, in the one order every path uses (the buffer's rows, the update, stacked seeds).
BATCH_COLUMNS = tuple(f.name for f in dataclasses.fields(Minibatch))
ROW_COLUMNS = {'reward', 'terminated'}  # one number per transition: the batch is their last axis


def checked_transition(obs, action, reward, next_obs, obs_dim: int, action_dim: int):
    """(obs, action, next_obs) as flat float32 arrays, or a ValueError if a size is wrong or a
    value is not finite (a NaN that reaches the critics poisons every later update)."""
    obs = np.asarray(obs, dtype=np.float32).reshape(-1)
    action = np.asarray(action, dtype=np.float32).reshape(-1)
    next_obs = np.asarray(next_obs, dtype=np.float32).reshape(-1)
    if obs.shape[0] != obs_dim or next_obs.shape[0] != obs_dim:
        raise ValueError(f'observation has {obs.shape[0]}/{next_obs.shape[0]} values, the buffer holds {obs_dim}')
    if action.shape[0] != action_dim:
        raise ValueError(f'action has {action.shape[0]} values, the buffer holds {action_dim}')
    if not (
        np.isfinite(obs).all() and np.isfinite(action).all() and np.isfinite(next_obs).all() and np.isfinite(reward)
    ):
        raise ValueError('transition holds a non-finite value (NaN or inf); not stored')
    return obs, action, next_obs


def column_widths(obs_dim: int, action_dim: int) -> dict:
    """float32 values of each field of one stored transition, a row [obs | action | reward | next_obs | terminated]."""
    return {'obs': obs_dim, 'action': action_dim, 'reward': 1, 'next_obs': obs_dim, 'terminated': 1}


def row_width(obs_dim: int, action_dim: int) -> int:
    """float32 values of one stored transition (D's memory is capacity rows of it)."""
    return sum(column_widths(obs_dim, action_dim).values())


class ReplayBuffer:
    """A fixed-capacity ring buffer of transitions (s, a, r, s', terminated), preallocated.

    Every stored value is checked finite: a NaN that reaches the critics poisons
    every later update, so it is refused here with an error instead.
    """

    def __init__(self, capacity: int, obs_dim: int, action_dim: int):
        if capacity < 1:
            raise ValueError(f'replay capacity must be >= 1, got {capacity}')
        self.capacity = int(capacity)
        self.obs_dim = obs_dim
        self.action_dim = action_dim
        # One row per transition, [obs | action | reward | next_obs | terminated]; the fields
        # are column views of it (and numpy views, below, for writing a transition).
        widths = column_widths(obs_dim, action_dim)
        self._columns, start = {}, 0
        for name in BATCH_COLUMNS:
            self._columns[name] = (start, start + widths[name])
            start += widths[name]
        self.rows = torch.zeros(capacity, start)
        for name, view in self._split(self.rows).items():
            setattr(self, name, view)
        # numpy views on the same memory: one transition is written without tensor ops.
        self._np = {name: getattr(self, name).numpy() for name in BATCH_COLUMNS}
        self.position = 0
        self.size = 0

    def _split(self, rows: torch.Tensor) -> dict:
        """Column views of ``rows`` by field; reward and terminated are 1-D."""
        views = {name: rows[:, a:b] for name, (a, b) in self._columns.items()}
        for name in ROW_COLUMNS:
            views[name] = views[name][:, 0]
        return views

    def __len__(self) -> int:
        return self.size

    def add(self, obs, action, reward: float, next_obs, terminated: bool) -> None:
        obs, action, next_obs = checked_transition(obs, action, reward, next_obs, self.obs_dim, self.action_dim)
        i = self.position
        self._np['obs'][i] = obs
        self._np['action'][i] = action
        self._np['reward'][i] = reward
        self._np['next_obs'][i] = next_obs
        self._np['terminated'][i] = float(terminated)
        self.position = (i + 1) % self.capacity
        self.size = min(self.size + 1, self.capacity)

    def sample(self, batch_size: int, generator: torch.Generator, replacement: bool = True) -> Minibatch:
        """Uniform sample. With replacement by default (as SB3 and CleanRL); without
        replacement needs at least ``batch_size`` transitions."""
        if self.size == 0:
            raise ValueError('cannot sample from an empty replay buffer')
        if replacement:
            index = torch.randint(self.size, (batch_size,), generator=generator)
        else:
            index = torch.randperm(self.size, generator=generator)[:batch_size]
        return self.gather(index)

    def empty(self) -> 'ReplayBuffer':
        """A new, empty memory of the same sizes (to load a saved one into, checked, first)."""
        return ReplayBuffer(self.capacity, self.obs_dim, self.action_dim)

    def saved_bytes_limit(self) -> int:
        """The most bytes its state_dict() can hold: full, float32 rows."""
        return 4 * self.capacity * self.rows.shape[1]

    def gather(self, index: torch.Tensor) -> Minibatch:
        """The transitions at rows ``index`` (a memory that keeps more per row draws its own),
        each column gathered from its own view, contiguous as the update reads it. (One gather of
        the rows left column views that the update then copied one by one: 38 against 19 us for a
        batch of 256, docs/performance.md.)"""
        return Minibatch(**{name: getattr(self, name).index_select(0, index) for name in BATCH_COLUMNS})

    def state_dict(self) -> dict:
        """Tensors of the stored part only, in insertion order's ring layout, plus the cursor."""
        return {
            **{name: getattr(self, name)[: self.size].clone() for name in BATCH_COLUMNS},
            'position': self.position,
            'size': self.size,
            'capacity': self.capacity,
        }

    def load_state_dict(self, state: dict) -> None:
        size, position = int(state['size']), int(state['position'])
        if not 0 <= size <= self.capacity:
            raise ValueError(f'saved buffer holds {size} transitions, capacity is {self.capacity}')
        if not 0 <= position < self.capacity:
            raise ValueError(f'saved buffer position {position} is outside [0, {self.capacity})')
        for name in BATCH_COLUMNS:
            saved = state[name]
            target = getattr(self, name)
            if tuple(saved.shape[1:]) != tuple(target.shape[1:]) or saved.shape[0] != size:
                raise ValueError(
                    f'saved buffer field {name!r} has shape {tuple(saved.shape)}, '
                    f'expected ({size}, ...{tuple(target.shape[1:])})'
                )
            if not torch.isfinite(saved).all():
                raise ValueError(f'saved buffer field {name!r} holds non-finite values (NaN or inf)')
        for name in BATCH_COLUMNS:
            getattr(self, name)[:size] = state[name]
        self.size = size
        self.position = position
