"""Kalibr ``camchain.yaml``: hbvs reads ``cam0``, a ``pinhole`` camera with ``radtan`` (read as
plumb_bob with k3 = 0), ``equidistant`` (``cv2.fisheye``) or no distortion."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ...core.camera import CameraIntrinsics
from ...errors import CalibrationError
from .validate import _build_intrinsics, _image_side, _kind_of, _numbers

#: Kalibr's distortion model names to hbvs's (ROS's).
_KALIBR_MODELS = {"radtan": "plumb_bob", "equidistant": "equidistant", "none": "none"}


def is_kalibr(mapping: Mapping[str, Any]) -> bool:
    """True for a Kalibr camchain: a ``cam0`` mapping holding ``intrinsics``."""
    camera = mapping.get("cam0")
    return isinstance(camera, Mapping) and "intrinsics" in camera


def intrinsics_from_kalibr(mapping: Mapping[str, Any], name: str, image_size: tuple[int, int] | None = None) -> CameraIntrinsics:
    """The intrinsics of ``cam0`` of a Kalibr camchain; :class:`CalibrationError` when unsupported or bad."""
    camera = mapping["cam0"]
    where = f"{name}: cam0"
    model = camera.get("camera_model", "pinhole")
    if model != "pinhole":
        raise CalibrationError(f"{where}: camera_model {str(model)[:40]!r} is not supported (hbvs reads pinhole)")
    intrinsics = _numbers(camera["intrinsics"], f"{where}: intrinsics")
    if len(intrinsics) != 4:
        raise CalibrationError(f"{where}: intrinsics has {len(intrinsics)} numbers, expected 4 (fu fv pu pv)")
    fu, fv, pu, pv = intrinsics
    distortion = camera.get("distortion_model", "none")
    if not isinstance(distortion, str) or distortion.strip().lower() not in _KALIBR_MODELS:
        shown = str(distortion)[:40] if isinstance(distortion, str) else _kind_of(distortion)
        raise CalibrationError(f"{where}: distortion_model {shown!r} is not supported (hbvs reads radtan, equidistant, none)")
    coefficients = _numbers(camera.get("distortion_coeffs") or [], f"{where}: distortion_coeffs")
    resolution = camera.get("resolution")
    if resolution is not None:
        size = _numbers(resolution, f"{where}: resolution")
        if len(size) != 2:
            raise CalibrationError(f"{where}: resolution has {len(size)} numbers, expected 2 (width, height)")
        width, height = _image_side(size[0], f"{where}: resolution"), _image_side(size[1], f"{where}: resolution")
    elif image_size is not None:
        width, height = image_size
    else:
        raise CalibrationError(f"{where}: no resolution and no images to take the size from")
    K = [fu, 0.0, pu, 0.0, fv, pv, 0.0, 0.0, 1.0]
    return _build_intrinsics(
        K, width, height, _KALIBR_MODELS[distortion.strip().lower()], coefficients, where, "intrinsics", "distortion_coeffs",
    )
