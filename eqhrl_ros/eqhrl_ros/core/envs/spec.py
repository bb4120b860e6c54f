"""What a learner needs to know about an env, whoever provides it: EnvSpec, and success.

An env node announces an EnvSpec (as eqhrl_interfaces/msg/EnvInfo on `env_info`); a
gymnasium id gives one too (envs.gym_spec); a user may give the spaces as parameters.
No gymnasium and no torch here, so that light nodes (a teleop) can read it.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, fields
from typing import Optional

import numpy as np

from ..data.camera_frames import MAX_FRAME_PIXELS, MAX_FRAME_STACK

# How success is judged (EnvInfo.success_rule; the message's SUCCESS_* constants are checked
# against this tuple by the tests).
SUCCESS_RULES = ('none', 'reported', 'return_at_least', 'pendulum_upright')


# Sizes beyond any flat observation or action this learner is built for: an announcement
# outside them is refused before a network of that size is made.
MAX_OBSERVATION_SIZE = 1_000_000
MAX_ACTION_SIZE = 10_000
# A label names one value for a person (the console's bars, the record): a word or a few, on one line.
MAX_LABEL_LENGTH = 64
# A topic a node subscribes to because an env announced it (a camera's): a ROS name, relative,
# absolute or private (~/...), with no substitution. Before, another name raised in the middle
# of the learner's (or the person's console's) start, where it stopped the node with a traceback.
TOPIC_NAME = re.compile(r'(?:~/|/)?[A-Za-z_][A-Za-z0-9_]*(?:/[A-Za-z_][A-Za-z0-9_]*)*')
MAX_TOPIC_LENGTH = 255


def builtin_success(name: str) -> tuple[str, float]:
    """The built-in success rule of a gymnasium env: Pendulum ends balanced; LunarLander
    reaches 200, the env's solved line. Any other env: none (an env node may report it)."""
    if name.startswith('Pendulum'):
        return 'pendulum_upright', 0.0
    if name.startswith('LunarLander'):
        return 'return_at_least', 200.0
    return 'none', 0.0


# A camera the learner can read: at most this many pixels a frame (a 4096x4096 frame is 16.8 M
# pixels, what camera_frames accepts from a topic) and frames a stack.
MAX_CAMERA_PIXELS = MAX_FRAME_PIXELS
CAMERA_CHANNELS = (1, 3)  # mono or colour: what camera_frames' encodings give


@dataclass(frozen=True)
class CameraSpec:
    """A camera part of an observation: each frame height x width x channels uint8 (a camera's
    layout, sensor_msgs/Image), and how many of the newest frames the learner reads at once
    (``stack``; an episode's first stacks repeat its first frame)."""

    height: int
    width: int
    channels: int = 3
    stack: int = 3

    def __post_init__(self):
        for name in ('height', 'width', 'channels', 'stack'):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                raise ValueError(f'camera {name} must be an integer, got {value!r}')
            object.__setattr__(self, name, int(value))
        if self.channels not in CAMERA_CHANNELS:
            raise ValueError(f'camera channels must be one of {CAMERA_CHANNELS}, got {self.channels}')
        if not (1 <= self.height and 1 <= self.width and self.height * self.width <= MAX_CAMERA_PIXELS):
            raise ValueError(f'camera frames of {self.height}x{self.width} (at most {MAX_CAMERA_PIXELS} pixels)')
        if not 1 <= self.stack <= MAX_FRAME_STACK:
            raise ValueError(f'camera stack must be in [1, {MAX_FRAME_STACK}], got {self.stack}')

    @property
    def frame_shape(self) -> tuple[int, int, int]:
        """(channels, height, width): one frame as a convolution reads it."""
        return (self.channels, self.height, self.width)

    @property
    def stack_shape(self) -> tuple[int, int, int, int]:
        """(stack, height, width, channels): the stack an observation carries, oldest first."""
        return (self.stack, self.height, self.width, self.channels)

    @property
    def stack_size(self) -> int:
        """Values in one stack."""
        return self.stack * self.height * self.width * self.channels


def check_label(what: str, label, where: str = '') -> None:
    """A name a person reads (a label, a camera's name): ValueError unless one short printable line."""
    if not (isinstance(label, str) and len(label) <= MAX_LABEL_LENGTH and label.isprintable()):
        raise ValueError(
            f'{what} {_quoted(str(label))}: each label must be printable text on one line, at most '
            f'{MAX_LABEL_LENGTH} characters{where}'
        )


def _quoted(text: str) -> str:
    """Another node's text in a message: escaped, and cut when long."""
    return repr(text) if len(text) <= 40 else f'{text[:40]!r}... ({len(text)} characters)'


@dataclass(frozen=True)
class EnvCamera:
    """A camera an env announces beside its observation vector (EnvInfo.cameras): its name, the
    topic its frames come on, their size and encoding (camera_frames.ENCODINGS)."""

    name: str
    topic: str
    height: int
    width: int
    encoding: str

    def __post_init__(self):
        from ..data.camera_frames import ENCODINGS

        if not self.name or not self.topic:
            raise ValueError(f'a camera needs a name and a topic, got {self.name!r} on {self.topic!r}')
        check_label('camera name', self.name)
        if len(self.topic) > MAX_TOPIC_LENGTH or not TOPIC_NAME.fullmatch(self.topic):
            raise ValueError(
                f'camera {self.name!r}: topic {_quoted(self.topic)} is not a ROS topic name (letters, digits and _ '
                f'in parts joined by /, none starting with a digit, at most {MAX_TOPIC_LENGTH} characters)'
            )
        if self.encoding not in ENCODINGS:
            raise ValueError(f'camera {self.name!r}: encoding {self.encoding!r} is not one of {", ".join(ENCODINGS)}')
        if not (1 <= self.height and 1 <= self.width and self.height * self.width <= MAX_CAMERA_PIXELS):
            raise ValueError(f'camera {self.name!r}: frames of {self.height}x{self.width} pixels')

    @property
    def channels(self) -> int:
        from ..data.camera_frames import ENCODINGS

        return ENCODINGS[self.encoding]

    def spec(self, stack: int) -> 'CameraSpec':
        """What a learner reads from this camera, ``stack`` frames at a time."""
        return CameraSpec(self.height, self.width, self.channels, stack)


@dataclass(frozen=True, eq=False)
class EnvSpec:
    """An env's interface: observation size, action bounds, pace and success rule."""

    name: str
    observation_size: int
    action_low: np.ndarray
    action_high: np.ndarray
    observation_labels: tuple = ()
    action_labels: tuple = ()
    max_episode_steps: int = 0  # 0: no limit
    realtime: bool = False
    rate_hz: float = 0.0
    success_rule: str = 'none'
    success_threshold: float = 0.0
    cameras: tuple = ()  # EnvCamera each, beside the observation vector
    source: str = field(default='', compare=False)  # where it came from, for messages

    def __post_init__(self):
        low = np.asarray(self.action_low, dtype=np.float32).reshape(-1)
        high = np.asarray(self.action_high, dtype=np.float32).reshape(-1)
        object.__setattr__(self, 'action_low', low)
        object.__setattr__(self, 'action_high', high)
        object.__setattr__(self, 'observation_labels', tuple(self.observation_labels))
        object.__setattr__(self, 'action_labels', tuple(self.action_labels))
        object.__setattr__(self, 'cameras', tuple(self.cameras))
        where = f' ({self.source})' if self.source else ''
        if not 1 <= self.observation_size <= MAX_OBSERVATION_SIZE:
            raise ValueError(
                f'observation size must be in [1, {MAX_OBSERVATION_SIZE:,}], got {self.observation_size}{where}'
            )
        if low.size > MAX_ACTION_SIZE:
            raise ValueError(f'action size must be at most {MAX_ACTION_SIZE:,}, got {low.size}{where}')
        if low.shape != high.shape or low.size == 0:
            raise ValueError(
                f'action_low has {low.size} values and action_high {high.size}; '
                f'they must have one per action dimension{where}'
            )
        if not (np.isfinite(low).all() and np.isfinite(high).all()) or (high <= low).any():
            raise ValueError(
                f'action bounds must be finite with high > low in every dimension: '
                f'low {low.tolist()}, high {high.tolist()}{where}'
            )
        for kind, labels, size in (
            ('observation', self.observation_labels, self.observation_size),
            ('action', self.action_labels, low.size),
        ):
            if labels and len(labels) != size:
                raise ValueError(f'{len(labels)} {kind} labels for {size} {kind} values{where}')
            for label in labels:
                check_label(f'{kind} label', label, where)
        if self.success_rule not in SUCCESS_RULES:
            raise ValueError(f'success rule {self.success_rule!r} is not one of {SUCCESS_RULES}{where}')
        if not math.isfinite(self.success_threshold):
            raise ValueError(f'success threshold must be finite{where}')
        if not (math.isfinite(self.rate_hz) and self.rate_hz >= 0.0):
            # The learner reads a real-time episode's seconds left from it: a NaN or infinite rate left
            # none, and each request for the wheel ended before a person could take it.
            raise ValueError(
                f'rate_hz must be a finite number of steps a second, >= 0 (0: not said), got {self.rate_hz}{where}'
            )
        names = [camera.name for camera in self.cameras]
        if len(set(names)) != len(names) or not all(isinstance(c, EnvCamera) for c in self.cameras):
            raise ValueError(f'cameras must be EnvCamera with names of their own, got {names}{where}')

    def camera(self, name: str) -> 'EnvCamera':
        """The camera of that name, or a ValueError that lists those there are."""
        for camera in self.cameras:
            if camera.name == name:
                return camera
        there = ', '.join(repr(c.name) for c in self.cameras) or 'none'
        raise ValueError(f'the env announces no camera {name!r} (its cameras: {there})')

    def __eq__(self, other) -> bool:
        # Field by field (the bounds are arrays); where the spec came from is not part of it.
        if not isinstance(other, EnvSpec):
            return NotImplemented
        return self.cameras == other.cameras and all(
            np.array_equal(getattr(self, f.name), getattr(other, f.name))
            for f in fields(self)
            if f.compare and f.name != 'cameras'
        )

    __hash__ = None  # type: ignore[assignment]  # field-wise equality of arrays: not hashable

    @property
    def action_size(self) -> int:
        return int(self.action_low.size)

    def disagreements(self, other: 'EnvSpec') -> list[str]:
        """What ``other`` (e.g. the env's announcement) says differently about the spaces:
        observation size, action size and bounds. Empty when a learner built for one can
        act in the other."""
        found = []
        if other.observation_size != self.observation_size:
            found.append(f'observation size {other.observation_size}, not {self.observation_size}')
        if other.action_size != self.action_size:
            found.append(f'action size {other.action_size}, not {self.action_size}')
        elif not (
            np.allclose(other.action_low, self.action_low, rtol=1e-6, atol=1e-6)
            and np.allclose(other.action_high, self.action_high, rtol=1e-6, atol=1e-6)
        ):
            found.append(
                f'action bounds [{other.action_low.tolist()}, {other.action_high.tolist()}], '
                f'not [{self.action_low.tolist()}, {self.action_high.tolist()}]'
            )
        return found

    def success_criterion(self) -> 'SuccessCriterion':
        return success_criterion(self.success_rule, self.success_threshold)


class SuccessCriterion:
    """Per-episode success, fed every step. Subclasses define it per rule ('none': never)."""

    def reset(self) -> None:
        pass

    def update(self, obs: np.ndarray, reward: float) -> None:
        pass

    def success(self, episode_return: float) -> bool:
        return False


class ReturnAtLeast(SuccessCriterion):
    """Success when the episode's return reaches a threshold (LunarLander: 200, the env's solved line)."""

    def __init__(self, threshold: float):
        self.threshold = threshold

    def success(self, episode_return: float) -> bool:
        return episode_return >= self.threshold


class PendulumUpright(SuccessCriterion):
    """Success when the pendulum ends the episode balanced: its last ``hold_steps``
    observations all have cos(theta) >= cos(max_angle) (theta = 0 is upright)."""

    def __init__(self, max_angle_deg: float = 18.0, hold_steps: int = 10):
        self.min_cos = math.cos(math.radians(max_angle_deg))
        self.hold_steps = hold_steps
        self.reset()

    def reset(self) -> None:
        self._upright_run = 0

    def update(self, obs: np.ndarray, reward: float) -> None:
        self._upright_run = self._upright_run + 1 if obs[0] >= self.min_cos else 0

    def success(self, episode_return: float) -> bool:
        return self._upright_run >= self.hold_steps


def success_criterion(rule: str, threshold: float = 0.0) -> SuccessCriterion:
    """The criterion a rule names. 'reported' judges nothing itself: the env's observation
    messages carry the verdict, which the learner takes over any criterion (EQSACLearner.step)."""
    if rule == 'pendulum_upright':
        return PendulumUpright()
    if rule == 'return_at_least':
        return ReturnAtLeast(threshold)
    if rule in ('none', 'reported'):
        return SuccessCriterion()
    raise ValueError(f'success rule {rule!r} is not one of {SUCCESS_RULES}')


def spec_from_parameters(
    observation_size: int, action_low, action_high, name: str = '', source: str = 'parameters'
) -> Optional[EnvSpec]:
    """The spaces given as node parameters: all three or none (None). ValueError otherwise."""
    given = {
        'observation_size': observation_size > 0,
        'action_low': action_low is not None and len(action_low) > 0,
        'action_high': action_high is not None and len(action_high) > 0,
    }
    if not any(given.values()):
        return None
    if not all(given.values()):
        missing = [k for k, v in given.items() if not v]
        raise ValueError(
            f'observation_size, action_low and action_high go together: {", ".join(missing)} '
            f'{"is" if len(missing) == 1 else "are"} missing'
        )
    return EnvSpec(name, int(observation_size), action_low, action_high, source=source)


class ActionScaler:
    """Affine map between the policy's box [-1, 1]^m and the env's [low, high]."""

    def __init__(self, low, high):
        self.low = np.asarray(low, dtype=np.float32).reshape(-1)
        self.high = np.asarray(high, dtype=np.float32).reshape(-1)
        if self.low.shape != self.high.shape:
            raise ValueError('action low and high differ in size')
        if not (np.isfinite(self.low).all() and np.isfinite(self.high).all()):
            raise ValueError('EQ-HRL needs finite action bounds')
        if (self.high <= self.low).any():
            raise ValueError('action high must exceed low in every dimension')
        self.scale = (self.high - self.low) / 2.0
        self.center = (self.high + self.low) / 2.0

    @property
    def dim(self) -> int:
        return self.low.shape[0]

    def to_env(self, normalized: np.ndarray) -> np.ndarray:
        return (self.center + self.scale * np.asarray(normalized, dtype=np.float32)).astype(np.float32)

    def to_normalized(self, action: np.ndarray) -> np.ndarray:
        return ((np.asarray(action, dtype=np.float32) - self.center) / self.scale).astype(np.float32)
