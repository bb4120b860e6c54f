"""Who drives, step by step: the learner, the person because they were asked (the wheel
protocol, core/experts/wheel.py) or the person unasked (core/experts/takeover.py).

The acting node hands it the person's commands (``heard``) and, at every step, asks ``turn``
first: a step it decides is the person's, or the learner's own while a request for the wheel
waits to be taken; None leaves the step to the gates. ``ask`` opens a request for the wheel
when they fire. What it decides is counted in the learner (the person's seconds step by step,
so that the budget in seconds closes within a step), said on ``learner/advice_request`` (the
page and keyboard_teleop alert from it) and on ``learner/driver`` (latched, on each change).
"""

from __future__ import annotations

import math
from typing import Callable, Optional

import numpy as np

from ..core.algorithm.learner import EQSACLearner, Proposal
from ..core.envs.spec import EnvSpec
from ..core.experts.takeover import DeadmanTakeover, PersonCommand, heard
from ..core.experts.wheel import AskedWheel, WheelRules, WheelTurn
from . import messages

# learner/driver (std_msgs/String, latched): who drives now, one of these.
DRIVERS = ('learner', 'person_asked', 'person_unasked')


class PersonWheel:
    """The person's side of each step (module docstring)."""

    def __init__(
        self, learner: EQSACLearner, threshold: float, publish_request: Callable, publish_driver: Callable, log
    ):
        self.learner = learner
        self.takeover = DeadmanTakeover(learner.scaler, threshold)
        self.publish_request = publish_request  # (AdviceRequest msg) -> None
        self.publish_driver = publish_driver  # (driver name) -> None
        self.log = log
        self.person: Optional[PersonCommand] = None
        self.open: Optional[AskedWheel] = None
        self.proposal: Optional[Proposal] = None  # the proposal whose gates opened the request
        self.last_action: Optional[np.ndarray] = None  # the person's last action (for the outcome)
        self.driver = ''
        self._say_driver('learner')

    # ------------------------------------------------------------------ input

    def heard(self, action: np.ndarray, deadman: bool, take_over: bool, now: float) -> None:
        self.person = heard(self.person, action, deadman, take_over, now)

    def _say_driver(self, driver: str) -> None:
        if driver != self.driver:
            self.driver = driver
            self.publish_driver(driver)

    # ------------------------------------------------------------------ each step

    def turn(self, proposal: Proposal, now: float) -> Optional[tuple[np.ndarray, bool, str]]:
        """(action, advised, source) when the person decides this step (or a request for the wheel
        is open), else None: the gates decide."""
        if self.open is not None:
            return self._asked_turn(proposal, now)
        taken = self.takeover.person_drives(self.person, proposal.action, now)
        learner = self.learner
        if taken is not None and 2 * taken.seconds > learner.person_budget_left_s:
            # The next step would pass the person's seconds: the learner drives from here (STOP still
            # holds the robot), so that the budget is not overspent.
            taken = None
        if taken is not None:
            resolution = learner.take_over(proposal, taken.action, taken.seconds, taken.starts)
            self.takeover.taken(now, accepted=resolution.outcome == 'taken over')
            if taken.starts and self.takeover.taking_over:
                self.log.info(f'the person takes over at episode {learner.episode}, step {learner.episode_step}')
            self._say_driver('person_unasked' if self.takeover.taking_over else 'learner')
            return (*resolution.action_and_advised(), resolution.source)
        if self.takeover.hand_back():
            self.log.info('the person hands control back to the learner')
        self._say_driver('learner')
        return None

    def ask(self, proposal: Proposal, now: float, env_step: int, pace: EnvSpec) -> np.ndarray:
        """The gates fired: alert the person to take the wheel; the learner drives meanwhile.
        The time to take it is wheel_take_s, cut to what is left of the episode (when its length
        is known: ``pace``, the env's own env_info) and of the person's budget: a countdown never
        promises more than there is."""
        config = self.learner.config
        take_s = min(config.wheel_take_s, self.learner.person_budget_left_s, _episode_left_s(pace, env_step))
        rules = WheelRules(max(take_s, 1e-3), config.wheel_max_s, config.wheel_agree, config.wheel_agree_steps)
        self.open, self.proposal, self.last_action = AskedWheel(now, rules, self.learner.scaler), proposal, None
        self._publish('pending')
        return proposal.action

    def _asked_turn(self, proposal: Proposal, now: float) -> tuple[np.ndarray, bool, str]:
        learner, wheel = self.learner, self.open
        turn = wheel.step(self.person, proposal.action, now, learner.person_budget_left_s)
        learner.count_person_seconds(turn.seconds, asked=True)
        if turn.ended:
            self._end(turn)
            return proposal.action, False, 'learner'  # handed back: the learner drives this step
        if turn.action is None:  # waiting to be taken: the learner's own policy, never a held action
            return proposal.action, False, 'learner'
        resolution = learner.drive_asked(proposal, turn.action)
        if resolution.outcome != 'asked':  # an action out of bounds: not the person's step
            return (*resolution.action_and_advised(), resolution.source)
        self.last_action = resolution.action
        if turn.starts:
            self.log.info(f'the person takes the wheel at episode {learner.episode}, step {learner.episode_step}')
            self._publish('taken')
        self._say_driver('person_asked')
        return (*resolution.action_and_advised(), resolution.source)

    def _end(self, turn: WheelTurn) -> None:
        self.learner.end_wheel_request(turn.ended, turn.taken)
        if turn.taken:
            self.log.info(f'the person hands the wheel back ({turn.ended}) after {self.open.steps} steps')
            self._publish('given', detail=turn.ended)
        else:
            failure = 'budget_spent' if turn.ended == 'budget' else turn.ended
            self._publish('failed', detail=failure)
        self.open = self.proposal = None
        self._say_driver('learner')

    def _publish(self, outcome: str, detail: str = '') -> None:
        wheel, request = self.open, self.proposal.request
        seconds = wheel.counted_to - (wheel.alerted_at if outcome != 'pending' else wheel.counted_to)
        self.publish_request(
            messages.advice_request_msg(
                outcome,
                request,
                wheel.rules.take_s if outcome == 'pending' else wheel.seconds_left(wheel.counted_to),
                detail,
                human=outcome in ('given', 'failed') and detail != 'episode_ended',
                response_time_s=max(0.0, seconds),
                given_action=self.last_action if outcome in ('given', 'taken') and self.last_action is not None else (),
                wheel=True,
                steps_driven=wheel.steps,
            )
        )

    # ------------------------------------------------------------------ the episode and STOP

    def episode_ends(self, now: float) -> None:
        """The episode ends with a request open (before the summary is made): count it."""
        if self.open is not None:
            turn = self.open.end_episode(now)
            self.learner.count_person_seconds(turn.seconds, asked=True)
            self._end(turn)
        if self.takeover.hand_back():
            self._say_driver('learner')

    def stopped(self, stop: bool, now: float) -> None:
        """STOP pauses the open request and its countdown; released, they go on."""
        if self.open is None:
            return
        if stop:
            self.open.pause(now)
            self._publish_paused('stopped', now)
        else:
            self.open.resume(now)
            self._publish_paused('', now)

    def _publish_paused(self, detail: str, now: float) -> None:
        """The open request again, with what is left of its time ('stopped': held by STOP)."""
        wheel = self.open
        left = wheel.seconds_left(now)
        outcome = 'taken' if wheel.taken else 'pending'
        self.publish_request(
            messages.advice_request_msg(
                outcome,
                self.proposal.request,
                left,
                detail,
                wheel=True,
                steps_driven=wheel.steps,
                response_time_s=max(0.0, wheel.counted_to - wheel.alerted_at),
                given_action=self.last_action if wheel.taken and self.last_action is not None else (),
            )
        )


def _episode_left_s(pace: EnvSpec, env_step: int) -> float:
    """Seconds left of the episode at ``env_step`` (inf when its length or rate is unknown)."""
    if pace.max_episode_steps <= 0 or pace.rate_hz <= 0:
        return math.inf
    return max(0.0, (pace.max_episode_steps - env_step) / pace.rate_hz)
