"""Camera calibration files: ROS ``camera_info`` YAML (read and written), OpenCV ``FileStorage``,
Kalibr ``camchain.yaml`` and plain JSON (``{"K": [[...], [...], [...]], "D": [...], "width": 640, "height": 480}``),
recognised by content (:func:`load_calibration`); every format passes :mod:`.mapping`'s checks, and a user's mistake raises
a one-line :class:`~hbvs_cli.errors.CalibrationError`."""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from typing import Any

from ...core.camera import CameraIntrinsics
from ...errors import CalibrationError
from ..text_files import read_small_file
from .mapping import (
    _intrinsics_from_mapping, _one_line, _require_mapping, intrinsics_from_kalibr, intrinsics_from_values, is_kalibr,
    stated_sigma,
)
from .opencv import _read_opencv_storage
from .ros import _read_yaml, calibration_from_foxglove, calibration_to_foxglove, save_calibration_ros

__all__ = [
    "MAX_CALIBRATION_BYTES", "load_calibration", "save_calibration_ros", "calibration_to_foxglove",
    "calibration_from_foxglove", "intrinsics_from_values", "stated_sigma",
]

#: Calibration files are a few hundred bytes; anything above this is refused unread.
MAX_CALIBRATION_BYTES = 1 << 20


def load_calibration(
    path: str | os.PathLike[str], image_size: tuple[int, int] | None = None, notes: list[str] | None = None,
) -> CameraIntrinsics:
    """Camera intrinsics from a ROS, OpenCV, Kalibr or JSON calibration file (detected by content);
    ``image_size`` (width, height) when the file gives none; ``notes`` receives what was assumed."""
    name = str(path)
    data = read_small_file(path, MAX_CALIBRATION_BYTES, "a calibration file", CalibrationError)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise CalibrationError(
            f"{name}: not UTF-8 text (invalid byte at offset {exc.start}); expected a YAML or JSON calibration file"
        ) from None
    text = text.removeprefix("\ufeff")  # editors on Windows add a byte-order mark
    if "\x00" in text:
        raise CalibrationError(f"{name}: contains NUL bytes; expected a YAML or JSON calibration file")
    head = text.lstrip()
    if not head:
        raise CalibrationError(f"{name}: the file is empty")

    if head.startswith("%YAML:") or "opencv-matrix" in text or head.startswith("<"):
        # "%YAML:1.0" and opencv-matrix tags need OpenCV's own reader; XML can only be OpenCV's.
        mapping = _read_opencv_storage(text, name)
    elif head.startswith("{") or head.startswith("["):
        mapping = _read_json(text, name)
    else:
        mapping = _read_yaml(text, name)
    if is_kalibr(mapping):
        return intrinsics_from_kalibr(mapping, name, image_size)
    return _intrinsics_from_mapping(mapping, name, image_size, notes)


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
