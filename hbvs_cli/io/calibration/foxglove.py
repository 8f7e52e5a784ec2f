"""``foxglove.CameraCalibration`` messages (protobuf) from and to intrinsics."""

from __future__ import annotations

from typing import Any

from ...core.camera import CameraIntrinsics
from ...errors import InputError
from .ros import _IDENTITY, _projection, _ros_distortion
from .validate import intrinsics_from_values


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
