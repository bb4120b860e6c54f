"""A person as the expert: the latest teleop command becomes the advised action.

No ROS here: the teleop_expert node turns sensor_msgs/Joy, geometry_msgs/Twist or
a Float32MultiArray into plain lists and calls these functions.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Optional, Sequence

import numpy as np

from .experts import Advice, AdviceRequest


@dataclass(frozen=True)
class Command:
    """One mapped teleop command: values per action dimension (env units, not yet clipped)."""

    values: np.ndarray
    enabled: bool  # the deadman/enable button is held (always True without one)
    disabled_reason: str = ''


def affine(values: Sequence[float], scales: Sequence[float], offsets: Sequence[float]) -> np.ndarray:
    values = np.asarray(values, dtype=np.float32)
    return values * np.asarray(scales, dtype=np.float32) + np.asarray(offsets, dtype=np.float32)


def joy_command(
    axes: Sequence[float],
    buttons: Sequence[int],
    axis_indices: Sequence[int],
    scales: Sequence[float],
    offsets: Sequence[float],
    require_enable_button: bool = True,
    enable_button: int = 0,
) -> Command:
    """sensor_msgs/Joy -> Command, in the style of teleop_twist_joy (axis index and scale per output).

    An axis index beyond the joystick's axes reads as 0.
    """
    raw = [axes[i] if 0 <= i < len(axes) else 0.0 for i in axis_indices]
    values = affine(raw, scales, offsets)
    if require_enable_button:
        held = 0 <= enable_button < len(buttons) and bool(buttons[enable_button])
        if not held:
            return Command(values, False, f'enable (deadman) button {enable_button} is not held')
    return Command(values, True)


TWIST_FIELDS = ('linear.x', 'linear.y', 'linear.z', 'angular.x', 'angular.y', 'angular.z')


def twist_command(
    read: Callable[[str], float], fields: Sequence[str], scales: Sequence[float], offsets: Sequence[float]
) -> Command:
    """geometry_msgs/Twist -> Command: ``fields`` names one Twist field per action dimension.

    ``read('angular.z')`` returns that field's value. teleop_twist_keyboard and the like
    publish a zero Twist when keys are released, so a Twist has no deadman: staleness covers it.
    """
    return Command(affine([read(f) for f in fields], scales, offsets), True)


def array_command(
    data: Sequence[float], indices: Sequence[int], scales: Sequence[float], offsets: Sequence[float]
) -> Command:
    """A plain Float32MultiArray command: value ``indices[i]`` drives action dimension i."""
    if any(i >= len(data) or i < 0 for i in indices):
        raise ValueError(f'command has {len(data)} values, the mapping reads indices {list(indices)}')
    return Command(affine([data[i] for i in indices], scales, offsets), True)


class TeleopExpert:
    """An Expert (core interface) that answers with a person's latest command.

    Declines, with a reason, when no command has arrived yet, when the latest one is
    older than ``stale_after_s``, when its deadman is not held, or when its size does
    not match the env's action. Otherwise it clips the command into the env's bounds
    (given in each request) and marks the advice as human.
    """

    def __init__(self, stale_after_s: float = 0.5, name: str = 'teleop', clock: Callable[[], float] = time.monotonic):
        if stale_after_s <= 0:
            raise ValueError(f'stale_after_s must be > 0, got {stale_after_s}')
        self.stale_after_s = stale_after_s
        self.name = name
        self._clock = clock
        self._command: Optional[Command] = None
        self._stamp = 0.0

    def update(self, command: Command) -> None:
        self._command = command
        self._stamp = self._clock()

    def __call__(self, request: AdviceRequest) -> Advice:
        command = self._command
        if command is None:
            return Advice.decline('no teleop command received yet', self.name)
        age = self._clock() - self._stamp
        if age > self.stale_after_s:
            return Advice.decline(
                f'last teleop command is {age:.2f} s old (stale after {self.stale_after_s:g} s)', self.name
            )
        if not command.enabled:
            return Advice.decline(command.disabled_reason or 'teleop disabled', self.name)
        low = np.asarray(request.action_low, dtype=np.float32)
        high = np.asarray(request.action_high, dtype=np.float32)
        if command.values.shape[0] != low.shape[0]:
            return Advice.decline(
                f'teleop command has {command.values.shape[0]} values, the env action has {low.shape[0]}', self.name
            )
        return Advice(np.clip(command.values, low, high), expert_name=self.name, human=True)
