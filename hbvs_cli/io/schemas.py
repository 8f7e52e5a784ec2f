"""JSON schemas of every message hbvs writes, and the topics they go on.

Foxglove schemas (``foxglove.*``) follow the documented Foxglove message formats field for
field, so the files open in Foxglove with images, annotations, poses and plots. The
``hbvs.*`` schemas are ours. Messages use the ``json`` message encoding and the
``jsonschema`` schema encoding, but for images: hbvs writes ``foxglove.CompressedImage`` in
Foxglove's protobuf encoding (:mod:`.images`), and reads the JSON form below from older
files. Times are ``{"sec", "nsec"}`` and MCAP log times are in nanoseconds.

The topics of each file kind are listed in :mod:`.topics` (and in the README).
"""

from __future__ import annotations

from typing import Any

from .topics import (
    CAMERA_CALIBRATION_SCHEMA, COMPRESSED_IMAGE_SCHEMA, CONTROLLER_STATE_SCHEMA, DESIRED_SIGNAL_SCHEMA, FIT_MODEL_SCHEMA,
    IMAGE_ANNOTATIONS_SCHEMA, LOG_SCHEMA, POSE_IN_FRAME_SCHEMA, VELOCITY_COMMAND_SCHEMA,
)

_TIME = {
    "type": "object",
    "title": "time",
    "properties": {
        "sec": {"type": "integer", "minimum": 0},
        "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999},
    },
    "required": ["sec", "nsec"],
}
_NUMBER = {"type": "number"}
_NUMBER_OR_NULL = {"type": ["number", "null"]}
_POINT2 = {"title": "foxglove.Point2", "type": "object", "properties": {"x": _NUMBER, "y": _NUMBER}, "required": ["x", "y"]}
_COLOR = {
    "title": "foxglove.Color",
    "type": "object",
    "properties": {"r": _NUMBER, "g": _NUMBER, "b": _NUMBER, "a": _NUMBER},
    "required": ["r", "g", "b", "a"],
}
_KEY_VALUES = {
    "type": "array",
    "items": {
        "title": "foxglove.KeyValuePair",
        "type": "object",
        "properties": {"key": {"type": "string"}, "value": {"type": "string"}},
        "required": ["key", "value"],
    },
}
_VECTOR3 = {
    "title": "foxglove.Vector3",
    "type": "object",
    "properties": {"x": _NUMBER, "y": _NUMBER, "z": _NUMBER},
    "required": ["x", "y", "z"],
}
_QUATERNION = {
    "title": "foxglove.Quaternion",
    "type": "object",
    "properties": {"x": _NUMBER, "y": _NUMBER, "z": _NUMBER, "w": _NUMBER},
    "required": ["x", "y", "z", "w"],
}


def _number_array(length: int | None = None) -> dict[str, Any]:
    schema: dict[str, Any] = {"type": "array", "items": _NUMBER}
    if length is not None:
        schema.update(minItems=length, maxItems=length)
    return schema


FOXGLOVE_SCHEMAS: dict[str, dict[str, Any]] = {
    COMPRESSED_IMAGE_SCHEMA: {
        "title": COMPRESSED_IMAGE_SCHEMA,
        "description": "A compressed image",
        "type": "object",
        "properties": {
            "timestamp": _TIME,
            "frame_id": {"type": "string"},
            "data": {"type": "string", "contentEncoding": "base64"},
            "format": {"type": "string", "enum": ["jpeg", "png", "webp", "avif"]},
        },
        "required": ["timestamp", "frame_id", "data", "format"],
    },
    CAMERA_CALIBRATION_SCHEMA: {
        "title": CAMERA_CALIBRATION_SCHEMA,
        "description": "Camera calibration parameters",
        "type": "object",
        "properties": {
            "timestamp": _TIME,
            "frame_id": {"type": "string"},
            "width": {"type": "integer", "minimum": 0},
            "height": {"type": "integer", "minimum": 0},
            "distortion_model": {"type": "string"},
            "D": _number_array(),
            "K": _number_array(9),
            "R": _number_array(9),
            "P": _number_array(12),
        },
        "required": ["timestamp", "frame_id", "width", "height", "distortion_model", "D", "K", "R", "P"],
    },
    POSE_IN_FRAME_SCHEMA: {
        "title": POSE_IN_FRAME_SCHEMA,
        "description": "A timestamped pose for an object or reference frame in 3D space",
        "type": "object",
        "properties": {
            "timestamp": _TIME,
            "frame_id": {"type": "string"},
            "pose": {
                "title": "foxglove.Pose",
                "type": "object",
                "properties": {"position": _VECTOR3, "orientation": _QUATERNION},
                "required": ["position", "orientation"],
            },
        },
        "required": ["timestamp", "frame_id", "pose"],
    },
    IMAGE_ANNOTATIONS_SCHEMA: {
        "title": IMAGE_ANNOTATIONS_SCHEMA,
        "description": "Array of annotations for a 2D image",
        "type": "object",
        "properties": {
            "circles": {
                "type": "array",
                "items": {
                    "title": "foxglove.CircleAnnotation",
                    "type": "object",
                    "properties": {
                        "timestamp": _TIME,
                        "position": _POINT2,
                        "diameter": _NUMBER,
                        "thickness": _NUMBER,
                        "fill_color": _COLOR,
                        "outline_color": _COLOR,
                        "metadata": _KEY_VALUES,
                    },
                    "required": ["timestamp", "position", "diameter", "thickness", "fill_color", "outline_color", "metadata"],
                },
            },
            "points": {
                "type": "array",
                "items": {
                    "title": "foxglove.PointsAnnotation",
                    "type": "object",
                    "properties": {
                        "timestamp": _TIME,
                        "type": {"type": "integer", "enum": [0, 1, 2, 3, 4]},
                        "points": {"type": "array", "items": _POINT2},
                        "outline_color": _COLOR,
                        "outline_colors": {"type": "array", "items": _COLOR},
                        "fill_color": _COLOR,
                        "thickness": _NUMBER,
                        "metadata": _KEY_VALUES,
                    },
                    "required": ["timestamp", "type", "points", "outline_color", "outline_colors", "fill_color", "thickness", "metadata"],
                },
            },
            "texts": {
                "type": "array",
                "items": {
                    "title": "foxglove.TextAnnotation",
                    "type": "object",
                    "properties": {
                        "timestamp": _TIME,
                        "position": _POINT2,
                        "text": {"type": "string"},
                        "font_size": _NUMBER,
                        "text_color": _COLOR,
                        "background_color": _COLOR,
                        "metadata": _KEY_VALUES,
                    },
                    "required": ["timestamp", "position", "text", "font_size", "text_color", "background_color", "metadata"],
                },
            },
        },
        "required": ["circles", "points", "texts"],
    },
    LOG_SCHEMA: {
        "title": LOG_SCHEMA,
        "description": "A log message",
        "type": "object",
        "properties": {
            "timestamp": _TIME,
            "level": {"type": "integer", "enum": [0, 1, 2, 3, 4, 5]},
            "message": {"type": "string"},
            "name": {"type": "string"},
            "file": {"type": "string"},
            "line": {"type": "integer", "minimum": 0},
        },
        "required": ["timestamp", "level", "message", "name", "file", "line"],
    },
}

HBVS_SCHEMAS: dict[str, dict[str, Any]] = {
    VELOCITY_COMMAND_SCHEMA: {
        "title": VELOCITY_COMMAND_SCHEMA,
        "description": "A unicycle velocity command: v along the robot's x axis, w about z",
        "type": "object",
        "properties": {
            "timestamp": _TIME,
            "v": {**_NUMBER, "description": "linear velocity (m/s)"},
            "w": {**_NUMBER, "description": "angular velocity (rad/s)"},
            "saturated": {"type": "boolean", "description": "clipped by the actuator limits"},
        },
        "required": ["timestamp", "v", "w"],
    },
    DESIRED_SIGNAL_SCHEMA: {
        "title": DESIRED_SIGNAL_SCHEMA,
        "description": "Desired signals of Remark 1: decomposed (raw) or smoothed by splines",
        "type": "object",
        "properties": {
            "timestamp": _TIME,
            "t": {**_NUMBER, "description": "time from the start of the taught run (s)"},
            "theta_d": {**_NUMBER, "description": "desired rotation (rad)"},
            "x_hd1": {**_NUMBER, "description": "desired scaled translation x_f1 / d* (-)"},
            "x_hd2": {**_NUMBER, "description": "desired scaled translation x_f2 / d* (-)"},
            "theta_d_dot": {**_NUMBER_OR_NULL, "description": "rad/s (smooth only)"},
            "x_hd1_dot": {**_NUMBER_OR_NULL, "description": "1/s (smooth only)"},
            "x_hd2_dot": {**_NUMBER_OR_NULL, "description": "1/s (smooth only)"},
            "residual": {**_NUMBER_OR_NULL, "description": "RMS equation residual of the frame (raw only)"},
        },
        "required": ["timestamp", "t", "theta_d", "x_hd1", "x_hd2"],
    },
    FIT_MODEL_SCHEMA: {
        "title": FIT_MODEL_SCHEMA,
        "description": "The fitted desired trajectory and everything repeat needs to track it",
        "type": "object",
        "properties": {
            "format_version": {"type": "integer", "const": 1},
            "timestamp": _TIME,
            "target_kind": {"type": "string", "enum": ["dots", "aruco", "texture"]},
            "camera": {"type": "object"},
            "reference": {"type": "object"},
            "normal": _number_array(3),
            "normal_margin": _NUMBER,
            "trajectory": {"type": "object"},
            "dhat0": {**_NUMBER, "exclusiveMinimum": 0, "description": "suggested initial depth estimate (m)"},
            "dhat0_source": {"type": "string"},
            "depth": {"type": "object"},
            "frames": {"type": "object"},
            "condition35": {"type": "object"},
            "world": {"type": ["object", "null"]},
            "taught_path": {"type": ["object", "null"]},
            "detector": {"type": "object"},
            "residual_px": {"type": "object"},
            "render": {"type": ["object", "null"], "description": "sensor model of a simulated teach"},
            "gains": {"type": ["object", "null"], "description": "gains suggested from x_hd1_dot and the detector's noise (k_v, k_w, gamma, k_2 and the rule's inputs)"},
        },
        "required": [
            "format_version", "timestamp", "target_kind", "camera", "reference", "normal",
            "trajectory", "dhat0", "dhat0_source", "frames", "condition35",
        ],
    },
    CONTROLLER_STATE_SCHEMA: {
        "title": CONTROLLER_STATE_SCHEMA,
        "description": "One control step of the adaptive tracking controller (29)-(31)",
        "type": "object",
        "properties": {
            "timestamp": _TIME,
            "t": _NUMBER,
            "x_h1": _NUMBER_OR_NULL, "x_h2": _NUMBER_OR_NULL, "theta": _NUMBER_OR_NULL,
            "x_hd1": _NUMBER, "x_hd2": _NUMBER, "theta_d": _NUMBER,
            "x_hd1_dot": _NUMBER, "x_hd2_dot": _NUMBER, "theta_d_dot": _NUMBER,
            "e1": _NUMBER_OR_NULL, "e2": _NUMBER_OR_NULL, "ebar2": _NUMBER_OR_NULL, "e3": _NUMBER_OR_NULL,
            "v_c": _NUMBER, "w_c": _NUMBER,
            "v_law": _NUMBER_OR_NULL, "w_law": _NUMBER_OR_NULL,
            "saturated": {"type": "boolean"},
            "dhat": _NUMBER,
            "target_lost": {"type": "boolean"},
            "lost_reason": {"type": "string"},
            "frame_dropped": {"type": "boolean"},
            "residual": _NUMBER_OR_NULL,
            "V": _NUMBER_OR_NULL,
            "theta_est": _NUMBER_OR_NULL, "x_h1_est": _NUMBER_OR_NULL, "x_h2_est": _NUMBER_OR_NULL,
            "theta_std": _NUMBER_OR_NULL, "x_h1_std": _NUMBER_OR_NULL, "x_h2_std": _NUMBER_OR_NULL,
            "noise_px": _NUMBER_OR_NULL,
            "filter": {"type": "string", "description": "what the state filter did: fused, gated, started, predicted, or empty without a filter"},
        },
        "required": [
            "timestamp", "t", "x_h1", "x_h2", "theta", "x_hd1", "x_hd2", "theta_d",
            "x_hd1_dot", "x_hd2_dot", "theta_d_dot", "e1", "e2", "ebar2", "e3",
            "v_c", "w_c", "saturated", "dhat", "target_lost", "V",
        ],
    },
}

#: Every schema hbvs can write or read, by name.
SCHEMAS: dict[str, dict[str, Any]] = {**FOXGLOVE_SCHEMAS, **HBVS_SCHEMAS}
