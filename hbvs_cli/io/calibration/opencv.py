"""OpenCV ``FileStorage`` calibration files (YAML with ``!!opencv-matrix`` tags, JSON, XML)."""

from __future__ import annotations

import math
import re
from typing import Any

import numpy as np

from ...errors import CalibrationError
from ..native_log import opencv_error_text
from .mapping import _ALL_KEYS, _MAX_NUMBERS, _normalise_key


def _read_opencv_storage(text: str, name: str) -> dict[str, Any]:
    """The calibration-related top-level entries of an OpenCV FileStorage document."""
    import cv2

    try:
        # FILE_STORAGE_MEMORY: the text already read (and size-checked), not the path a second time.
        storage = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
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
        finally:
            storage.release()
    except (cv2.error, SystemError) as exc:
        # OpenCV's parser errors surface as SystemError chained to the cv2.error.
        raise CalibrationError(f"{name}: malformed OpenCV FileStorage file: {opencv_error_text(exc)}") from None


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
    """An ``opencv-matrix`` (rows, cols, dt, data) or ``opencv-nd-matrix`` (sizes, dt, data) mapping, read
    field by field as a flat array: ``FileNode.mat()`` corrupts OpenCV's heap on a matrix without rows or cols."""
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
