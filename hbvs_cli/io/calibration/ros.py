"""ROS ``camera_info`` YAML, read (as the ROS camera calibrator or ``ros2 topic echo`` write it) and written, and
``foxglove.CameraCalibration`` messages (protobuf) from and to intrinsics."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from ...core.camera import CameraIntrinsics
from ...errors import CalibrationError, InputError
from ..limits import load_yaml_documents
from .mapping import _one_line, _require_mapping, intrinsics_from_values


def _read_yaml(text: str, name: str) -> Mapping[str, Any]:
    try:
        # All documents: `ros2 topic echo` output ends with a "---" separator (the first non-empty one is used).
        document = next((doc for doc in load_yaml_documents(text, name, error=CalibrationError) if doc is not None), None)
    except yaml.MarkedYAMLError as exc:
        where = f" at line {exc.problem_mark.line + 1}" if exc.problem_mark is not None else ""
        raise CalibrationError(f"{name}: malformed YAML{where}: {_one_line(exc.problem or exc)}") from None
    except RecursionError:
        raise CalibrationError(f"{name}: malformed YAML: nested too deeply") from None
    except (yaml.YAMLError, ValueError) as exc:
        raise CalibrationError(f"{name}: malformed YAML: {_one_line(exc)}") from None
    if document is None:
        raise CalibrationError(f"{name}: the YAML document is empty")
    return _require_mapping(document, name)


def _ros_distortion(camera: CameraIntrinsics) -> tuple[str, list[float]]:
    """ROS/Foxglove name and coefficients; "none", which ROS tools do not know, becomes plumb_bob with
    zeros (read back as "none")."""
    if camera.distortion_model in ("none", "") or not camera.distortion:
        return "plumb_bob", [0.0] * 5
    return camera.distortion_model, [float(v) for v in camera.distortion]


def _projection(camera: CameraIntrinsics) -> list[float]:
    return [camera.fx, 0.0, camera.cx, 0.0, 0.0, camera.fy, camera.cy, 0.0, 0.0, 0.0, 1.0, 0.0]


_IDENTITY = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]


def save_calibration_ros(camera: CameraIntrinsics, path: str | os.PathLike[str], camera_name: str = "hbvs") -> Path:
    """Write ``camera`` as the ROS camera calibrator's ``camera_info`` YAML (identity rectification,
    projection ``[K | 0]``, floats exact; its ``sigma`` as ``std_deviations_intrinsics``) and return ``path``; :class:`InputError` if it cannot."""
    model, coefficients = _ros_distortion(camera)
    document = {
        "image_width": int(camera.width), "image_height": int(camera.height), "camera_name": str(camera_name),
        "camera_matrix": {"rows": 3, "cols": 3, "data": [float(v) for v in camera.K.ravel()]},
        "distortion_model": model,
        "distortion_coefficients": {"rows": 1, "cols": len(coefficients), "data": coefficients},
        "rectification_matrix": {"rows": 3, "cols": 3, "data": list(_IDENTITY)},
        "projection_matrix": {"rows": 3, "cols": 4, "data": [float(v) for v in _projection(camera)]},
    }
    if camera.sigma:  # not ROS's: the standard deviations hbvs's fit counts (docs/uncertainty.md); ROS tools skip it
        document["std_deviations_intrinsics"] = {"rows": len(camera.sigma), "cols": 1, "data": [float(v) for v in camera.sigma]}
    # PyYAML writes floats exactly (repr); flow style keeps each matrix on one line like the ROS tools.
    text = yaml.safe_dump(document, default_flow_style=None, sort_keys=False, width=4096)
    target = Path(path)
    try:
        target.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise InputError(f"{path}: cannot write the calibration ({exc.strerror or exc})") from None
    return target


def calibration_to_foxglove(camera: CameraIntrinsics, frame_id: str, timestamp_ns: int) -> Any:
    """The ``foxglove.CameraCalibration`` of ``camera`` (``R`` identity, ``P`` ``[K | 0]``, no distortion
    as plumb_bob zeros); :class:`InputError` for a negative ``timestamp_ns``."""
    from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration

    from ..messages import stamp

    if int(timestamp_ns) < 0:
        raise InputError(f"CameraCalibration timestamp must not be negative, got {int(timestamp_ns)} ns")
    model, coefficients = _ros_distortion(camera)
    return CameraCalibration(
        timestamp=stamp(timestamp_ns), frame_id=str(frame_id), width=int(camera.width), height=int(camera.height),
        distortion_model=model, D=coefficients, K=[float(v) for v in camera.K.ravel()], R=list(_IDENTITY),
        P=[float(v) for v in _projection(camera)],
    )


def calibration_from_foxglove(msg: Any, source: str = "foxglove.CameraCalibration message") -> CameraIntrinsics:
    """Intrinsics from a ``foxglove.CameraCalibration``'s ``K``, ``D`` and size (the images are
    unrectified: ``R`` and ``P`` unused); :class:`CalibrationError` when unusable."""
    return intrinsics_from_values(list(msg.K), msg.width, msg.height, msg.distortion_model, list(msg.D), source)
