"""The live robot's ROS 2 endpoints: the newest camera frame in (older ones counted as
dropped, never queued), velocity commands out. Messages, names and QoS: :mod:`.ros2_dds`."""

from __future__ import annotations

import time
from contextlib import suppress
from typing import Any

import numpy as np

from ..core.camera import CameraIntrinsics
from ..errors import InputError
from . import ros2_dds as dds
from .ros2_names import full_topic_name
from .sources.frame_source import LiveFrame
from .sources.ros_images import compressed_to_image8, raw_to_image8
from .sources.rosbag import camera_from_info

#: Seconds to wait for a camera topic's publisher and its CameraInfo (a node may still be starting).
DISCOVERY_TIMEOUT_S = 10.0


class LatestImage:
    """The newest frame of an image topic, with the sensor-data QoS."""

    def __init__(self, node: dds.Ros2Node, topic: str, discovery_timeout_s: float = DISCOVERY_TIMEOUT_S) -> None:
        full_topic_name(topic, "--ros2-image")
        self.topic = topic
        # image_transport's naming (Cyclone's Python binding cannot read the type from discovery reliably).
        self.message_type = dds.CompressedImage if topic.rstrip("/").endswith("/compressed") else dds.Image
        self.reader = node.subscriber(topic, self.message_type, dds.sensor_qos())
        self._waitset = _waitset(node, self.reader)
        # Wait until a publisher of this type matches (a publisher of another type never does).
        deadline = time.monotonic() + discovery_timeout_s
        while self.reader.get_subscription_matched_status().current_count == 0:
            if time.monotonic() > deadline:
                ros_type = next(name for name, kind in dds.MESSAGE_TYPES.items() if kind is self.message_type)
                raise InputError(
                    f"{topic}: no {ros_type} publisher within {discovery_timeout_s:g} s (ROS_DOMAIN_ID "
                    f"{dds.domain_id()}): the camera is not running, is on another network or domain, or publishes another "
                    "type (CompressedImage topics end in /compressed)"
                )
            time.sleep(0.02)

    def latest(self, timeout_s: float) -> LiveFrame | None:
        """The newest frame, waiting up to ``timeout_s`` for one; None when none came."""
        samples = _taken(self.reader, 64)
        if not samples:
            self._waitset.wait(int(max(timeout_s, 0.0) * 1e9))
            samples = _taken(self.reader, 64)
        if not samples:
            return None
        message = samples[-1]
        arrival = _arrival(message)
        image = decode_image_message(message, self.topic)
        stamp = dds.seconds_of(message.header.stamp) or time.time()  # a driver that leaves it zero
        return LiveFrame(image=image, stamp=stamp, arrival=arrival, skipped=len(samples) - 1)


def _taken(reader: Any, count: int) -> list[Any]:
    """Samples taken from ``reader``, less the "invalid" ones (no data) a publisher going away leaves."""
    return [sample for sample in reader.take(N=count) if hasattr(sample, "header")]


def _waitset(node: dds.Ros2Node, reader: Any) -> Any:
    """A waitset that wakes when ``reader`` has any sample."""
    from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet

    waitset = WaitSet(node.participant)
    waitset.attach(ReadCondition(reader, SampleState.Any | ViewState.Any | InstanceState.Any))
    return waitset


#: Largest plausible transport delay (s): a publication time beyond it is another host's clock.
_SAME_CLOCK_S = 1.0


def _arrival(message: Any) -> float:
    """When the frame arrived (``time.monotonic()``): its DDS publication time when on this
    host's clock (a wait in the reader counts), else now."""
    now, wall = time.monotonic(), time.time()
    info = getattr(message, "sample_info", None)
    source_ns = getattr(info, "source_timestamp", None)
    if isinstance(source_ns, int) and source_ns > 0:
        waited = wall - source_ns * 1e-9
        if 0.0 <= waited < _SAME_CLOCK_S:
            return now - waited
    return now


def decode_image_message(message: Any, topic: str) -> np.ndarray:
    """A ``sensor_msgs`` Image or CompressedImage as 8-bit gray or BGR; :class:`InputError` if unreadable."""
    if isinstance(message, dds.CompressedImage):
        return compressed_to_image8(message, topic)[0]
    if message.encoding == "mono8" and message.step == message.width:
        # The common case, without a conversion: the data are the image.
        data = np.frombuffer(message.data, dtype=np.uint8)
        if data.size != message.width * message.height:
            raise InputError(f"{topic}: {data.size} bytes of data, expected {message.width * message.height} ({message.height} rows of {message.width})")
        return data.reshape(message.height, message.width)
    return raw_to_image8(message, topic)


def wait_camera_info(node: dds.Ros2Node, topic: str, timeout_s: float = DISCOVERY_TIMEOUT_S) -> CameraIntrinsics:
    """The camera of the first ``sensor_msgs/msg/CameraInfo`` on ``topic`` within ``timeout_s``."""
    # Best effort: matches the camera's CameraInfo whether it is published reliably or not.
    reader = node.subscriber(topic, dds.CameraInfo, dds.sensor_qos())
    waitset = _waitset(node, reader)
    deadline = time.monotonic() + timeout_s
    while True:
        infos = _taken(reader, 8)
        if infos:
            camera, problem = camera_from_info(infos[-1], topic)
            if camera is None:
                raise InputError(problem or f"{topic}: unusable CameraInfo")
            return camera
        left = deadline - time.monotonic()
        if left <= 0:
            raise InputError(f"{topic}: no CameraInfo within {timeout_s:g} s; give the calibration with --calibration")
        waitset.wait(int(left * 1e9))


class CommandPublisher:
    """Velocity commands on a ROS 2 topic (reliable): ``Twist``, or ``TwistStamped`` in ``base_link``;
    it also watches the topic for another commander (a robot obeys whoever spoke last)."""

    def __init__(self, node: dds.Ros2Node, topic: str, stamped: bool = False) -> None:
        from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication
        from cyclonedds.qos import Policy, Qos

        full_topic_name(topic, "--ros2-cmd")
        self.topic = topic
        self.stamped = stamped
        message_type = dds.TwistStamped if stamped else dds.Twist
        self.writer = node.publisher(topic, message_type, dds.command_qos())
        # Another writer's commands only: ignoring this participant, the echo never matches hbvs's own
        # writer (whose matched count then counts the robot's subscribers alone).
        self._echo = node.subscriber(topic, message_type, dds.command_qos() + Qos(Policy.IgnoreLocal.Participant))
        self._publications = BuiltinDataReader(node.participant, BuiltinTopicDcpsPublication)
        self._dds_topic = dds.dds_topic_name(topic)

    def other_publishers(self) -> int:
        """How many other writers on the topic are alive now (ROS 2 nodes that could command the robot)."""
        from cyclonedds.core import InstanceState

        return sum(
            1 for endpoint in self._publications.read(N=1024)
            if getattr(endpoint, "topic_name", None) == self._dds_topic and endpoint.key != self.writer.guid
            and endpoint.sample_info.instance_state == InstanceState.Alive
        )

    def foreign_commands(self) -> int:
        """Commands another writer put on the topic since the last call."""
        # (Not a writer going away: those samples carry no data.)
        return sum(1 for sample in self._echo.take(N=256) if hasattr(sample, "linear") or hasattr(sample, "twist"))

    def wait_delivered(self, timeout_s: float) -> None:
        """Wait, at most ``timeout_s``, until every reliable reader acknowledged the commands sent (the last
        zero above all): hbvs ends without Cyclone DDS's teardown, which would have resent a lost one."""
        with suppress(Exception):  # no reader left: nothing more to deliver
            self.writer.wait_for_acks(dds.duration(seconds=timeout_s))

    def publish(self, v: float, w: float, stamp: float | None = None) -> None:
        """Send ``(v, w)`` (m/s, rad/s), stamped ``stamp`` (s; now when None) if stamped."""
        twist = dds.Twist(linear=dds.Vector3(x=float(v)), angular=dds.Vector3(z=float(w)))
        if self.stamped:
            header = dds.Header(stamp=dds.stamp_of(time.time() if stamp is None else stamp), frame_id="base_link")
            self.writer.write(dds.TwistStamped(header=header, twist=twist))
        else:
            self.writer.write(twist)
