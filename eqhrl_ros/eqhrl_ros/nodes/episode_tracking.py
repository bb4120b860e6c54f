"""What each observation means for the learner's episode, and the env's silences and stops.

The acting node acts on one env step at a time; ``EpisodeTracking`` remembers which (``state``
and ``key``: its observation and (env episode, env step)) and says what the next observation
is: the next step (a transition), a restart (step 0: an unfinished episode is abandoned, its
index reused), a gap in the same env episode (a lost message: the episode goes on, marked
interrupted) or a mid-episode start (marked interrupted). No transition is ever made across a
gap. It also notes silences (a stall: said once, nothing dropped) and the person's STOP (a pause,
counted in the episode's record).
"""

from __future__ import annotations

import time
from typing import Optional

import numpy as np

from ..core.data.summary import EpisodeSummary
from .messages import EnvStep


class EpisodeTracking:
    """The env step acted on last, and the counts of what happened between steps."""

    def __init__(self, log):
        self.log = log  # the node's logger
        self.state: Optional[np.ndarray] = None  # s_t the last action answered
        self.key: Optional[tuple] = None  # its (env episode, env step)
        self.observation_gaps = 0  # an observation that skipped steps (a message was lost)
        self.stalls = 0  # times no observation came for stall_timeout_s mid-episode
        self.stalled_since: Optional[float] = None
        self.stopped_since: Optional[float] = None  # time.monotonic() when the current STOP began
        self.last_observation_time = time.monotonic()

    def follows(self, key: tuple) -> bool:
        """Whether ``key`` is the step after the one acted on."""
        return key[1] > 0 and self.state is not None and self.key is not None and key == (self.key[0], self.key[1] + 1)

    def observed(self) -> None:
        """An observation came: a stall, if there was one, is over."""
        now = time.monotonic()
        self.last_observation_time = now
        if self.stalled_since is not None:
            self.log.info(f'observations are back after {now - self.stalled_since:.1f} s')
            self.stalled_since = None

    def start_from(self, learner, env_step: EnvStep, key: tuple) -> None:
        """An observation that does not continue the transition acted on (module docstring)."""
        same_episode = self.key is not None and key[0] == self.key[0] and key[1] > self.key[1]
        if env_step.step == 0:
            if learner.episode_step > 0:
                self.log.warn(
                    f'the env started a new episode: abandoning episode '
                    f'{learner.episode} after {learner.episode_step} steps '
                    '(no row is written; the index is reused)'
                )
            learner.abandon_episode()  # a fresh start, also of an interrupted mark
            return
        if same_episode and learner.episode_step > 0:
            self.observation_gaps += 1
            self.log.warn(
                f'observation {key} does not follow {self.key}: '
                f'episode {learner.episode} continues, marked interrupted',
                throttle_duration_sec=5.0,
            )
        else:
            if learner.episode_step > 0:
                self.log.warn(
                    f'observation {key} is from another env episode than {self.key}: '
                    f'abandoning episode {learner.episode}',
                    throttle_duration_sec=5.0,
                )
                learner.abandon_episode()
            self.log.info(
                f'joining the env mid-episode at {key}: episode {learner.episode} is marked interrupted',
                throttle_duration_sec=5.0,
            )
        learner.mark_interrupted()

    def check_stall(self, learner, waiting_for_advice: bool, timeout_s: float) -> None:
        """Say, once per silence, that the env has gone quiet. Nothing is dropped: a paused or
        starved env (or this process itself starved) comes back with the next step of the same
        episode, which then simply continues; an env that restarted comes back with step 0,
        which abandons the unfinished episode (start_from)."""
        if (
            self.state is None
            or waiting_for_advice
            or self.stalled_since is not None
            or self.stopped_since is not None  # the person's STOP: a pause, not a stall
        ):
            return
        silent = time.monotonic() - self.last_observation_time
        if silent < timeout_s:
            return
        self.stalls += 1
        self.stalled_since = self.last_observation_time
        self.log.warn(
            f'no observation for {silent:.1f} s in episode {learner.episode} (step '
            f'{learner.episode_step}): waiting for the env; the episode continues if its next '
            'step comes, and is abandoned if the env starts a new one'
        )

    def stop(self, pressed: bool, learner) -> None:
        """The person's STOP pressed or released: the episode current at the release is paused for
        as long as it held (a stop latched before the learner existed counts when released)."""
        now = time.monotonic()
        if pressed and self.stopped_since is None:
            self.stopped_since = now
            if learner is not None:
                self.log.warn(f'STOPPED by the person: episode {learner.episode} paused')
        elif not pressed and self.stopped_since is not None:
            held, self.stopped_since = now - self.stopped_since, None
            self.last_observation_time = now  # the env steps again from now: no stall before
            if learner is not None:
                learner.note_stopped(held, starts=True)
                self.log.info(f'stop released after {held:.1f} s: episode {learner.episode} goes on')


def episode_line(summary: EpisodeSummary, failed: dict, experts: str) -> str:
    """The log line of a finished episode (``failed``: the run's failed requests by kind;
    ``experts``: who answered this episode, and how often)."""
    failures = ', '.join(f'{k} {v}' for k, v in failed.items() if v)
    person = (
        f'  person {summary.human_time_s:.1f} s (total {summary.human_time_total_s:.1f} s)'
        if summary.human_time_total_s
        else ''
    )
    taken = (
        f'  taken over {summary.takeover_steps} steps in {summary.takeovers} stretches ({summary.takeover_s:.1f} s)'
        if summary.takeover_steps
        else ''
    )
    stopped = f'  stopped {summary.stops}x ({summary.stopped_s:.1f} s)' if summary.stops else ''
    return (
        f'episode {summary.episode:4d}  return {summary.episode_return:9.2f}  len {summary.length:4d}  '
        f'advice {summary.advice_given}/{summary.advice_asked}'
        f'{" (%d from a person)" % summary.advice_human if summary.advice_human else ""}'
        f'{"  declined %d" % summary.advice_declined if summary.advice_declined else ""}'
        f'{"  failed %d (total: %s)" % (summary.advice_failed, failures) if summary.advice_failed else ""}'
        f'  success {int(summary.success)}  steps {summary.total_steps}  alpha {summary.alpha:.3f}'
        f'{"  INTERRUPTED (not seen whole)" if summary.interrupted else ""}'
        f'{person}'
        f'{taken}'
        f'{stopped}'
        f'{"  answered by: " + experts if experts else ""}'
    )
