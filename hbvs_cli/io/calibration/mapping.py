"""A calibration read as a mapping of keys (ROS YAML, plain JSON, OpenCV FileStorage) to intrinsics;
keys match without regard to case, ``_`` or ``-`` (``camera_matrix`` is ``cameraMatrix``).
Kalibr ``camchain.yaml``: ``cam0``, a ``pinhole`` camera with ``radtan`` (read as plumb_bob with k3 = 0),
``equidistant`` (``cv2.fisheye``) or no distortion."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from ...core.camera import CameraIntrinsics
from ...errors import CalibrationError
from .validate import _build_intrinsics, _image_side, _kind_of, _normalise_key, _numbers

# Aliases, normalised by _normalise_key, in order of preference.
_K_KEYS = ("cameramatrix", "k", "intrinsicmatrix", "intrinsics")
_D_KEYS = ("distortioncoefficients", "d", "distcoeffs", "distcoeff", "distortion")
_WIDTH_KEYS = ("imagewidth", "width")
_HEIGHT_KEYS = ("imageheight", "height")
_SIZE_KEYS = ("imagesize",)
_MODEL_KEYS = ("distortionmodel",)
# The intrinsics' standard deviations: calibrateCameraExtended's (fx fy cx cy k1 k2 p1 p2 k3 ...), as
# docs/walkthrough.md writes them; OpenCV's interactive calibration writes them in two parts.
_SIGMA_KEYS = ("stddeviationsintrinsics",)
_SIGMA_PARTS = (("cameramatrixstddev",), ("distcoeffsstddev",))
_ALL_KEYS = frozenset(_K_KEYS + _D_KEYS + _WIDTH_KEYS + _HEIGHT_KEYS + _SIZE_KEYS + _MODEL_KEYS + _SIGMA_KEYS + sum(_SIGMA_PARTS, ()))


def _require_mapping(document: Any, name: str) -> Mapping[str, Any]:
    if not isinstance(document, Mapping):
        raise CalibrationError(
            f"{name}: expected a mapping of calibration keys (camera_matrix, image_width, ...), "
            f"found {_kind_of(document)}"
        )
    return document


def _lookup(mapping: Mapping[str, Any], aliases: Sequence[str]) -> tuple[str, Any] | None:
    """The first entry whose normalised key is one of ``aliases`` (in their order)."""
    normalised: dict[str, tuple[str, Any]] = {}
    for key, value in mapping.items():
        normalised.setdefault(_normalise_key(key), (str(key), value))
    return next((normalised[alias] for alias in aliases if alias in normalised), None)


def _intrinsics_from_mapping(
    mapping: Mapping[str, Any], name: str, image_size: tuple[int, int] | None = None, notes: list[str] | None = None,
) -> CameraIntrinsics:
    """Intrinsics from a calibration's keys; ``image_size`` (width, height) stands in for a
    file that gives none (an OpenCV calibration often leaves it out)."""
    found = _lookup(mapping, _K_KEYS)
    if found is None:
        raise CalibrationError(f"{name}: no camera_matrix (or K) found; is this a camera calibration file?")
    k_key, k_value = found
    K = _numbers(k_value, f"{name}: {k_key}")
    if len(K) != 9:
        raise CalibrationError(f"{name}: {k_key} has {len(K)} numbers, expected 9")

    width = _lookup(mapping, _WIDTH_KEYS)
    height = _lookup(mapping, _HEIGHT_KEYS)
    size = _lookup(mapping, _SIZE_KEYS)
    if (width is None or height is None) and size is not None:
        pair = _numbers(size[1], f"{name}: {size[0]}")
        if len(pair) != 2:
            raise CalibrationError(f"{name}: {size[0]} has {len(pair)} numbers, expected 2 (width, height)")
        width, height = (size[0] + "[0]", pair[0]), (size[0] + "[1]", pair[1])
    if width is None and height is None and image_size is not None:
        width, height = ("the images' width", image_size[0]), ("the images' height", image_size[1])
    if width is None:
        raise CalibrationError(f"{name}: no image_width (or width) found")
    if height is None:
        raise CalibrationError(f"{name}: no image_height (or height) found")
    w = _image_side(width[1], f"{name}: {width[0]}")
    h = _image_side(height[1], f"{name}: {height[0]}")

    found_d = _lookup(mapping, _D_KEYS)
    coefficients: list[float] = []
    d_key = "distortion_coefficients"
    if found_d is not None and found_d[1] is not None:
        d_key = found_d[0]
        coefficients = _numbers(found_d[1], f"{name}: {d_key}")
    found_model = _lookup(mapping, _MODEL_KEYS)
    model: Any = found_model[1] if found_model is not None else None
    if model is not None and not isinstance(model, str):
        raise CalibrationError(f"{name}: distortion_model must be a string, got {_kind_of(model)}")
    return _build_intrinsics(K, w, h, model, coefficients, name, k_key, d_key, notes, stated_sigma(mapping, name))


def intrinsics_from_values(
    K: Any, width: Any, height: Any, distortion_model: str | None, distortion: Any, source: str,
) -> CameraIntrinsics:
    """Validated intrinsics from raw values (e.g. a ROS ``CameraInfo``): ``K`` (9 numbers row-major, or 3x3), the
    image size (px), the distortion model (None: inferred from the count) and its coefficients in OpenCV order."""
    if distortion_model is not None and not isinstance(distortion_model, str):  # said as these values' own error
        raise CalibrationError(f"{source}: distortion_model must be a string, found {_kind_of(distortion_model)}")
    values = {"K": K, "width": width, "height": height, "D": distortion, "distortion_model": distortion_model}
    return _intrinsics_from_mapping(values, source)


def stated_sigma(mapping: Mapping[str, Any], name: str) -> tuple[float, ...]:
    """The standard deviations of (fx, fy, cx, cy, *distortion) the calibration states, () when none."""
    parts = [found for found in [_lookup(mapping, _SIGMA_KEYS)] if found is not None] or [
        found for found in (_lookup(mapping, keys) for keys in _SIGMA_PARTS) if found is not None]
    sigma = tuple(value for key, part in parts for value in _numbers(part, f"{name}: {key}"))
    if sigma and (not 4 <= len(sigma) <= 18 or not all(math.isfinite(v) and v >= 0.0 for v in sigma)):
        raise CalibrationError(f"{name}: {parts[0][0]} must hold 4 to 18 finite non-negative standard deviations (fx fy cx cy, then the distortion's)")
    return sigma

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
