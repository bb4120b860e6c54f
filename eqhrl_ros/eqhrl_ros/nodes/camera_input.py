"""CameraInput: the frames of the camera a learner reads, paired with the env's observations.

The env announces its cameras in env_info (eqhrl_interfaces/msg/CameraPart); a learner whose
``camera`` parameter names one subscribes to its topic: sensor_msgs/Image, or with
``camera_transport: compressed`` sensor_msgs/CompressedImage (JPEG or PNG) on ``<topic>/compressed``,
as image_transport names it. The rule that pairs a frame with an observation message (which has
no header):

- An observation takes the newest frame that came after the one the step before took (a
  lock-step env publishes each step's frame just before its observation; a real-time camera
  at its own rate gives the newest it has).
- **Late:** when no such frame has come yet, the observation waits for it, at most
  ``camera_wait_s``. **Missing:** then the newest frame there is stands in (counted as
  ``stale_frames``); with no frame ever, the observation is dropped (``frameless_observations``;
  a lock-step env sends it again). An observation still waiting when the next comes is acted on
  at once, with the newest frame there is, and the next waits in its place: no step is lost (a
  lock-step env sends an episode's last observation and the next episode's first together).
- The learner reads the last ``camera_stack`` frames: an episode's first step, or a step that
  does not follow the one before (one was lost), starts the stack over with its frame repeated,
  as the replay memory rebuilds it.

Frames are taken while one node alone publishes the topic (``camera_publisher``, when set, names
it): with two, none is, since a stranger's frame cannot be told from the camera's. A frame is
then checked by meaning against the announcement before it is kept: its encoding, height
and width as announced, and its row length and size as its header says; a compressed one's
declared size before it is decoded (no more pixels than announced: a frame that would decode
to gigabytes costs nothing), then what it decodes to (core/data/camera_frames.py). A frame
refused is counted and said (throttled), and changes nothing. Only the newest frame is kept: a
flood costs a check per message and holds one frame.
"""

from __future__ import annotations

import dataclasses
import time
from collections import deque
from typing import Callable, Optional

import numpy as np
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CompressedImage, Image

from ..core.data.camera_frames import FrameError
from ..core.envs.spec import EnvCamera
from .frame_msgs import announced_frame
from .graph_trust import OnePublisher
from .health import OK, WARN, Check
from .messages import EnvStep
from .spinning import steady_clock

FRAME_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)


class CameraInput:
    """Frames from one announced camera, attached to observations as {'state', 'pixels'}."""

    def __init__(
        self,
        node: Node,
        camera: EnvCamera,
        stack: int,
        wait_s: float,
        lock,
        retry: Callable[[bytes], None],
        publisher: str = '',
        transport: str = 'raw',
    ):
        """``retry(data)``: the node acts on an observation that waited, once its frame came or
        the wait ended (under the node's ``lock``, as every callback here). ``publisher``: the
        only node whose frames are taken (empty: any one node, while it publishes alone).
        ``transport``: 'raw' (sensor_msgs/Image on the topic) or 'compressed' (CompressedImage on
        <topic>/compressed)."""
        self.node, self.camera, self.stack, self.wait_s = node, camera, int(stack), float(wait_s)
        self._lock, self._retry = lock, retry
        self.latest: Optional[np.ndarray] = None  # the newest frame, (H, W, C) uint8
        self.received = 0  # frames kept so far
        self._used = 0  # the count of frames when the last observation took one
        self._frames: deque = deque(maxlen=self.stack)
        self._last_key: Optional[tuple] = None
        self._waiting: Optional[tuple] = None  # (observation data, time.monotonic() it began waiting)
        compressed = transport == 'compressed'
        self.topic = f'{camera.topic}/compressed' if compressed else camera.topic
        self.guard = OnePublisher(node, self.topic, publisher)
        self.refused_frames = 0  # for what they hold
        self.untrusted_frames = 0  # for who sent them
        self.stale_frames = 0
        self.frameless_observations = 0
        node.create_subscription(CompressedImage if compressed else Image, self.topic, self._on_frame, FRAME_QOS)
        node.create_timer(max(0.01, self.wait_s / 4), self._check_wait, clock=steady_clock())

    def _trusted(self) -> bool:
        refusal = self.guard.refusal()
        if refusal:
            self.untrusted_frames += 1
            self.node.get_logger().error(f'frames refused: {refusal}', throttle_duration_sec=5.0)
        return not refusal

    def _refuse(self, error: FrameError) -> None:
        self.refused_frames += 1
        self.node.get_logger().error(
            f'frame on {self.topic} refused: {error} ({self.refused_frames} so far)', throttle_duration_sec=5.0
        )

    def _on_frame(self, msg) -> None:
        """A raw or compressed frame, checked against the announcement (frame_msgs.announced_frame)."""
        if not self._trusted():
            return
        try:
            frame = announced_frame(msg, self.camera)
        except FrameError as error:
            self._refuse(error)
            return
        self._keep(frame)

    def _keep(self, frame: np.ndarray) -> None:
        with self._lock:
            self.latest, self.received = frame, self.received + 1
            waiting = self._waiting
        if waiting is not None:
            self._retry(waiting[0])

    def _check_wait(self) -> None:
        with self._lock:
            waiting = self._waiting
        if waiting is not None and time.monotonic() - waiting[1] >= self.wait_s:
            self._retry(waiting[0])

    def health_check(self) -> Check:
        """The camera on /diagnostics: WARN while frames are refused for who sends them, or none came."""
        values = {
            'frames': self.received,
            'refused frames': self.refused_frames,
            'untrusted frames': self.untrusted_frames,
            'stale frames': self.stale_frames,
            'frameless observations': self.frameless_observations,
        }
        refusal = self.guard.refusal()
        if refusal:
            return Check('camera', WARN, f'frames refused: {refusal}', values)
        if self.received == 0:
            return Check('camera', WARN, f'no frame yet on {self.topic}', values)
        return Check('camera', OK, f'frames arrive on {self.topic}', values)

    def seen_again(self) -> None:
        """The env sent the observation acted on again (with its frame): that frame is used."""
        self._used = self.received

    def attach(self, env_step: EnvStep, data: bytes) -> Optional[EnvStep]:
        """``env_step`` with its frames (its obs {'state', 'pixels'}); None while it waits for
        its frame, or when it is dropped (no frame ever came)."""
        fresh = self.latest is not None and self.received > self._used
        if not fresh:
            waiting = self._waiting
            if waiting is not None and waiting[0] is not data:  # an older one still waits: it goes first,
                self._waiting = (waiting[0], float('-inf'))  # with the newest frame there is (so no step is lost)
                self._retry(waiting[0])
                waiting = None
            if waiting is None:
                self._waiting = (data, time.monotonic())  # late: it waits
                return None
            if time.monotonic() - waiting[1] < self.wait_s:
                return None
            self._waiting = None
            if self.latest is None:
                self.frameless_observations += 1
                self.node.get_logger().warn(
                    f'no frame on {self.topic} after {self.wait_s:g} s: observation dropped '
                    f'({self.frameless_observations} so far)',
                    throttle_duration_sec=5.0,
                )
                return None
            self.stale_frames += 1
            self.node.get_logger().warn(
                f'no new frame on {self.topic} within {self.wait_s:g} s: the newest stands in '
                f'({self.stale_frames} stale so far)',
                throttle_duration_sec=5.0,
            )
        self._waiting, self._used = None, self.received
        key = (env_step.episode, env_step.step)
        if env_step.step == 0 or self._last_key != (key[0], key[1] - 1):  # a stack starts over
            self._frames.extend([self.latest] * self.stack)
        else:
            self._frames.append(self.latest)
        self._last_key = key
        return dataclasses.replace(env_step, obs={'state': env_step.obs, 'pixels': np.stack(self._frames)})
