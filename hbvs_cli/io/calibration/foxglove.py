"""``foxglove.CameraCalibration`` messages from and to intrinsics."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from ...core.camera import CameraIntrinsics
from ...errors import CalibrationError, InputError
from .ros import _IDENTITY, _projection, _ros_distortion
from .validate import _kind_of, intrinsics_from_values


def calibration_to_foxglove(camera: CameraIntrinsics, frame_id: str, timestamp_ns: int) -> dict[str, Any]:
    """The ``foxglove.CameraCalibration`` message (JSON encoding) for ``camera``.

    Parameters
    ----------
    camera : CameraIntrinsics
    frame_id : str
        The camera's frame of reference.
    timestamp_ns : int
        Message time in nanoseconds (non-negative).

    Returns
    -------
    dict
        ``timestamp {sec, nsec}``, ``frame_id``, ``width``, ``height``,
        ``distortion_model``, ``D``, ``K`` (9, row-major), ``R`` (9, identity) and ``P``
        (12, ``[K | 0]``). A camera without distortion is written as plumb_bob with five
        zeros, which every viewer understands.

    Raises
    ------
    InputError
        If ``timestamp_ns`` is negative.
    """
    ns = int(timestamp_ns)
    if ns < 0:
        raise InputError(f"CameraCalibration timestamp must not be negative, got {ns} ns")
    model, coefficients = _ros_distortion(camera)
    sec, nsec = divmod(ns, 1_000_000_000)
    return {
        "timestamp": {"sec": sec, "nsec": nsec},
        "frame_id": str(frame_id),
        "width": int(camera.width),
        "height": int(camera.height),
        "distortion_model": model,
        "D": coefficients,
        "K": [float(v) for v in camera.K.ravel()],
        "R": list(_IDENTITY),
        "P": [float(v) for v in _projection(camera)],
    }


def calibration_from_foxglove(
    msg: Mapping[str, Any], source: str = "foxglove.CameraCalibration message"
) -> CameraIntrinsics:
    """Intrinsics from a ``foxglove.CameraCalibration`` message (the inverse of
    :func:`calibration_to_foxglove`).

    Parameters
    ----------
    msg : mapping
        The decoded JSON message. ``R``, ``P``, ``frame_id`` and ``timestamp`` are not
        used: hbvs works on unrectified images with ``K``.
    source : str
        How to name the message in error messages (e.g. ``"run.mcap /camera/calibration"``).

    Returns the validated :class:`CameraIntrinsics`; raises :class:`CalibrationError` (an
    :class:`InputError`) if a field is missing or of the wrong type, and otherwise as
    :func:`~hbvs_cli.io.calibration.validate.intrinsics_from_values`.
    """
    if not isinstance(msg, Mapping):
        raise CalibrationError(f"{source}: expected a JSON object, found {_kind_of(msg)}")
    for key in ("width", "height", "K"):
        if key not in msg:
            raise CalibrationError(f"{source}: missing field {key!r}")
    if not isinstance(msg["K"], Sequence) or isinstance(msg["K"], (str, bytes)):
        raise CalibrationError(f"{source}: K must be a list of 9 numbers, found {_kind_of(msg['K'])}")
    raw_d = msg.get("D", [])
    if raw_d is None:
        raw_d = []
    if not isinstance(raw_d, Sequence) or isinstance(raw_d, (str, bytes)):
        raise CalibrationError(f"{source}: D must be a list of numbers, found {_kind_of(raw_d)}")
    return intrinsics_from_values(msg["K"], msg["width"], msg["height"], msg.get("distortion_model", ""), raw_d, source)
