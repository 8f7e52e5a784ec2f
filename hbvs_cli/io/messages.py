"""Builders and readers of the small Foxglove and hbvs messages (poses, commands, logs,
annotations). Images are in :mod:`.images`, calibrations in :mod:`.calibration`."""

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


def pose_message(timestamp: dict[str, int], pose: Sequence[float], height: float = 0.0, frame_id: str = WORLD_FRAME) -> dict[str, Any]:
    """A ``foxglove.PoseInFrame`` of a planar pose (x, y, phi) at ``height`` (m)."""
    x, y, phi = (float(v) for v in pose)
    qx, qy, qz, qw = (float(v) for v in yaw_to_quaternion(phi))
    return {
        "timestamp": timestamp,
        "frame_id": frame_id,
        "pose": {
            "position": {"x": x, "y": y, "z": float(height)},
            "orientation": {"x": qx, "y": qy, "z": qz, "w": qw},
        },
    }


def planar_pose_from_message(message: dict[str, Any], source: str = "") -> tuple[float, float, float]:
    """(x, y, phi) of a ``foxglove.PoseInFrame`` (the yaw of its quaternion)."""
    try:
        position = message["pose"]["position"]
        q = message["pose"]["orientation"]
        x, y = float(position["x"]), float(position["y"])
        quaternion = [float(q[k]) for k in ("x", "y", "z", "w")]
    except (KeyError, TypeError, ValueError):
        raise RecordingError(f"{source}: malformed pose message") from None
    values = (x, y, float(quaternion_to_yaw(quaternion)))
    if not all(math.isfinite(v) for v in values):
        raise RecordingError(f"{source}: a pose message holds NaN or infinity")
    return values


def velocity_message(timestamp: dict[str, int], v: float, w: float, saturated: bool | None = None) -> dict[str, Any]:
    """An ``hbvs.VelocityCommand``."""
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


def log_message(timestamp: dict[str, int], level: int, text: str, name: str = "hbvs") -> dict[str, Any]:
    """A ``foxglove.Log`` line (shown in Foxglove's Log panel)."""
    return {"timestamp": timestamp, "level": int(level), "message": text, "name": name, "file": "", "line": 0}


def _color(r: float, g: float, b: float, a: float = 1.0) -> dict[str, float]:
    return {"r": r, "g": g, "b": b, "a": a}


DETECTED_COLOR = _color(0.1, 0.9, 0.2)
DESIRED_COLOR = _color(1.0, 0.3, 0.1)
_CLEAR = _color(0.0, 0.0, 0.0, 0.0)


def annotations_message(
    timestamp: dict[str, int],
    detected: np.ndarray | None,
    desired: np.ndarray | None = None,
    label: str | None = None,
) -> dict[str, Any]:
    """A ``foxglove.ImageAnnotations`` with circles on detected (green) and desired (orange) points.

    Pixels are given in OpenCV's convention (centre of the top-left pixel at 0, 0);
    Foxglove puts 0, 0 at the top-left *corner*, hence the half-pixel shift.
    """
    circles = []
    texts = []
    for points, color, diameter in ((detected, DETECTED_COLOR, 10.0), (desired, DESIRED_COLOR, 16.0)):
        if points is None:
            continue
        for index, (u, v) in enumerate(np.asarray(points, dtype=float)):
            if not (math.isfinite(u) and math.isfinite(v)):
                continue
            circles.append({
                "timestamp": timestamp,
                "position": {"x": u + 0.5, "y": v + 0.5},
                "diameter": diameter,
                "thickness": 2.0,
                "fill_color": _CLEAR,
                "outline_color": color,
                "metadata": [{"key": "point", "value": str(index)}],
            })
            if color is DETECTED_COLOR:
                texts.append({
                    "timestamp": timestamp,
                    "position": {"x": u + 8.5, "y": v - 5.5},
                    "text": str(index),
                    "font_size": 12.0,
                    "text_color": color,
                    "background_color": _CLEAR,
                    "metadata": [],
                })
    if label:
        texts.append({
            "timestamp": timestamp, "position": {"x": 8.0, "y": 20.0}, "text": label, "font_size": 14.0,
            "text_color": _color(1.0, 1.0, 1.0), "background_color": _color(0.0, 0.0, 0.0, 0.5), "metadata": [],
        })
    return {"circles": circles, "points": [], "texts": texts}
