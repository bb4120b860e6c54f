"""A lone in-process run saved between episodes and resumed exactly (eqhrl-experiment, eqhrl-study).

A run of LunarLander's 400 episodes takes about an hour on one core: a Ctrl-C, a closed
terminal or a reboot must not cost all of it. Every few minutes, at the end of an episode
(after its record and its evaluation are written), the runner saves what the rest of the
run depends on, in one checkpoint (core/runs/checkpoint.py: written whole, then renamed):
- the learner: networks, optimisers, gates, counters and random streams, and both replay
  memories (their own file, paired with the checkpoint);
- the env's random stream: the next episode's start state (and, in LunarLander, the
  engines' dispersion at every step);
- the random streams of the expert and of the experts it wraps (a simulated person's
  noise and misses);
- what the run was started with (its settings), and the wall time it has run so far.

Resumed from there, the run computes what it would have computed without the
interruption: the same episodes, evaluations and gate records, row for row
(tests/cli/test_experiment.py). Rows written after the save are dropped on resume and made
again. A save that cannot be used (another run's settings, a damaged file) is reported in
one line and the run starts over; it never continues from something it cannot trust.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Callable

import numpy as np

from .checkpoint import load_checkpoint, save_checkpoint
from ..data.errors import CheckpointError, CheckpointWriteError
from .records import previous_replay_path

CHECKPOINT = 'resume.pt'
REPLAY = 'resume-replay.pt'


def expert_generators(expert) -> list:
    """The numpy random streams of an expert and of the experts it wraps (``.expert``)."""
    found = []
    while expert is not None:
        rng = getattr(expert, 'rng', None)
        if isinstance(rng, np.random.Generator):
            found.append(rng)
        expert = getattr(expert, 'expert', None)
    return found


class ResumePoint:
    """The resume files of the run in ``folder``; ``every_s``: seconds between saves (0: never).

    ``identity``: plain values that say which run this is (its settings, mode and seed): a
    save made with others is not resumed.
    """

    def __init__(self, folder, identity: dict, every_s: float, log: Callable[[str], None] = print):
        self.folder = Path(folder)
        self.checkpoint, self.replay = self.folder / CHECKPOINT, self.folder / REPLAY
        self.identity = json.loads(json.dumps(identity, default=repr))  # as it reads back from the file
        self.every_s = float(every_s)
        self.log = log
        self.seconds_before = 0.0  # the wall time of the run before this process took it up
        self._started = time.monotonic()
        self._last_save = self._started

    @property
    def seconds(self) -> float:
        """The run's wall time so far, earlier processes included."""
        return self.seconds_before + time.monotonic() - self._started

    def restore(self, learner, env, expert) -> bool:
        """Load the saved run into a fresh learner, env and expert; False (and everything
        left fresh) if there is none or it cannot be used."""
        if not self.checkpoint.exists():
            return False
        generators = expert_generators(expert)

        def check(extra) -> None:  # before the learner takes anything from the file
            if not isinstance(extra, dict) or extra.get('identity') != self.identity:
                raise CheckpointError('it was saved by a run with other settings')
            if not isinstance(extra.get('expert_rng'), list) or len(extra['expert_rng']) != len(generators):
                raise CheckpointError('its expert has a different number of random streams')
            if not isinstance(extra.get('seconds'), (int, float)):
                raise CheckpointError('its wall time is not a number')
            for state, generator in [(extra.get('env_rng'), env.unwrapped.np_random)] + list(
                zip(extra['expert_rng'], generators)
            ):
                try:  # on a throwaway generator of the same kind: numpy checks the state
                    type(generator.bit_generator)().state = state
                except (TypeError, ValueError, KeyError) as error:
                    raise CheckpointError(f"a random stream's state is not one ({error})") from error

        try:
            extra = load_checkpoint(learner, self.checkpoint, self.replay, check_extra=check)
        except CheckpointError as error:
            self.log(f'{self.folder}: the saved state is not resumed ({error}); the run starts over')
            self.remove()
            return False
        # The learner has its state now; the env and the expert take theirs (checked above:
        # check() refuses a file without them, so extra is a dict here).
        assert isinstance(extra, dict)
        env.unwrapped.np_random.bit_generator.state = extra['env_rng']
        for generator, state in zip(generators, extra['expert_rng']):
            generator.bit_generator.state = state
        self.seconds_before = float(extra['seconds'])
        self.log(
            f'{self.folder}: resumed after episode {learner.episode} ({self.seconds_before / 60:.1f} min run before)'
        )
        return True

    def save_if_due(self, learner, env, expert) -> None:
        """Save now if ``every_s`` has passed since the last save; call between episodes only."""
        if self.every_s <= 0 or time.monotonic() - self._last_save < self.every_s:
            return
        extra = {
            'identity': self.identity,
            'env_rng': env.unwrapped.np_random.bit_generator.state,
            'expert_rng': [g.bit_generator.state for g in expert_generators(expert)],
            'seconds': self.seconds,
        }
        try:
            save_checkpoint(learner, self.checkpoint, self.replay, extra=extra)
        except CheckpointWriteError as error:
            # A full disk costs the resume point, not the run: the previous save stays.
            self.log(f'{self.folder}: could not save the resume point ({error}); the run goes on')
        self._last_save = time.monotonic()

    def remove(self) -> None:
        remove_files(self.folder)


def remove_files(folder) -> None:
    """Delete a run's resume files (the run finished, or they cannot be used)."""
    folder = Path(folder)
    for path in (folder / CHECKPOINT, folder / REPLAY, previous_replay_path(folder / REPLAY)):
        path.unlink(missing_ok=True)
