"""Builders and readers of the small messages: ``foxglove.*`` ones as the protobuf classes
of ``foxglove-schemas-protobuf``, ``hbvs.VelocityCommand`` as JSON. Images are in
:mod:`.images`, calibrations in :mod:`.calibration`, the 3D scene in :mod:`.foxglove_scene`."""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from ..core.frames import quaternion_to_yaw, yaw_to_quaternion
from ..errors import RecordingError

WORLD_FRAME = "world"
#: The camera's frame in the optical convention Foxglove's CameraCalibration and ROS's
#: CameraInfo expect (z forward, x right, y down); see :mod:`.foxglove_scene`.
CAMERA_FRAME = "camera_optical"

#: foxglove.Log levels.
LOG_INFO, LOG_WARNING, LOG_ERROR = 2, 3, 4


def stamp(ns: int) -> Any:
    """A ``google.protobuf.Timestamp`` from nanoseconds (negative ones clamp to 0)."""
    from google.protobuf.timestamp_pb2 import Timestamp

    seconds, nanos = divmod(max(int(ns), 0), 1_000_000_000)
    return Timestamp(seconds=seconds, nanos=nanos)


def stamp_ns(timestamp: Any) -> int:
    """Nanoseconds of a ``google.protobuf.Timestamp``."""
    return int(timestamp.seconds) * 1_000_000_000 + int(timestamp.nanos)


def vector3(values: Sequence[float]) -> Any:
    from foxglove_schemas_protobuf.Vector3_pb2 import Vector3

    x, y, z = (float(v) for v in values)
    return Vector3(x=x, y=y, z=z)


def quaternion(values: Sequence[float]) -> Any:
    """A ``foxglove.Quaternion`` from (x, y, z, w)."""
    from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion

    x, y, z, w = (float(v) for v in values)
    return Quaternion(x=x, y=y, z=z, w=w)


def pose_at(position: Sequence[float], rotation: Sequence[float] = (0.0, 0.0, 0.0, 1.0)) -> Any:
    """A ``foxglove.Pose``: ``position`` (m) and the unit quaternion ``rotation`` (x, y, z, w)."""
    from foxglove_schemas_protobuf.Pose_pb2 import Pose

    return Pose(position=vector3(position), orientation=quaternion(rotation))


def pose_message(ns: int, pose: Sequence[float], height: float = 0.0, frame_id: str = WORLD_FRAME) -> Any:
    """A ``foxglove.PoseInFrame`` of a planar pose (x, y, phi) (m, m, rad) at ``height`` (m)."""
    from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame

    x, y, phi = (float(v) for v in pose)
    return PoseInFrame(timestamp=stamp(ns), frame_id=frame_id, pose=pose_at((x, y, height), yaw_to_quaternion(phi)))


def planar_pose_from_message(message: Any, source: str = "") -> tuple[float, float, float]:
    """(x, y, phi) of a ``foxglove.PoseInFrame`` (phi: the yaw of its quaternion)."""
    position, q = message.pose.position, message.pose.orientation
    values = (float(position.x), float(position.y), float(quaternion_to_yaw([q.x, q.y, q.z, q.w])))
    if not all(math.isfinite(v) for v in values):
        raise RecordingError(f"{source}: a pose message holds NaN or infinity")
    return values


def velocity_message(timestamp: dict[str, int], v: float, w: float, saturated: bool | None = None) -> dict[str, Any]:
    """An ``hbvs.VelocityCommand`` (m/s, rad/s)."""
    message: dict[str, Any] = {"timestamp": timestamp, "v": float(v), "w": float(w)}
    if saturated is not None:
        message["saturated"] = bool(saturated)
    return message


def velocity_from_message(message: dict[str, Any], source: str = "") -> tuple[float, float]:
    try:
        v, w = float(message["v"]), float(message["w"])
    except (KeyError, TypeError, ValueError):
        raise RecordingError(f"{source}: malformed velocity command message") from None
    if not (math.isfinite(v) and math.isfinite(w)):
        raise RecordingError(f"{source}: a velocity command holds NaN or infinity")
    return v, w


def log_message(ns: int, level: int, text: str, name: str = "hbvs") -> Any:
    """A ``foxglove.Log`` line (shown in Foxglove's Log panel)."""
    from foxglove_schemas_protobuf.Log_pb2 import Log

    return Log(timestamp=stamp(ns), level=int(level), message=text, name=name)


def color(r: float, g: float, b: float, a: float = 1.0) -> Any:
    from foxglove_schemas_protobuf.Color_pb2 import Color

    return Color(r=r, g=g, b=b, a=a)


DETECTED_RGBA = (0.1, 0.9, 0.2, 1.0)
DESIRED_RGBA = (1.0, 0.3, 0.1, 1.0)


def annotations_message(ns: int, detected: np.ndarray | None, desired: np.ndarray | None = None, label: str | None = None) -> Any:
    """A ``foxglove.ImageAnnotations`` with circles on detected (green, numbered) and desired
    (orange) points, (N, 2) pixels, and an optional label.

    Pixels are in OpenCV's convention (centre of the top-left pixel at 0, 0); Foxglove puts
    0, 0 at the top-left *corner*, hence the half-pixel shift.
    """
    from foxglove_schemas_protobuf.CircleAnnotation_pb2 import CircleAnnotation
    from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
    from foxglove_schemas_protobuf.Point2_pb2 import Point2
    from foxglove_schemas_protobuf.TextAnnotation_pb2 import TextAnnotation

    time, clear = stamp(ns), color(0.0, 0.0, 0.0, 0.0)
    annotations = ImageAnnotations()
    for points, rgba, diameter in ((detected, DETECTED_RGBA, 10.0), (desired, DESIRED_RGBA, 16.0)):
        outline = color(*rgba)
        # Every point's annotations copied from one made whole: building each nested message
        # anew cost the fit more than a third of a millisecond a frame.
        circle = CircleAnnotation(timestamp=time, diameter=diameter, thickness=2.0, fill_color=clear, outline_color=outline)
        number = TextAnnotation(timestamp=time, font_size=12.0, text_color=outline, background_color=clear)
        for index, (u, v) in enumerate(np.asarray(points if points is not None else [], dtype=float).reshape(-1, 2).tolist()):
            if not (math.isfinite(u) and math.isfinite(v)):
                continue
            added = annotations.circles.add()
            added.CopyFrom(circle)
            added.position.x, added.position.y = u + 0.5, v + 0.5
            added.metadata.add(key="point", value=str(index))
            if rgba is DETECTED_RGBA:
                text = annotations.texts.add()
                text.CopyFrom(number)
                text.position.x, text.position.y = u + 8.5, v - 5.5
                text.text = str(index)
    if label:
        annotations.texts.append(TextAnnotation(
            timestamp=time, position=Point2(x=8.0, y=20.0), text=label, font_size=14.0,
            text_color=color(1.0, 1.0, 1.0), background_color=color(0.0, 0.0, 0.0, 0.5),
        ))
    return annotations
