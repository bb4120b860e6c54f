"""A node's record (``record: true``): one MCAP file beside episodes.csv (eqhrl_ros/mcap_record.py).

What the node sends is written as it publishes it; what it receives is written as it arrives,
serialized as on the wire; the ``advise`` exchange comes from rclpy's service introspection
(both sides publish on ``<service>/_service_event``), which a real ``ros2 bag record`` also
captures; frames of ``gym_env/image`` are written JPEG-compressed.
"""

from __future__ import annotations

from typing import Optional

from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from rclpy.service_introspection import ServiceIntrospectionState
from sensor_msgs.msg import CompressedImage, Image

from ..core.data import camera_frames
from .frame_msgs import frame_of
from .spinning import steady_clock

# Service events: reliable, so that the record (and ros2 bag) holds every call.
SERVICE_EVENT_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
EVENT_SUFFIX = '/_service_event'
JPEG_QUALITY = 80


def type_name(cls) -> str:
    """'pkg/msg/Name' (or 'pkg/srv/Name_Event') of a generated message class."""
    package, kind = cls.__module__.split('.')[:2]
    return f'{package}/{kind}/{cls.__name__}'


def introspect(endpoint, node) -> None:
    """Publish every call of a service client or server, with its contents, on
    ``<service>/_service_event`` (ros2 service echo, ros2 bag record and the record read it)."""
    endpoint.configure_introspection(node.get_clock(), SERVICE_EVENT_QOS, ServiceIntrospectionState.CONTENTS)


class NodeRecord:
    """The MCAP file of one node's run. ``write`` a message the node handles; ``tap`` a topic the
    node does not otherwise hear (its messages are written as they arrive, undecoded)."""

    def __init__(self, node, path, metadata: Optional[dict] = None):
        from ..files.mcap_record import FLUSH_PERIOD_S, McapRecord  # here: nodes that never record never load mcap

        self.node = node
        self.file = McapRecord(path, metadata=metadata)
        self.path = self.file.path
        # A quiet run still closes its chunk every second (a kill -9 keeps what came before).
        self._timer = node.create_timer(FLUSH_PERIOD_S, self.file.flush, clock=steady_clock())
        self.frames = 0
        self.failed = 0

    def write(self, topic: str, msg) -> None:
        self._guarded(self.file.write, topic, type_name(type(msg)), serialize_message(msg))

    def write_raw(self, topic: str, cls, data: bytes) -> None:
        self._guarded(self.file.write, topic, type_name(cls), data)

    def tap(self, topic: str, cls, qos) -> str:
        """Record ``topic`` (relative names resolve in the node's namespace); returns its full name."""
        name = self.node.resolve_topic_name(topic)
        self.node.create_subscription(cls, name, lambda data: self.write_raw(name, cls, data), qos, raw=True)
        return name

    def tap_service(self, service_name: str, srv_type) -> str:
        """Record the calls of a service (introspect() on a client or server of it publishes them)."""
        return self.tap(service_name + EVENT_SUFFIX, srv_type.Event, SERVICE_EVENT_QOS)

    def tap_images(self, topic: str) -> str:
        """Frames (sensor_msgs/Image) recorded as sensor_msgs/CompressedImage, JPEG, on ``<topic>/compressed``."""
        name = self.node.resolve_topic_name(topic)
        self.node.create_subscription(Image, name, lambda msg: self._on_frame(name + '/compressed', msg), 2)
        return name

    def _on_frame(self, topic: str, msg: Image) -> None:
        try:
            pixels = frame_of(msg)
        except camera_frames.FrameError:
            self.failed += 1
            return
        data = camera_frames.jpeg_bytes(pixels, JPEG_QUALITY)
        self.write(topic, CompressedImage(header=msg.header, format='jpeg', data=data))
        self.frames += 1

    def _guarded(self, write, *args) -> None:
        """A record that cannot be written (a full disk) is one log line a while; the run goes on."""
        try:
            write(*args)
        except OSError as error:
            self.failed += 1
            self.node.get_logger().error(
                f'{self.path}: {error.strerror or error}; {self.failed} message(s) not recorded (the run goes on)',
                throttle_duration_sec=10.0,
            )

    def close(self) -> None:
        self.node.destroy_timer(self._timer)
        try:
            self.file.close()
        except OSError as error:
            self.node.get_logger().error(
                f'{self.path}: not finished ({error.strerror or error}); it reads up to its last chunk'
            )
            return
        self.node.get_logger().info(f'record: {self.file.messages} messages in {self.path}')
