"""What came of each request and each step the person drove, counted in the episode's
AdviceCounts: one answer (the paper's protocol), a stretch asked for (the wheel,
core/experts/wheel.py), a takeover unasked, and the person's seconds on each. The learner
calls these with its open episode's counts (learner.py); nothing here holds state.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..data.advice import FAILURE_KINDS, OUTCOME_SOURCES, Advice, AdviceRequest, check_advised_action
from ..envs.spec import ActionScaler
from .advice_counts import AdviceCounts
from .advising import GateDecision

# How an untaken request for the wheel ended (wheel.UNTAKEN) and the failure kind it counts as.
UNTAKEN_FAILURES = {'timeout': 'timeout', 'budget': 'budget_spent', 'episode_ended': 'episode_ended'}


@dataclass(frozen=True)
class Proposal:
    """The learner's own action for s_t, the gate decision, and the request to send if it fired."""

    action: np.ndarray  # env units
    decision: GateDecision
    request: Optional[AdviceRequest]


@dataclass(frozen=True)
class Resolution:
    """How an advice request ended: the action to take, and why."""

    action: np.ndarray  # env units: the advice, or the learner's own action
    advised: bool  # the advice is used (and goes to D_advising)
    outcome: str  # 'given', 'declined', 'failed' or 'taken over'
    detail: str = ''  # the failure kind, or the expert's reason for declining

    @property
    def source(self) -> str:
        """Who chose the action it gives (one of ACTION_SOURCES)."""
        return OUTCOME_SOURCES.get(self.outcome, 'learner')

    def action_and_advised(self) -> tuple[np.ndarray, bool]:
        """(action, advised): what Algorithm 1 acts with and stores."""
        return self.action, self.advised


def resolve(
    counts: AdviceCounts,
    proposal: Proposal,
    advice: Optional[Advice],
    failure: str,
    scaler: ActionScaler,
    seconds_left: float,
) -> Resolution:
    """Count the outcome of a request for one answer and return what to do.

    ``failure`` names why no answer came (one of FAILURE_KINDS); otherwise ``advice`` is the
    answer. A refusal or a failure leaves the learner's own action. A person's time on the
    request (advice.response_time_s) is counted whatever they said; a person's answer window
    that passed (advice.timed_out) counts as a timeout, and so does an answer that came after
    the person's seconds (``seconds_left``) ran out: their window ended there (the nodes cut
    the wait to it; a simulated person's later answer is cut the same way here).
    """
    if advice is not None and advice.human and advice.response_time_s > seconds_left:
        advice = Advice.no_answer(seconds_left, advice.expert_name)
    counts.asked += 1
    if advice is not None and advice.human:
        counts.human_time_s += max(0.0, float(advice.response_time_s))
    if advice is not None and advice.timed_out:
        failure = 'timeout'
    if failure:
        if failure not in counts.failed:
            raise ValueError(f'unknown failure kind {failure!r}; one of {FAILURE_KINDS}')
        counts.failed[failure] += 1
        return Resolution(proposal.action, False, 'failed', failure)
    if advice is None or not advice.advised:
        counts.declined += 1
        return Resolution(proposal.action, False, 'declined', advice.reason if advice else '')
    action, failure = check_advised_action(advice.action, scaler.low, scaler.high)
    if failure or action is None:
        counts.failed[failure] += 1
        return Resolution(proposal.action, False, 'failed', failure)
    counts.given += 1
    counts.human += int(advice.human)
    return Resolution(action, True, 'given')


def take_over(
    counts: AdviceCounts,
    proposal: Proposal,
    action,
    seconds: float,
    starts: bool,
    scaler: ActionScaler,
    to_memory: bool,
) -> Resolution:
    """The person took this step over unasked (mixed initiative): their action replaces the
    learner's, counted apart from answered requests (``starts``: a new stretch of takeover;
    ``seconds``: the person's time on this step). The step goes to D_advising too when
    ``to_memory`` (takeover_to_advice_memory) is set. An action outside the bounds is refused."""
    action, failure = check_advised_action(action, scaler.low, scaler.high)
    if failure:
        return Resolution(proposal.action, False, 'failed', failure)
    counts.takeovers += int(starts)
    counts.takeover_steps += 1
    counts.takeover_s += max(0.0, float(seconds))
    return Resolution(action, to_memory, 'taken over')


def drive_asked(counts: AdviceCounts, proposal: Proposal, action, scaler: ActionScaler) -> Resolution:
    """A step of a stretch the person drives because they were asked to (the wheel): their action
    replaces the learner's and goes to D_advising. The request itself is counted when it ends
    (end_wheel_request); an action outside the bounds is refused (the learner's own action goes)."""
    action, failure = check_advised_action(action, scaler.low, scaler.high)
    if failure:
        return Resolution(proposal.action, False, 'failed', failure)
    counts.asked_steps += 1
    return Resolution(action, True, 'asked')


def end_wheel_request(counts: AdviceCounts, ended: str, taken: bool) -> None:
    """A request for the wheel ended: taken (advice given by a person, whatever ended the
    stretch), or not (a timeout, the budget spent, or the episode's end)."""
    counts.asked += 1
    if taken:
        counts.given += 1
        counts.human += 1
        return
    counts.failed[UNTAKEN_FAILURES[ended]] += 1


def count_person_seconds(counts: AdviceCounts, seconds: float, asked: bool) -> None:
    """The person's seconds on this step: on a request (asked) or an unasked takeover. Counted
    as they pass, so that the budget in seconds closes within a step of being spent."""
    if asked:
        counts.human_time_s += max(0.0, float(seconds))
    else:
        counts.takeover_s += max(0.0, float(seconds))
