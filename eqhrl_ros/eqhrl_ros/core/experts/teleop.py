"""A person as the expert: the latest teleop command becomes the advised action.

No ROS here: the teleop_expert node turns sensor_msgs/Joy, geometry_msgs/Twist or
a Float32MultiArray into plain lists and calls these functions.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable, Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike

from ..data.advice import SKIPPED, Advice, AdviceRequest
from .wheel import MIN_REACTION_S


@dataclass(frozen=True)
class Command:
    """One mapped teleop command: values per action dimension (env units, not yet clipped)."""

    values: np.ndarray
    enabled: bool  # the deadman/enable button is held (always True without one)
    disabled_reason: str = ''
    answer: bool = False  # the answer button is held: "use my command for this request"
    skip: bool = False  # the skip button is held: "no advice for this request"
    # The (episode, step) of the request the person's screen showed when they acted (the
    # console says it; a stick or keyboard_teleop may not): None, any open request.
    request: Optional[tuple] = None
    take_over: bool = False  # the take-over button is held: "my command, now, unasked"


def unit_values(values: Sequence[float], what: str) -> np.ndarray:
    """Joystick axes and teleop_command values: finite and in [-1, 1] (their documented range),
    else ValueError. An inf or 1e30 would otherwise become full-scale advice, a NaN an answer."""
    array = np.asarray(values, dtype=np.float64)
    if not np.isfinite(array).all():
        raise ValueError(f'{what} holds a non-finite value: {list(values)}')
    if array.size and float(np.abs(array).max()) > 1.0 + 1e-6:
        raise ValueError(f'{what} holds a value outside [-1, 1]: {float(np.abs(array).max()):.3g}')
    return array


def affine(values: ArrayLike, scales: ArrayLike, offsets: ArrayLike) -> np.ndarray:
    array = np.asarray(values, dtype=np.float32)
    return array * np.asarray(scales, dtype=np.float32) + np.asarray(offsets, dtype=np.float32)


def joy_command(
    axes: Sequence[float],
    buttons: Sequence[int],
    axis_indices: Sequence[int],
    scales: Sequence[float],
    offsets: Sequence[float],
    require_enable_button: bool = True,
    enable_button: int = 0,
    answer_button: int = -1,
    skip_button: int = -1,
) -> Command:
    """sensor_msgs/Joy -> Command, in the style of teleop_twist_joy (axis index and scale per output).

    An axis index beyond the joystick's axes reads as 0; a button index of -1 (or beyond the
    joystick's buttons) is a button that is never held.
    """

    def held(index: int) -> bool:
        return 0 <= index < len(buttons) and bool(buttons[index])

    raw = unit_values([axes[i] if 0 <= i < len(axes) else 0.0 for i in axis_indices], 'joy axes')
    values = affine(raw, scales, offsets)
    answer, skip = held(answer_button), held(skip_button)
    if require_enable_button and not held(enable_button):
        return Command(values, False, f'enable (deadman) button {enable_button} is not held', answer, skip)
    return Command(values, True, '', answer, skip)


def joy_misfit(n_axes: int, n_buttons: int, axis_indices: Sequence[int], buttons: dict) -> str:
    """What of a joy mapping the joystick cannot give ('' when it all fits): an axis it lacks reads
    as 0 and a button it lacks is never held (joy_command), so the person would steer or press
    and see nothing happen. ``buttons``: a button's parameter name -> its index (-1: none)."""
    problems = [f'axes[{i}] is {a}' for i, a in enumerate(axis_indices) if not 0 <= a < n_axes]
    problems += [f'{name} is {b}' for name, b in buttons.items() if b >= n_buttons]
    if not problems:
        return ''
    return (
        f"'joy' has {n_axes} axes and {n_buttons} buttons, but {', '.join(problems)}: "
        'that axis reads as 0 and that button is never held (set axes and the buttons to what '
        '`ros2 topic echo /joy` shows moving)'
    )


TWIST_FIELDS = ('linear.x', 'linear.y', 'linear.z', 'angular.x', 'angular.y', 'angular.z')


def twist_command(
    read: Callable[[str], float], fields: Sequence[str], scales: Sequence[float], offsets: Sequence[float]
) -> Command:
    """geometry_msgs/Twist -> Command: ``fields`` names one Twist field per action dimension.

    ``read('angular.z')`` returns that field's value. teleop_twist_keyboard and the like
    publish a zero Twist when keys are released, so a Twist has no deadman: staleness covers it.
    """
    values = [read(f) for f in fields]
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f'cmd_vel holds a non-finite value: {values}')
    return Command(affine(values, scales, offsets), True)


# The teleop_command message (std_msgs/Float32MultiArray), as keyboard_teleop and
# advice_console publish it: labelled fields, 'command' first. A plain unlabelled array is
# all command, always enabled, with no buttons.
COMMAND_FIELDS = ('command', 'enabled', 'answer', 'skip')
# A command may also name the request it was meant for: 'request' = [episode, step].
REQUEST_FIELD = 'request'


def array_command(fields: dict, indices: Sequence[int], scales: Sequence[float], offsets: Sequence[float]) -> Command:
    """A Float32MultiArray command read into ``fields`` ({label: values}): value ``indices[i]``
    of 'command' drives action dimension i; 'enabled' (the deadman), 'answer' and 'skip' are
    buttons, held when non-zero (an absent one reads: enabled, not pressed)."""
    data = list(fields.get('command', ()))
    if any(i >= len(data) or i < 0 for i in indices):
        raise ValueError(f'command has {len(data)} values, the mapping reads indices {list(indices)}')

    def held(label: str, default: bool) -> bool:
        values = fields.get(label)
        return default if not values else bool(values[0])

    enabled = held('enabled', True)
    shown = fields.get(REQUEST_FIELD)
    return Command(
        affine(unit_values([data[i] for i in indices], 'command'), scales, offsets),
        enabled,
        '' if enabled else 'the deadman is not held',
        held('answer', False),
        held('skip', False),
        (int(shown[0]), int(shown[1])) if shown is not None and len(shown) == 2 else None,
        held('take_over', False),
    )


ANSWER_MODES = ('window', 'instant')


@dataclass
class OpenRequest:
    """A request held open for the person to answer."""

    request: AdviceRequest
    opened: float  # clock() when it arrived
    values: Optional[np.ndarray]  # the command held when it arrived (None: none yet)
    steered: Optional[np.ndarray] = None  # the command the person is steering to (deadman held)
    steered_at: float = 0.0  # clock() of its last change
    appeared: float = 0.0  # clock() when it arrived, never moved (``opened`` is, by a STOP's hold)


class TeleopExpert:
    """An Expert (core interface) that answers with a person's command.

    Two ways to answer (the teleop_expert node's ``answer_mode``):
    - ``window``: ``open(request)`` holds the request until the person acts. ``update``
      returns the answer when a command answers it, with the deadman held: the answer button
      pressed, or a command that differs from the one held when the request came (by more
      than ``answer_change`` in some dimension) and has then held still for ``settle_s``
      (the person steers to a value and stops there: the answer is where they stopped, not
      their first key step; ``settled()`` says so between commands); the deadman pressed alone
      does not answer; the skip button declines. A command sooner than MIN_REACTION_S after
      the request came cannot be a reaction to it: it becomes the command held when it came
      (a key pressed for the request before stays that one's). ``expire`` ends
      it unanswered (a timeout). Each answer carries the person's reaction time.
    - ``instant`` (calling it): the latest command at once, for a person who holds the stick
      all along (HIL-SERL-style intervention).
    Either way it declines, with a reason, a command that is missing, stale (older than
    ``stale_after_s``), without its deadman, or of the wrong size; an advised action is
    clipped into the env's bounds (given in each request) and marked human.
    """

    def __init__(
        self,
        stale_after_s: float = 0.5,
        name: str = 'teleop',
        clock: Callable[[], float] = time.monotonic,
        answer_change: float = 0.05,
        settle_s: float = 0.3,
    ):
        if stale_after_s <= 0:
            raise ValueError(f'stale_after_s must be > 0, got {stale_after_s}')
        self.stale_after_s = stale_after_s
        self.answer_change = answer_change
        self.settle_s = settle_s
        self.name = name
        self._clock = clock
        self._command: Optional[Command] = None
        self._stamp = 0.0
        self.pending: Optional[OpenRequest] = None
        self.held = False  # a STOP holds the open request: commands are heard, nothing answers

    # ------------------------------------------------------------------ instant

    def __call__(self, request: AdviceRequest) -> Advice:
        command = self._command
        if command is None:
            return Advice.decline('no teleop command received yet', self.name)
        age = self._clock() - self._stamp
        if age > self.stale_after_s:
            return Advice.decline(
                f'last teleop command is {age:.2f} s old (stale after {self.stale_after_s:g} s)', self.name
            )
        return self._advice(command, request, 0.0)

    def _advice(self, command: Command, request: AdviceRequest, reaction_s: float) -> Advice:
        if not command.enabled:
            return Advice.decline(command.disabled_reason or 'teleop disabled', self.name, True, reaction_s)
        low = np.asarray(request.action_low, dtype=np.float32)
        high = np.asarray(request.action_high, dtype=np.float32)
        if command.values.shape[0] != low.shape[0]:
            return Advice.decline(
                f'teleop command has {command.values.shape[0]} values, the env action has {low.shape[0]}',
                self.name,
                True,
                reaction_s,
            )
        return Advice(np.clip(command.values, low, high), expert_name=self.name, human=True, response_time_s=reaction_s)

    # ------------------------------------------------------------------ answer window

    def open(self, request: AdviceRequest) -> None:
        """Hold ``request`` open for the person (a request still open is replaced)."""
        held = self._command.values.copy() if self._command is not None else None
        now = self._clock()
        self.pending = OpenRequest(request, now, held, appeared=now)

    def update(self, command: Command) -> Optional[Advice]:
        """Take the person's latest command; returns the answer to the open request if this
        command gives one (the request is then closed), else None."""
        previous = self._command
        self._command, self._stamp = command, self._clock()
        pending = self.pending
        if pending is None or self.held:
            return None

        def pressed(button: str) -> bool:  # a rising edge: held now, not in the previous command
            return getattr(command, button) and not (previous is not None and getattr(previous, button))

        reaction = self._stamp - pending.opened
        if command.request is not None and command.request != (pending.request.episode, pending.request.step):
            return None  # meant for the request the person saw, not this newer one they have not seen
        if self._stamp - pending.appeared < MIN_REACTION_S:  # too soon to be a reaction: made for what came before
            pending.values = command.values.copy()
            return None
        if pressed('skip'):
            self.pending = None
            return Advice.decline(SKIPPED, self.name, True, reaction)
        # The deadman permits an answer and never gives one: pressed alone it would send the
        # command held before (the person who holds Shift first and then steers meant another).
        if not command.enabled:
            pending.steered = None
            return None  # nothing is given without the deadman
        if pressed('answer'):
            return self._answer(command, reaction)
        if not self._differs(command.values, pending.values):
            pending.steered = None
            return None
        if pending.steered is None or self._differs(command.values, pending.steered):
            pending.steered, pending.steered_at = command.values.copy(), self._stamp  # still steering
            if self.settle_s > 0:
                return None
        return self.settled()

    def _differs(self, values: np.ndarray, other: Optional[np.ndarray]) -> bool:
        return (
            other is None
            or other.shape != values.shape
            or (float(np.max(np.abs(values - other), initial=0.0)) > self.answer_change)
        )

    def _answer(self, command: Command, reaction: float) -> Advice:
        pending, self.pending = self.pending, None
        assert pending is not None  # only called with a request open
        return self._advice(command, pending.request, reaction)

    def settled(self) -> Optional[Advice]:
        """The answer, once the command the person steered to has held still for settle_s with
        the deadman held (called on every command, and by the node between commands); else None."""
        pending, command = self.pending, self._command
        if pending is None or self.held or pending.steered is None or command is None or not command.enabled:
            return None
        now = self._clock()
        if now - pending.steered_at < self.settle_s - 1e-9 or now - self._stamp > self.stale_after_s:
            return None
        return self._answer(command, now - pending.opened)

    def expire(self, window_s: float) -> Optional[Advice]:
        """The answer window passed: the open request ends unanswered (None if none was open)."""
        if self.pending is None:
            return None
        self.pending = None
        return Advice.no_answer(window_s, self.name)

    def withdraw(self, reason: str) -> Optional[Advice]:
        """End the open request without the person (e.g. a newer request replaces it)."""
        if self.pending is None:
            return None
        pending, self.pending = self.pending, None
        return Advice.decline(reason, self.name, True, self._clock() - pending.opened)
