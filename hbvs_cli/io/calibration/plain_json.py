"""Plain JSON calibration files such as ``{"K": [[...], [...], [...]], "D": [...], "width": 640, "height": 480}``."""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

from ...errors import CalibrationError
from .mapping import _require_mapping
from .opencv import _read_opencv_storage
from .validate import _one_line


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
