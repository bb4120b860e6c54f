"""The learner's camera on the person's page: advice_console follows the camera the learner reads
(its ``camera`` and ``camera_transport`` parameters, the camera's topic and size from env_info)
and keeps its newest frame, live, at the size the learner reads it. Frames are taken as the
learner takes them: from one publisher alone, each checked against the announcement
(frame_msgs.announced_frame); a frame refused is counted and logged (throttled), and changes
nothing on the page."""

from __future__ import annotations

from typing import Callable, Optional

import numpy as np
from sensor_msgs.msg import CompressedImage, Image

from ..core.data.camera_frames import FrameError
from ..core.envs.spec import EnvCamera
from .camera_input import FRAME_QOS
from .frame_msgs import announced_frame
from .graph_trust import OnePublisher


class LearnerCamera:
    """The newest frame of the camera the learner reads, once ``follow`` names it."""

    def __init__(self, node, on_frame: Callable[[bool], None]):
        """``on_frame(refused)``: a frame was kept, or refused (from the subscription's callback)."""
        self.node, self._on_frame_seen = node, on_frame
        self.camera: Optional[EnvCamera] = None
        self.topic = ''
        self.latest: Optional[np.ndarray] = None  # (H, W, C) uint8, as the learner reads it
        self.number = 0  # frames kept so far
        self.refused = 0
        self._subscription = None
        self._guard: Optional[OnePublisher] = None
        self._publisher = ''

    def follow(self, camera: Optional[EnvCamera], transport: str = 'raw', publisher: str = '') -> None:
        """Watch ``camera`` (None: none) as the learner reads it: ``transport`` raw or compressed,
        frames from ``publisher`` alone when it is set (the learner's camera_publisher)."""
        topic = '' if camera is None else f'{camera.topic}/compressed' if transport == 'compressed' else camera.topic
        if (camera, topic, publisher) == (self.camera, self.topic, self._publisher):
            return
        if self._subscription is not None:
            self.node.destroy_subscription(self._subscription)
            self._subscription = self._guard = None
        self.camera, self.topic, self._publisher, self.latest = camera, topic, publisher, None
        if camera is not None:
            kind = CompressedImage if transport == 'compressed' else Image
            self._guard = OnePublisher(self.node, topic, publisher)
            self._subscription = self.node.create_subscription(kind, topic, self._on_frame, FRAME_QOS)

    def _on_frame(self, msg) -> None:
        camera, guard = self.camera, self._guard
        if camera is None or guard is None:
            return
        try:
            refusal = guard.refusal()
            if refusal:
                raise FrameError(refusal)
            frame = announced_frame(msg, camera)
        except FrameError as error:
            self.refused += 1
            self.node.get_logger().warning(
                f"the learner's camera on the page: a frame on {self.topic} refused: {error}",
                throttle_duration_sec=5.0,
            )
            self._on_frame_seen(True)
            return
        self.latest, self.number = frame, self.number + 1
        self._on_frame_seen(False)

    def shown(self) -> Optional[dict]:
        """What the page says of it; None while no camera is followed."""
        camera = self.camera
        if camera is None:
            return None
        return {
            'name': camera.name,
            'topic': self.topic,
            'height': camera.height,
            'width': camera.width,
            'encoding': camera.encoding,
            'frames': self.number,
            'refused': self.refused,
        }
