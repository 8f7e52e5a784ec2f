"""Camera calibration files: read the common formats, write ROS ``camera_info`` YAML.

Three families of files are recognised by their content (the extension is only a hint
people get wrong):

* the ROS ``camera_info`` YAML written by the ROS camera calibrator (``camera_matrix:
  {rows, cols, data}``...), and also the flat ``k:``/``d:`` lists of a dumped
  ``sensor_msgs/CameraInfo``;
* OpenCV ``FileStorage`` files (YAML with ``!!opencv-matrix`` tags, JSON with
  ``"type_id": "opencv-matrix"``, XML), parsed with :class:`cv2.FileStorage` and their
  matrices read field by field (``FileNode.mat()`` corrupts OpenCV's heap on a malformed
  matrix);
* plain JSON such as ``{"K": [[...], [...], [...]], "D": [...], "width": 640, "height": 480}``.

Key names are matched without regard to case, ``_`` or ``-``, so ``camera_matrix``,
``cameraMatrix`` and ``Camera_Matrix`` are the same key.

Every problem a user can cause raises :class:`~hbvs_cli.errors.CalibrationError` with a
one-line message that starts with the file name.
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..core.camera import CameraIntrinsics
from ..errors import CalibrationError, InputError
from .images import MAX_IMAGE_PIXELS

__all__ = [
    "MAX_CALIBRATION_BYTES",
    "load_calibration",
    "parse_calibration",
    "save_calibration_ros",
    "calibration_to_foxglove",
    "calibration_from_foxglove",
    "intrinsics_from_values",
]

#: Calibration files are a few hundred bytes; anything above this is refused unread, so a
#: hostile or mistaken file (a video passed as --calibration) cannot exhaust memory.
MAX_CALIBRATION_BYTES = 1 << 20

#: Image sizes beyond this are surely a typo, and would make later per-pixel buffers
#: (undistortion maps) allocate absurd amounts of memory.
_MAX_IMAGE_SIDE = 1 << 15

# Aliases, normalised by _normalise_key, in order of preference.
_K_KEYS = ("cameramatrix", "k", "intrinsicmatrix", "intrinsics")
_D_KEYS = ("distortioncoefficients", "d", "distcoeffs", "distcoeff", "distortion")
_WIDTH_KEYS = ("imagewidth", "width")
_HEIGHT_KEYS = ("imageheight", "height")
_SIZE_KEYS = ("imagesize",)
_MODEL_KEYS = ("distortionmodel",)
_ALL_KEYS = frozenset(_K_KEYS + _D_KEYS + _WIDTH_KEYS + _HEIGHT_KEYS + _SIZE_KEYS + _MODEL_KEYS)

_MODEL_SIZES = {"plumb_bob": 5, "rational_polynomial": 8}

#: More numbers than any calibration matrix holds. YAML aliases let a small file describe
#: a huge nested list; counting before flattening keeps that from exhausting memory.
_MAX_NUMBERS = 4096


# ----------------------------------------------------------------------------- reading
def load_calibration(path: str | os.PathLike[str]) -> CameraIntrinsics:
    """Read camera intrinsics from a ROS, OpenCV or JSON calibration file.

    Parameters
    ----------
    path : str or path-like
        The calibration file. Its format is detected from its content.

    Returns
    -------
    CameraIntrinsics
        Validated intrinsics. All-zero distortion coefficients become the ``"none"``
        model with no coefficients, so "no distortion" has a single representation.

    Raises
    ------
    CalibrationError
        If the file is missing, a directory, larger than :data:`MAX_CALIBRATION_BYTES`,
        not UTF-8 text, malformed, lacks a camera matrix or image size, or holds values
        that are not a valid zero-skew pinhole camera.
    """
    name = str(path)
    data = _read_capped(Path(path), name)
    return parse_calibration(data, name)


def parse_calibration(data: bytes | str, name: str = "calibration") -> CameraIntrinsics:
    """Parse the content of a calibration file (see :func:`load_calibration`).

    Parameters
    ----------
    data : bytes or str
        The file content.
    name : str
        How to name the source in error messages (usually the file name).

    Returns
    -------
    CameraIntrinsics

    Raises
    ------
    CalibrationError
        As :func:`load_calibration`.
    """
    if isinstance(data, bytes):
        if len(data) > MAX_CALIBRATION_BYTES:
            raise CalibrationError(f"{name}: larger than {MAX_CALIBRATION_BYTES} bytes, not a calibration file")
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise CalibrationError(
                f"{name}: not UTF-8 text (invalid byte at offset {exc.start}); expected a YAML or JSON calibration file"
            ) from None
    else:
        text = data
    text = text.removeprefix("\ufeff")  # editors on Windows add a byte-order mark
    if "\x00" in text:
        raise CalibrationError(f"{name}: contains NUL bytes; expected a YAML or JSON calibration file")
    head = text.lstrip()
    if not head:
        raise CalibrationError(f"{name}: the file is empty")

    if head.startswith("%YAML:") or "opencv-matrix" in text or head.startswith("<"):
        # "%YAML:1.0" is not even valid YAML for PyYAML, and the opencv-matrix tags need
        # OpenCV's own reader; XML can only be OpenCV's too.
        mapping = _read_opencv_storage(text, name)
    elif head.startswith("{") or head.startswith("["):
        mapping = _read_json(text, name)
    else:
        mapping = _read_yaml(text, name)
    return _intrinsics_from_mapping(mapping, name)


def _read_capped(path: Path, name: str) -> bytes:
    """The bytes of ``path``, refusing missing files, directories and oversized files."""
    try:
        if path.is_dir():
            raise CalibrationError(f"{name}: is a directory, expected a calibration file")
        size = path.stat().st_size
    except FileNotFoundError:
        raise CalibrationError(f"{name}: no such file") from None
    except OSError as exc:
        raise CalibrationError(f"{name}: cannot access the file ({exc.strerror or exc})") from None
    if size > MAX_CALIBRATION_BYTES:
        raise CalibrationError(
            f"{name}: {size} bytes is too large for a calibration file (limit {MAX_CALIBRATION_BYTES} bytes)"
        )
    try:
        with path.open("rb") as stream:
            # Read one byte past the cap: the size seen by stat() means nothing for pipes
            # and device files, and the file may grow between stat() and open().
            data = stream.read(MAX_CALIBRATION_BYTES + 1)
    except OSError as exc:
        raise CalibrationError(f"{name}: cannot read the file ({exc.strerror or exc})") from None
    if len(data) > MAX_CALIBRATION_BYTES:
        raise CalibrationError(
            f"{name}: too large for a calibration file (limit {MAX_CALIBRATION_BYTES} bytes)"
        )
    return data


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _read_yaml(text: str, name: str) -> Mapping[str, Any]:
    try:
        # safe_load_all: `ros2 topic echo` output ends with a "---" separator, which
        # safe_load rejects as a second document. The first non-empty document is used.
        document = next((doc for doc in yaml.safe_load_all(text) if doc is not None), None)
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


def _read_json(text: str, name: str) -> Mapping[str, Any]:
    try:
        document = json.loads(text)
    except json.JSONDecodeError as exc:
        raise CalibrationError(f"{name}: malformed JSON at line {exc.lineno} column {exc.colno}: {exc.msg}") from None
    except RecursionError:
        raise CalibrationError(f"{name}: malformed JSON: nested too deeply") from None
    except ValueError as exc:
        raise CalibrationError(f"{name}: malformed JSON: {_one_line(exc)}") from None
    mapping = _require_mapping(document, name)
    if any(isinstance(v, Mapping) and str(v.get("type_id", "")).startswith("opencv-") for v in mapping.values()):
        # OpenCV FileStorage JSON: let OpenCV interpret its own matrix encoding.
        return _read_opencv_storage(text, name)
    return mapping


def _require_mapping(document: Any, name: str) -> Mapping[str, Any]:
    if not isinstance(document, Mapping):
        raise CalibrationError(
            f"{name}: expected a mapping of calibration keys (camera_matrix, image_width, ...), "
            f"found {_kind_of(document)}"
        )
    return document


def _kind_of(value: Any) -> str:
    if isinstance(value, str):
        return "a string"
    if isinstance(value, Mapping):
        return "a mapping"
    if isinstance(value, Sequence):
        return "a list"
    return f"a {type(value).__name__}"


def _read_opencv_storage(text: str, name: str) -> dict[str, Any]:
    """The calibration-related top-level entries of an OpenCV FileStorage document."""
    import cv2

    try:
        # FILE_STORAGE_MEMORY parses the text already read (and size-checked) instead of
        # opening the path a second time.
        storage = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except (cv2.error, SystemError) as exc:
        # OpenCV's parser errors surface as SystemError chained to the cv2.error.
        raise CalibrationError(f"{name}: malformed OpenCV FileStorage file: {_opencv_message(exc)}") from None
    try:
        if not storage.isOpened():
            raise CalibrationError(f"{name}: OpenCV could not parse this FileStorage file")
        root = storage.root()
        if not root.isMap():
            raise CalibrationError(f"{name}: expected a mapping of calibration keys at the top level")
        result: dict[str, Any] = {}
        for key in root.keys():
            if _normalise_key(key) in _ALL_KEYS:
                result[key] = _opencv_node_value(storage.getNode(key), f"{name}: {key}")
        return result
    except (cv2.error, SystemError) as exc:
        raise CalibrationError(f"{name}: malformed OpenCV FileStorage file: {_opencv_message(exc)}") from None
    finally:
        storage.release()


def _opencv_message(exc: BaseException) -> str:
    """The useful part of an OpenCV error (``... error: (-212:Parsing error) ...``)."""
    cause = exc.__cause__ if exc.__cause__ is not None else exc
    message = _one_line(cause)
    marker = "error: "
    return message.split(marker, 1)[1] if marker in message else message


def _opencv_node_value(node: Any, what: str, depth: int = 0) -> Any:
    """A FileNode as a Python value; matrices through :func:`_opencv_matrix`."""
    if node.empty() or node.isNone():
        return None
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return float(node.real())
    if node.isString():
        return node.string()
    if node.isSeq():
        if depth > 2:
            raise CalibrationError(f"{what} is nested too deeply")
        if node.size() > _MAX_NUMBERS:
            raise CalibrationError(f"{what} has far more numbers than a calibration holds")
        return [_opencv_node_value(node.at(i), what, depth + 1) for i in range(node.size())]
    if node.isMap():
        return _opencv_matrix(node, what)
    return None


#: The element type of an ``opencv-matrix``: channels (optional) and a type letter.
_OPENCV_ELEMENT_TYPE = re.compile(r"([1-9][0-9]?)?([ucwsifdh])")


def _opencv_matrix(node: Any, what: str) -> np.ndarray:
    """An ``opencv-matrix`` (rows, cols, dt, data) or ``opencv-nd-matrix`` (sizes, dt,
    data) mapping, read and checked field by field, as a flat array.

    ``FileNode.mat()`` is not used: OpenCV corrupts its heap on a matrix without rows or
    cols (it raises, and the process aborts later with a double free), so no matrix is
    handed to OpenCV's reader at all.
    """
    if node.getNode("data").empty():
        raise CalibrationError(f"{what} is a mapping, expected a matrix or a list of numbers")
    sizes = node.getNode("sizes")
    if sizes.isSeq() and 1 <= sizes.size() <= 4:
        dimensions = [_opencv_count(sizes.at(i), f"{what} sizes") for i in range(sizes.size())]
    else:
        dimensions = [_opencv_count(node.getNode(key), f"{what} {key}") for key in ("rows", "cols")]
    element = node.getNode("dt")
    match = _OPENCV_ELEMENT_TYPE.fullmatch(element.string() if element.isString() else "")
    if match is None:
        raise CalibrationError(f"{what} is not a valid OpenCV matrix: no valid element type (dt)")
    count = math.prod(dimensions) * int(match.group(1) or 1)
    data = node.getNode("data")
    if not data.isSeq() or count > _MAX_NUMBERS or data.size() != count:
        size = data.size() if data.isSeq() else 0
        raise CalibrationError(f"{what} is not a valid OpenCV matrix: it declares {count} numbers and holds {size}")
    values = [data.at(i) for i in range(count)]
    if not all(value.isInt() or value.isReal() for value in values):
        raise CalibrationError(f"{what} is not a valid OpenCV matrix: its data must be numbers")
    return np.array([value.real() for value in values], dtype=float)


def _opencv_count(node: Any, what: str) -> int:
    """A matrix dimension: a whole number from 1 to _MAX_NUMBERS."""
    if not node.isInt() or not 1 <= node.real() <= _MAX_NUMBERS:
        raise CalibrationError(f"{what} must be a whole number from 1 to {_MAX_NUMBERS}")
    return int(node.real())


def _normalise_key(key: Any) -> str:
    return str(key).lower().replace("_", "").replace("-", "")


def _lookup(mapping: Mapping[str, Any], aliases: Sequence[str]) -> tuple[str, Any] | None:
    """The first entry whose normalised key is one of ``aliases`` (in their order)."""
    normalised: dict[str, tuple[str, Any]] = {}
    for key, value in mapping.items():
        normalised.setdefault(_normalise_key(key), (str(key), value))
    for alias in aliases:
        if alias in normalised:
            return normalised[alias]
    return None


def _intrinsics_from_mapping(mapping: Mapping[str, Any], name: str) -> CameraIntrinsics:
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
    return _build_intrinsics(K, w, h, model, coefficients, name, k_key, d_key)


def intrinsics_from_values(
    K: Any,
    width: Any,
    height: Any,
    distortion_model: str | None,
    distortion: Any,
    source: str,
) -> CameraIntrinsics:
    """Validate raw calibration values (e.g. the fields of a ROS ``CameraInfo``).

    Parameters
    ----------
    K : array_like
        Nine numbers, row-major, or a 3x3 array.
    width, height : int
        Image size (px).
    distortion_model : str or None
        ``plumb_bob``, ``rational_polynomial``, ``none`` or empty/None (inferred from the
        number of coefficients).
    distortion : array_like
        Distortion coefficients (OpenCV order).
    source : str
        How to name the origin of the values in error messages.

    Returns
    -------
    CameraIntrinsics

    Raises
    ------
    CalibrationError
        With the same checks as :func:`load_calibration`.
    """
    k_values = _numbers(K, f"{source}: K")
    if len(k_values) != 9:
        raise CalibrationError(f"{source}: K has {len(k_values)} numbers, expected 9")
    w = _image_side(width, f"{source}: width")
    h = _image_side(height, f"{source}: height")
    coefficients = _numbers(distortion, f"{source}: D") if distortion is not None else []
    if distortion_model is not None and not isinstance(distortion_model, str):
        raise CalibrationError(f"{source}: distortion_model must be a string, found {_kind_of(distortion_model)}")
    return _build_intrinsics(k_values, w, h, distortion_model, coefficients, source, "K", "D")


def _build_intrinsics(
    K: Sequence[float],
    width: int,
    height: int,
    model: str | None,
    coefficients: Sequence[float],
    name: str,
    k_key: str = "camera_matrix",
    d_key: str = "distortion_coefficients",
) -> CameraIntrinsics:
    """Validate a flat row-major K, a size and a distortion into CameraIntrinsics."""
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
        raise CalibrationError(
            f"{name}: {k_key} is not an intrinsic matrix: expected the form [fx 0 cx; 0 fy cy; 0 0 1]"
        )
    if width * height > MAX_IMAGE_PIXELS:
        raise CalibrationError(
            f"{name}: a {width}x{height} image has more pixels than hbvs reads ({MAX_IMAGE_PIXELS} at most)"
        )
    if not (0.0 <= cx <= width and 0.0 <= cy <= height):
        raise CalibrationError(
            f"{name}: principal point ({cx:g}, {cy:g}) lies outside the {width}x{height} image"
        )
    resolved_model, distortion = _resolve_distortion(model, list(coefficients), name, d_key)
    try:
        return CameraIntrinsics(
            fx=float(fx),
            fy=float(fy),
            cx=float(cx),
            cy=float(cy),
            width=width,
            height=height,
            distortion_model=resolved_model,
            distortion=distortion,
        )
    except CalibrationError as exc:
        raise CalibrationError(f"{name}: {exc}") from None


def _resolve_distortion(
    model: str | None, coefficients: list[float], name: str, d_key: str
) -> tuple[str, tuple[float, ...]]:
    """A supported (model, coefficients) pair, inferring the model from the count if absent.

    OpenCV pads its distortion vectors with zeros (14 coefficients when the thin-prism or
    tilt terms are off); trailing zeros beyond a model's length carry no information and
    are dropped.
    """
    requested = (model or "").strip().lower()
    n = len(coefficients)
    if requested in ("", "none"):
        if not any(coefficients):
            return "none", ()
        if requested == "none":
            raise CalibrationError(f"{name}: distortion_model is 'none' but {d_key} are not all zero")
        if n in (4, 5):
            requested = "plumb_bob"
        elif n in (8, 12, 14):
            requested = "rational_polynomial" if any(coefficients[5:]) else "plumb_bob"
        else:
            raise CalibrationError(
                f"{name}: {d_key} has {n} numbers; expected 5 (k1 k2 p1 p2 k3) or 8 (rational polynomial)"
            )
    if requested not in _MODEL_SIZES:
        raise CalibrationError(
            f"{name}: unsupported distortion model {requested!r} (hbvs supports plumb_bob, rational_polynomial, none)"
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
        raise CalibrationError(
            f"{name}: {d_key} has {n} numbers, expected {expected} for the {requested} model"
        )
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
    raise CalibrationError(f"{what} must hold numbers, found {_short_repr(value)}")


def _short_repr(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


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
                raise CalibrationError(
                    f"{what} declares {rows:g}x{cols:g} but its data has {len(data)} numbers"
                )
        return data
    if isinstance(value, Sequence) and not isinstance(value, (str, bytes)):
        if value and all(isinstance(row, Sequence) and not isinstance(row, (str, bytes)) for row in value):
            widths = {len(row) for row in value}
            if sum(len(row) for row in value) > _MAX_NUMBERS:
                raise CalibrationError(f"{what} has far more numbers than a calibration holds")
            if len(widths) != 1:
                raise CalibrationError(f"{what} has rows of different lengths")
            return [_number(v, what) for row in value for v in row]
        if len(value) > _MAX_NUMBERS:
            raise CalibrationError(f"{what} has far more numbers than a calibration holds")
        return [_number(v, what) for v in value]
    if hasattr(value, "__len__") and hasattr(value, "__iter__") and not isinstance(value, (str, bytes)):
        # array.array and other sized iterables (as decoded ROS messages may hold)
        if len(value) > _MAX_NUMBERS:
            raise CalibrationError(f"{what} has far more numbers than a calibration holds")
        return [_number(v, what) for v in value]
    return [_number(value, what)]


def _image_side(value: Any, what: str) -> int:
    number = _number(value, what)
    if not math.isfinite(number) or number != int(number):
        raise CalibrationError(f"{what} must be a whole number of pixels, got {_short_repr(value)}")
    if number <= 0:
        raise CalibrationError(f"{what} must be positive, got {int(number)}")
    if number > _MAX_IMAGE_SIDE:
        raise CalibrationError(f"{what} = {int(number)} px is implausibly large (limit {_MAX_IMAGE_SIDE})")
    return int(number)


# ----------------------------------------------------------------------------- writing
def _ros_distortion(camera: CameraIntrinsics) -> tuple[str, list[float]]:
    """ROS/Foxglove name and coefficients; "none" becomes plumb_bob with zeros.

    ROS tools (image_geometry, camera_info_manager) know no "none" model, while a
    zero plumb_bob is understood everywhere and loads back as "none".
    """
    if camera.distortion_model in ("none", "") or not camera.distortion:
        return "plumb_bob", [0.0] * 5
    return camera.distortion_model, [float(v) for v in camera.distortion]


def _projection(camera: CameraIntrinsics) -> list[float]:
    return [camera.fx, 0.0, camera.cx, 0.0, 0.0, camera.fy, camera.cy, 0.0, 0.0, 0.0, 1.0, 0.0]


_IDENTITY = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]


def save_calibration_ros(
    camera: CameraIntrinsics, path: str | os.PathLike[str], camera_name: str = "hbvs"
) -> Path:
    """Write ``camera`` as the ROS ``camera_info`` YAML of the ROS camera calibrator.

    The rectification is the identity and the projection ``[K | 0]`` (a monocular
    camera). Floats are written with their shortest exact representation, so
    :func:`load_calibration` returns the same values.

    Parameters
    ----------
    camera : CameraIntrinsics
    path : str or path-like
        Destination; overwritten if it exists.
    camera_name : str
        The ``camera_name`` field.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    InputError
        If the file cannot be written.
    """
    model, coefficients = _ros_distortion(camera)
    document = {
        "image_width": int(camera.width),
        "image_height": int(camera.height),
        "camera_name": str(camera_name),
        "camera_matrix": {"rows": 3, "cols": 3, "data": [float(v) for v in camera.K.ravel()]},
        "distortion_model": model,
        "distortion_coefficients": {"rows": 1, "cols": len(coefficients), "data": coefficients},
        "rectification_matrix": {"rows": 3, "cols": 3, "data": list(_IDENTITY)},
        "projection_matrix": {"rows": 3, "cols": 4, "data": [float(v) for v in _projection(camera)]},
    }
    # PyYAML writes floats with repr() (plus ".0" before an exponent), which is exact and
    # reads back as a float; flow style keeps each matrix on one line like the ROS tools.
    text = yaml.safe_dump(document, default_flow_style=None, sort_keys=False, width=4096)
    target = Path(path)
    try:
        target.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise InputError(f"{path}: cannot write the calibration ({exc.strerror or exc})") from None
    return target


# ----------------------------------------------------------------------------- Foxglove
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

    Returns
    -------
    CameraIntrinsics

    Raises
    ------
    CalibrationError
        (an :class:`InputError`) if a field is missing, of the wrong type or the values
        are not a valid camera.
    """
    if not isinstance(msg, Mapping):
        raise CalibrationError(f"{source}: expected a JSON object, found {_kind_of(msg)}")
    for key in ("width", "height", "K"):
        if key not in msg:
            raise CalibrationError(f"{source}: missing field {key!r}")
    if not isinstance(msg["K"], Sequence) or isinstance(msg["K"], (str, bytes)):
        raise CalibrationError(f"{source}: K must be a list of 9 numbers, found {_kind_of(msg['K'])}")
    K = _numbers(msg["K"], f"{source}: K")
    if len(K) != 9:
        raise CalibrationError(f"{source}: K has {len(K)} numbers, expected 9")
    width = _image_side(msg["width"], f"{source}: width")
    height = _image_side(msg["height"], f"{source}: height")
    raw_d = msg.get("D", [])
    if raw_d is None:
        raw_d = []
    if not isinstance(raw_d, Sequence) or isinstance(raw_d, (str, bytes)):
        raise CalibrationError(f"{source}: D must be a list of numbers, found {_kind_of(raw_d)}")
    if len(raw_d) > _MAX_NUMBERS:
        raise CalibrationError(f"{source}: D has far more numbers than a calibration holds")
    coefficients = [_number(v, f"{source}: D") for v in raw_d]
    model = msg.get("distortion_model", "")
    if model is not None and not isinstance(model, str):
        raise CalibrationError(f"{source}: distortion_model must be a string, found {_kind_of(model)}")
    return _build_intrinsics(K, width, height, model, coefficients, source, "K", "D")
