"""A calibration read as a mapping of keys (ROS YAML, plain JSON, OpenCV FileStorage) to intrinsics;
keys match without regard to case, ``_`` or ``-`` (``camera_matrix`` is ``cameraMatrix``).
Kalibr ``camchain.yaml``: ``cam0``, a ``pinhole`` camera with ``radtan`` (read as plumb_bob with k3 = 0),
``equidistant`` (``cv2.fisheye``) or no distortion.
The checks every calibration passes, whatever its format: numbers, image sides, K and the distortion model."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ...core.camera import CameraIntrinsics
from ...errors import CalibrationError
from ..images import MAX_IMAGE_PIXELS
from ..text_files import short_repr

#: Image sides beyond this are surely a typo (and would make undistortion maps huge).
_MAX_IMAGE_SIDE = 1 << 15
_MODEL_SIZES = {"plumb_bob": 5, "rational_polynomial": 8, "equidistant": 4}
#: Other names of the fisheye model (k1..k4 of ``cv2.fisheye``).
_MODEL_ALIASES = {"kannala_brandt": "equidistant", "fisheye": "equidistant", "kannala-brandt": "equidistant"}

#: More numbers than any calibration matrix holds (counted before flattening: YAML aliases).
_MAX_NUMBERS = 4096


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _kind_of(value: Any) -> str:
    if isinstance(value, str):
        return "a string"
    if isinstance(value, Mapping):
        return "a mapping"
    if isinstance(value, Sequence):
        return "a list"
    return f"a {type(value).__name__}"


def _normalise_key(key: Any) -> str:
    return str(key).lower().replace("_", "").replace("-", "")


def _build_intrinsics(
    K: Sequence[float], width: int, height: int, model: str | None, coefficients: Sequence[float], name: str,
    k_key: str = "camera_matrix", d_key: str = "distortion_coefficients", notes: list[str] | None = None,
    sigma: tuple[float, ...] = (),
) -> CameraIntrinsics:
    """Validate a flat row-major K, a size and a distortion into CameraIntrinsics (with the
    ``sigma`` the calibration states)."""
    if not all(math.isfinite(v) for v in K):
        raise CalibrationError(f"{name}: {k_key} contains NaN or infinity")
    if not all(math.isfinite(v) for v in coefficients):
        raise CalibrationError(f"{name}: {d_key} contains NaN or infinity")
    fx, skew, cx, zero_10, fy, cy, zero_20, zero_21, one = K
    if fx <= 0 or fy <= 0:
        raise CalibrationError(f"{name}: {k_key} focal lengths must be positive, got fx={fx:g}, fy={fy:g}")
    if abs(skew) > 1e-9 * fx:
        raise CalibrationError(f"{name}: {k_key} has skew {skew:g}; hbvs supports zero-skew cameras only")
    if zero_10 != 0 or zero_20 != 0 or zero_21 != 0 or one != 1:
        raise CalibrationError(f"{name}: {k_key} is not an intrinsic matrix: expected the form [fx 0 cx; 0 fy cy; 0 0 1]")
    if width * height > MAX_IMAGE_PIXELS:
        raise CalibrationError(f"{name}: a {width}x{height} image has more pixels than hbvs reads ({MAX_IMAGE_PIXELS} at most)")
    if not (0.0 <= cx <= width and 0.0 <= cy <= height):
        raise CalibrationError(f"{name}: principal point ({cx:g}, {cy:g}) lies outside the {width}x{height} image")
    resolved_model, distortion = _resolve_distortion(model, list(coefficients), name, d_key, notes)
    try:
        return CameraIntrinsics(
            fx=float(fx), fy=float(fy), cx=float(cx), cy=float(cy), width=width, height=height,
            distortion_model=resolved_model, distortion=distortion, sigma=sigma,
        )
    except CalibrationError as exc:
        raise CalibrationError(f"{name}: {exc}") from None


def _resolve_distortion(
    model: str | None, coefficients: list[float], name: str, d_key: str, notes: list[str] | None = None
) -> tuple[str, tuple[float, ...]]:
    """A supported (model, coefficients) pair, inferring the model from the count if absent;
    trailing zeros beyond a model's length (OpenCV's padding) are dropped."""
    requested = (model or "").strip().lower()
    requested = _MODEL_ALIASES.get(requested, requested)
    n = len(coefficients)
    if requested in ("", "none"):
        if not any(coefficients):
            return "none", ()
        if requested == "none":
            raise CalibrationError(f"{name}: distortion_model is 'none' but {d_key} are not all zero")
        if n in (4, 5):
            requested = "plumb_bob"
            if n == 4 and notes is not None:
                notes.append(
                    f"{name}: 4 distortion coefficients and no distortion_model: read as plumb_bob (k1 k2 p1 p2); "
                    "if this is a fisheye calibration (cv2.fisheye), add distortion_model: equidistant to the file"
                )
        elif n in (8, 12, 14):
            requested = "rational_polynomial" if any(coefficients[5:]) else "plumb_bob"
        else:
            raise CalibrationError(f"{name}: {d_key} has {n} numbers; expected 5 (k1 k2 p1 p2 k3) or 8 (rational polynomial)")
    if requested not in _MODEL_SIZES:
        raise CalibrationError(
            f"{name}: unsupported distortion model {requested!r} (hbvs supports plumb_bob, rational_polynomial, "
            "equidistant (fisheye, also kannala_brandt), none)"
        )
    expected = _MODEL_SIZES[requested]
    if n == 0 or not any(coefficients):
        # ROS writes plumb_bob with no or all-zero coefficients for an undistorted camera.
        return "none", ()
    if requested == "plumb_bob" and n == 4:
        coefficients = coefficients + [0.0]  # OpenCV's 4-coefficient form: k3 = 0
    elif n > expected and not any(coefficients[expected:]):
        coefficients = coefficients[:expected]
    if len(coefficients) != expected:
        raise CalibrationError(f"{name}: {d_key} has {n} numbers, expected {expected} for the {requested} model")
    return requested, tuple(float(v) for v in coefficients)


def _number(value: Any, what: str) -> float:
    # bool is an int subclass: `true` in a YAML matrix is a mistake, not a 1.
    if isinstance(value, bool) or value is None:
        raise CalibrationError(f"{what} must hold numbers, found {value!r}")
    if isinstance(value, (int, float, np.integer, np.floating)):
        try:
            return float(value)
        except OverflowError:  # an integer literal with hundreds of digits
            raise CalibrationError(f"{what} holds a number out of range") from None
    if isinstance(value, str):
        # PyYAML reads exponents without a dot ("1e-05") as strings (YAML 1.1 rules).
        try:
            return float(value)
        except ValueError:
            pass
    raise CalibrationError(f"{what} must hold numbers, found {short_repr(value, 40)}")


def _numbers(value: Any, what: str) -> list[float]:
    """Numbers from a ROS ``{rows, cols, data}`` matrix, a flat or nested list, or an array."""
    if isinstance(value, np.ndarray):
        if value.size > _MAX_NUMBERS:
            raise CalibrationError(f"{what} has {value.size} numbers, far more than a calibration holds")
        return [float(v) for v in value.ravel()]
    if isinstance(value, Mapping):
        lowered = {_normalise_key(k): v for k, v in value.items()}
        if "data" not in lowered:
            raise CalibrationError(f"{what} is a mapping without 'data'; expected {{rows, cols, data}} or a list")
        data = _numbers(lowered["data"], what)
        if "rows" in lowered and "cols" in lowered:
            rows = _number(lowered["rows"], f"{what} rows")
            cols = _number(lowered["cols"], f"{what} cols")
            if rows * cols != len(data):
                raise CalibrationError(f"{what} declares {rows:g}x{cols:g} but its data has {len(data)} numbers")
        return data
    if isinstance(value, (str, bytes)) or not (hasattr(value, "__len__") and hasattr(value, "__iter__")):
        return [_number(value, what)]
    # A list, or array.array and other sized iterables (as decoded ROS messages hold).
    rows = [value] if not value or not all(isinstance(row, Sequence) and not isinstance(row, (str, bytes)) for row in value) else value
    if sum(len(row) for row in rows) > _MAX_NUMBERS:
        raise CalibrationError(f"{what} has far more numbers than a calibration holds")
    if len({len(row) for row in rows}) != 1:
        raise CalibrationError(f"{what} has rows of different lengths")
    return [_number(v, what) for row in rows for v in row]


def _image_side(value: Any, what: str) -> int:
    number = _number(value, what)
    if not math.isfinite(number) or number != int(number):
        raise CalibrationError(f"{what} must be a whole number of pixels, got {short_repr(value, 40)}")
    if number <= 0:
        raise CalibrationError(f"{what} must be positive, got {int(number)}")
    if number > _MAX_IMAGE_SIDE:
        raise CalibrationError(f"{what} = {int(number)} px is implausibly large (limit {_MAX_IMAGE_SIDE})")
    return int(number)


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
