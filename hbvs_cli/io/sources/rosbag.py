"""Images, intrinsics and the operator's commands from a ROS 2 bag (``hbvs teach --bag``);
the storage is read by :mod:`.bag_storage`."""

from __future__ import annotations

import os
from collections import deque
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ...core.camera import CameraIntrinsics
from ...errors import CalibrationError, InputError, RecordingError, UsageError
from ..calibration import calibration_from_foxglove, intrinsics_from_values
from ..images import read_compressed_image
from ..topics import (
    CAMERA_CALIBRATION_SCHEMA, COMPRESSED_IMAGE_SCHEMA, ROS_CAMERA_INFO_SCHEMA, ROS_COMPRESSED_IMAGE_SCHEMA,
    ROS_IMAGE_SCHEMA, ROS_ODOMETRY_SCHEMA, ROS_TWIST_SCHEMA, ROS_TWIST_STAMPED_SCHEMA,
)
from ..mcap import ChannelSummary
from .bag_storage import BagMessage, McapFileBag, RosbagsBag, open_bag
from .frame_source import _NS, FrameSource, SourceFrame, _same_size
from .ros_images import compressed_to_image8, raw_to_image8

_IMAGE_TYPES = (ROS_COMPRESSED_IMAGE_SCHEMA, ROS_IMAGE_SCHEMA)
#: Message types that carry the operator's command, in order of preference for --cmd-topic auto.
_COMMAND_TYPES = (ROS_TWIST_SCHEMA, ROS_TWIST_STAMPED_SCHEMA)
#: Largest CameraInfo message decoded (a real one is under 1 KB; CDR arrays decode slowly).
_MAX_CAMERA_INFO_BYTES = 1 << 16


# Foxglove's image and calibration schemas (hbvs's own files) are read in protobuf only.
def _is_image_topic(topic: ChannelSummary) -> bool:
    if topic.schema_name == COMPRESSED_IMAGE_SCHEMA:
        return topic.message_encoding == "protobuf"
    return topic.schema_name in _IMAGE_TYPES and topic.message_encoding == "cdr"


def _stamp_ns(message: Any) -> int:
    """``header.stamp`` in ns, 0 when the message has no header (or the driver left it zero)."""
    header = getattr(message, "header", None)
    return int(header.stamp.sec) * _NS + int(header.stamp.nanosec) if header is not None else 0


def velocity_of(message: Any, message_type: str) -> tuple[float, float]:
    """(v, w) of a Twist, TwistStamped or Odometry message: ``linear.x`` (m/s) and ``angular.z`` (rad/s)."""
    if message_type == ROS_TWIST_STAMPED_SCHEMA:
        twist = message.twist
    elif message_type == ROS_ODOMETRY_SCHEMA:
        twist = message.twist.twist
    else:
        twist = message
    return float(twist.linear.x), float(twist.angular.z)


def camera_from_info(info: Any, source: str) -> tuple[CameraIntrinsics | None, str | None]:
    """The intrinsics of a ``sensor_msgs/msg/CameraInfo``, else (None, why they cannot be used)."""
    k = [float(v) for v in info.k]
    if not any(k):
        return None, f"{source}: K is all zeros (the driver publishes an uncalibrated CameraInfo)"
    if int(getattr(info, "binning_x", 0)) > 1 or int(getattr(info, "binning_y", 0)) > 1:
        return None, f"{source}: binning is not supported; give a calibration for the binned images"
    roi = getattr(info, "roi", None)
    if roi is not None and int(getattr(roi, "width", 0)) > 0:
        return None, (f"{source}: a region of interest is not supported; give a calibration for the cropped images")
    try:
        camera = intrinsics_from_values(k, info.width, info.height, info.distortion_model, list(info.d), source)
    except CalibrationError as exc:
        return None, str(exc)
    return camera, None


class BagSource(FrameSource):
    """Images from a ROS 2 bag with its stamps, frame_id, intrinsics (``camera``, else why not in
    ``camera_problem``) and taught commands (the last at or before each frame's stamp); ``topic`` and
    ``cmd_topic`` None pick the only one with messages."""

    kind = "ros2_bag"

    def __init__(self, path: str | os.PathLike[str], topic: str | None = None, cmd_topic: str | None = None) -> None:
        self.path = str(path)
        self._bag: RosbagsBag | McapFileBag = open_bag(Path(path), self.path)
        topics = self._bag.topics
        self.topic, self._topic = self._choose(topics, topic)
        self.cmd_topic, self.cmd_type = self._choose_commands(topics, cmd_topic)
        self.camera_problem: str | None = None
        self.camera_info_topic = self._camera_info_topic(topics)
        if self.camera_info_topic is not None:
            self.camera, self.camera_problem = self._read_camera_info(self.camera_info_topic)
        self.time_base_ns, self.frame_id, self.stamps, self._stamp_minus_log, first = self._first_frame()
        self.width, self.height = (int(first.shape[1]), int(first.shape[0])) if first is not None else (None, None)

    def _choose(self, topics: dict[str, ChannelSummary], topic: str | None) -> tuple[str, ChannelSummary]:
        images = sorted((t for t in topics.values() if _is_image_topic(t)), key=lambda t: t.topic)
        if topic is not None:
            chosen = topics.get(topic)
            if chosen is None:
                listed = ", ".join(t.topic for t in images) or "none"
                raise InputError(f"{self.path}: no topic {topic!r} in the bag (image topics: {listed})")
            if chosen.schema_name not in (*_IMAGE_TYPES, COMPRESSED_IMAGE_SCHEMA):
                raise InputError(
                    f"{self.path}: topic {topic} carries {chosen.schema_name or 'an unknown type'}, "
                    f"not {ROS_IMAGE_SCHEMA}, {ROS_COMPRESSED_IMAGE_SCHEMA} or {COMPRESSED_IMAGE_SCHEMA}"
                )
            if not _is_image_topic(chosen):
                expected = "protobuf" if chosen.schema_name == COMPRESSED_IMAGE_SCHEMA else "cdr"
                raise InputError(f"{self.path}: topic {topic} is encoded as {chosen.message_encoding!r}, expected {expected}")
            return topic, chosen
        # Recorders create channels for subscribed topics that never published: skip them.
        candidates = [t for t in images if t.message_count is None or t.message_count > 0] or images
        if not candidates:
            raise InputError(f"no image topic in {self.path}")
        if len(candidates) > 1:
            listed = ", ".join(f"{t.topic} ({t.schema_name.rsplit('/', 1)[-1]})" for t in candidates)
            raise UsageError(f"{self.path}: several image topics: {listed}; choose one with --topic")
        return candidates[0].topic, candidates[0]

    def _choose_commands(self, topics: dict[str, ChannelSummary], cmd_topic: str | None) -> tuple[str | None, str | None]:
        accepted = (*_COMMAND_TYPES, ROS_ODOMETRY_SCHEMA)
        if cmd_topic is not None:
            chosen = topics.get(cmd_topic)
            if chosen is None:
                listed = ", ".join(sorted(t.topic for t in topics.values() if t.schema_name in accepted)) or "none"
                raise InputError(f"{self.path}: no topic {cmd_topic!r} in the bag (command topics: {listed})")
            if chosen.schema_name not in accepted or chosen.message_encoding != "cdr":
                raise InputError(
                    f"{self.path}: topic {cmd_topic} carries {chosen.schema_name or 'an unknown type'}, "
                    f"not {', '.join(accepted)}"
                )
            return cmd_topic, chosen.schema_name
        for types in (_COMMAND_TYPES, (ROS_ODOMETRY_SCHEMA,)):
            found = sorted(
                (t for t in topics.values() if t.schema_name in types and t.message_encoding == "cdr" and t.message_count != 0),
                key=lambda t: t.topic,
            )
            if len(found) == 1:
                return found[0].topic, found[0].schema_name
            if len(found) > 1:
                listed = ", ".join(t.topic for t in found)
                raise UsageError(f"{self.path}: several command topics: {listed}; choose one with --cmd-topic")
        return None, None

    def _camera_info_topic(self, topics: dict[str, ChannelSummary]) -> str | None:
        # A CameraInfo, or hbvs's own foxglove.CameraCalibration (protobuf only).
        infos = sorted(t.topic for t in topics.values() if t.message_count != 0 and (t.schema_name == ROS_CAMERA_INFO_SCHEMA or (
            t.schema_name == CAMERA_CALIBRATION_SCHEMA and t.message_encoding == "protobuf")))
        if len(infos) <= 1:
            return infos[0] if infos else None

        # Several cameras: the CameraInfo whose namespace is the longest prefix of the image topic.
        def shared(info: str) -> int:
            namespace = info.rsplit("/", 1)[0] + "/"
            return len(namespace) if self.topic.startswith(namespace) else -1

        best = max(infos, key=shared)
        return best if shared(best) > 0 else None

    def _first_message(self, topic: str) -> BagMessage | None:
        """The first message of ``topic``, reading only up to it."""
        messages = self._bag.messages({topic})
        try:
            return next(messages, None)
        finally:
            messages.close()

    def _read_camera_info(self, topic: str) -> tuple[CameraIntrinsics | None, str | None]:
        source = f"{self.path} {topic}"
        first = self._first_message(topic)
        if first is None:
            return None, f"{source}: the topic has no messages"
        if first.size > _MAX_CAMERA_INFO_BYTES:
            return None, f"{source}: a CameraInfo message of {first.size} bytes is not one hbvs can use"
        if first.mcap is not None and first.mcap.schema_name == CAMERA_CALIBRATION_SCHEMA:  # hbvs's own, protobuf
            try:
                calibration = first.mcap.foxglove(source)
                if not any(calibration.K):
                    return None, f"{source}: K is all zeros (an uncalibrated camera)"
                return calibration_from_foxglove(calibration, source), None
            except (RecordingError, CalibrationError) as exc:
                return None, str(exc)
        try:
            info = first.decode(source)
            return camera_from_info(info, source)
        except (AttributeError, TypeError, ValueError, OverflowError) as exc:
            return None, f"{source}: malformed CameraInfo ({exc})"

    def _first_frame(self) -> tuple[int, str | None, str, int, np.ndarray | None]:
        """The first frame's stamp (ns), frame_id, which clock stamps the frames, its stamp less its log
        time (ns), and its image (None for a topic without messages, which iteration reports)."""
        first = self._first_message(self.topic)
        if first is None:
            return 0, None, "header", 0, None
        image, _, _, stamp_ns, frame_id = self._frame(first, f"{self.path} {self.topic} message 0")
        if stamp_ns == 0:
            return first.log_time, frame_id, "log time", 0, image
        return stamp_ns, frame_id, "header", stamp_ns - first.log_time, image

    def _frame(self, message: BagMessage, what: str) -> tuple[np.ndarray, bytes | None, str | None, int, str | None]:
        """Image, its bytes and format, its stamp (ns, 0 if none) and frame_id."""
        if message.mcap is not None and self._topic.schema_name == COMPRESSED_IMAGE_SCHEMA:  # a foxglove.CompressedImage
            stored = read_compressed_image(message.mcap.data, what)
            return (*compressed_to_image8(stored, what), stored.stamp_ns, None)
        decoded = message.decode(what)
        try:
            if self._topic.schema_name == ROS_COMPRESSED_IMAGE_SCHEMA:
                image, encoded, fmt = compressed_to_image8(decoded, what)
            else:
                image, encoded, fmt = raw_to_image8(decoded, what), None, None
            header = getattr(decoded, "header", None)
            frame_id = str(header.frame_id) if header is not None and header.frame_id else None
            return image, encoded, fmt, _stamp_ns(decoded), frame_id
        except (AttributeError, TypeError, ValueError, OverflowError) as exc:
            # A message definition that does not match the type's name: the fields are not there.
            raise InputError(f"{what}: malformed {self._topic.schema_name} message ({exc})") from None

    def __iter__(self) -> Iterator[SourceFrame]:
        size: tuple[int, int] | None = None
        index = 0
        # Commands on the images' clock, held: each frame takes the last one at or before its stamp.
        pending: deque[tuple[int, int, tuple[float, float]]] = deque()  # (stamp or 0, log time, (v, w))
        command: tuple[float, float] | None = (0.0, 0.0) if self.cmd_topic is not None else None
        wanted = {self.topic} | ({self.cmd_topic} if self.cmd_topic is not None else set())
        try:
            for message in self._bag.messages(wanted):
                if message.topic != self.topic:
                    what = f"{self.path} {message.topic}"
                    decoded = message.decode(what)
                    try:
                        velocity = velocity_of(decoded, self.cmd_type or "")
                    except (AttributeError, TypeError, ValueError) as exc:
                        raise InputError(f"{what}: malformed {self.cmd_type} message ({exc})") from None
                    if not all(np.isfinite(velocity)):
                        raise InputError(f"{what}: a command that is not a finite number ({velocity})")
                    pending.append((_stamp_ns(decoded), message.log_time, velocity))
                    continue
                what = f"{self.path} {self.topic} message {index}"
                image, encoded, fmt, stamp_ns, _ = self._frame(message, what)
                size = _same_size(size, image, what)
                if self.stamps == "header" and stamp_ns != 0:
                    ns = stamp_ns
                else:
                    # Same clock as the first frame (read by _first_frame): shift the log time onto the stamps.
                    ns = message.log_time + self._stamp_minus_log
                # A Twist has no stamp: its log time, shifted onto the images' clock.
                while pending and (pending[0][0] or pending[0][1] + self._stamp_minus_log) <= ns:
                    command = pending.popleft()[2]
                yield SourceFrame(
                    t=(ns - self.time_base_ns) / _NS, image=image, encoded=encoded, format=fmt, stamp_ns=ns, command=command,
                )
                index += 1
        finally:
            self._bag.close()  # reopened by a later iteration
        if index == 0:
            raise InputError(f"{self.path}: topic {self.topic} has no messages")

    def close(self) -> None:
        """Close the bag (iteration closes it at its end too)."""
        self._bag.close()

    def describe(self) -> dict[str, Any]:
        """What the source is, for the recording's metadata."""
        return {
            "kind": self.kind, "path": self.path, "files": [str(f) for f in self._bag.files], "topic": self.topic,
            "message_type": self._topic.schema_name, "frame_count": self._topic.message_count, "fps": None,
            "camera_info_topic": self.camera_info_topic, "camera_info_problem": self.camera_problem,
            "storage": self._bag.storage, "time_base_ns": self.time_base_ns, "timestamps": self.stamps,
            "frame_id": self.frame_id, "cmd_topic": self.cmd_topic, "cmd_type": self.cmd_type,
        }
