"""Image bytes <-> arrays, and the ``foxglove.CompressedImage`` message around them."""

from __future__ import annotations

import base64
import binascii
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError, RecordingError, UsageError

IMAGE_FORMATS = ("png", "jpeg")
#: Largest decoded image accepted (pixels): 8K x 8K. A hostile header cannot make OpenCV
#: allocate more than this.
MAX_IMAGE_PIXELS = 8192 * 8192


def encode_image(image: NDArray[np.uint8], image_format: str = "png", jpeg_quality: int = 95) -> bytes:
    """Compress an 8-bit image to PNG (lossless) or JPEG."""
    import cv2

    if image_format not in IMAGE_FORMATS:
        raise UsageError(f"unknown image format {image_format!r}: choose png or jpeg")
    # Sensor noise defeats LZ matching: Huffman-only PNG is both smaller and faster here.
    png = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY]
    params = [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality] if image_format == "jpeg" else png
    ok, buffer = cv2.imencode(".png" if image_format == "png" else ".jpg", image, params)
    if not ok:  # pragma: no cover - OpenCV encodes any uint8 image
        raise RecordingError("OpenCV could not encode an image")
    return buffer.tobytes()


def image_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) read from a PNG or JPEG header without decoding, when available."""
    if data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) >= 24:
        return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    return None


def decode_image(data: bytes, source: str = "") -> NDArray[np.uint8]:
    """Decode PNG/JPEG (any image OpenCV reads) to 8-bit gray; :class:`InputError` if it cannot.

    OpenCV's grayscale decoding converts colour and 16-bit images to 8-bit gray itself.
    """
    import cv2

    size = image_size(data)
    if size is not None and size[0] * size[1] > MAX_IMAGE_PIXELS:
        raise InputError(f"{source}: an image declares {size[0]}x{size[1]} pixels, more than hbvs accepts")
    try:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE) if data else None
    except (cv2.error, SystemError):
        image = None
    if image is None:
        raise InputError(f"{source}: cannot be decoded as an image (corrupt, truncated or not an image)")
    return image


def compressed_image_message(timestamp: dict[str, int], frame_id: str, data: bytes, image_format: str) -> dict[str, Any]:
    """A ``foxglove.CompressedImage`` message (base64 data, as the JSON encoding requires)."""
    return {
        "timestamp": timestamp,
        "frame_id": frame_id,
        "data": base64.b64encode(data).decode("ascii"),
        "format": image_format,
    }


def image_bytes_from_message(message: dict[str, Any], source: str = "") -> tuple[bytes, str]:
    """The compressed bytes and format of a ``foxglove.CompressedImage`` message."""
    try:
        data = base64.b64decode(message["data"], validate=True)
        image_format = str(message.get("format", ""))
    except (KeyError, TypeError, ValueError, binascii.Error):
        raise RecordingError(f"{source}: malformed image message (data must be base64)") from None
    return data, image_format
