"""Image bytes <-> arrays, and the ``foxglove.CompressedImage`` message around them."""

from __future__ import annotations

import base64
import binascii
import zlib
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


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: Most pixels a byte of compressed data can hold, by the file's first two bytes. Deflate
#: expands at most 1032:1 and a 1-bit PNG packs 8 pixels a byte; a JPEG spends a few bits
#: at least on every 8x8 block, even with progressive end-of-band runs.
_MAX_PIXELS_PER_BYTE = {b"\x89P": 8 * 1100, b"\xff\xd8": 1 << 14}
#: JPEG start-of-frame markers, which carry the image size (C4, C8 and CC are not frames).
_JPEG_FRAME_MARKERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
#: JPEG markers that stand alone, without a length field.
_JPEG_BARE_MARKERS = frozenset(range(0xD0, 0xDA)) | {0x01}


def image_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) read from a PNG, JPEG or BMP header without decoding, when available.

    Decoders allocate the whole image from these numbers before reading any pixel, so a
    few hostile bytes could ask for gigabytes; other formats rely on OpenCV's own cap.
    """
    if data[:8] == _PNG_SIGNATURE and len(data) >= 24:
        return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    if data[:2] == b"\xff\xd8":
        return _jpeg_size(data)
    if data[:2] == b"BM" and len(data) >= 26:
        width = int.from_bytes(data[18:22], "little", signed=True)
        height = int.from_bytes(data[22:26], "little", signed=True)
        return abs(width), abs(height)  # a negative height means rows stored top-down
    return None


def _jpeg_size(data: bytes) -> tuple[int, int] | None:
    """The size in a JPEG's start-of-frame segment (walking the segments before it)."""
    offset = 2
    while offset + 4 <= len(data):
        if data[offset] != 0xFF:
            return None
        marker = data[offset + 1]
        if marker == 0xFF:  # fill byte
            offset += 1
            continue
        if marker in _JPEG_BARE_MARKERS:
            offset += 2
            continue
        if marker in _JPEG_FRAME_MARKERS:
            if offset + 9 > len(data):
                return None
            return int.from_bytes(data[offset + 7:offset + 9], "big"), int.from_bytes(data[offset + 5:offset + 7], "big")
        if marker == 0xDA:  # scan data before any frame header: let the decoder refuse it
            return None
        offset += 2 + int.from_bytes(data[offset + 2:offset + 4], "big")
    return None


def _png_problem(data: bytes) -> str | None:
    """What is wrong with a PNG's chunk structure (lengths, CRCs, the end chunk), if anything.

    OpenCV's PNG reader trusts chunk lengths: a damaged one declaring gigabytes costs
    seconds and as much memory before the decode fails, so PNGs are walked here first.
    """
    offset = len(_PNG_SIGNATURE)
    while offset + 12 <= len(data):
        length = int.from_bytes(data[offset:offset + 4], "big")
        end = offset + 12 + length
        if end > len(data):
            return f"a {data[offset + 4:offset + 8]!r} chunk runs past the end of the data"
        if zlib.crc32(data[offset + 4:end - 4]) != int.from_bytes(data[end - 4:end], "big"):
            return f"a {data[offset + 4:offset + 8]!r} chunk fails its CRC check"
        if data[offset + 4:offset + 8] == b"IEND":
            return None
        offset = end
    return "the data ends before the PNG's end chunk"


def decode_image(data: bytes, source: str = "") -> NDArray[np.uint8]:
    """Decode PNG/JPEG (any image OpenCV reads) to 8-bit gray; :class:`InputError` if it cannot.

    OpenCV's grayscale decoding converts colour and 16-bit images to 8-bit gray itself.
    """
    import cv2

    size = image_size(data)
    if size is not None and size[0] * size[1] > MAX_IMAGE_PIXELS:
        raise InputError(f"{source}: an image declares {size[0]}x{size[1]} pixels, more than hbvs accepts")
    density = _MAX_PIXELS_PER_BYTE.get(data[:2])
    if size is not None and density is not None and size[0] * size[1] > density * len(data):
        # Decoders allocate and walk every declared row even when the data runs out, so
        # a few damaged bytes would cost seconds and megabytes before failing anyway.
        raise InputError(
            f"{source}: cannot be decoded as an image ({len(data)} bytes cannot hold the "
            f"{size[0]}x{size[1]} pixels its header declares: corrupt or truncated)"
        )
    problem = _png_problem(data) if data[:8] == _PNG_SIGNATURE else None
    if problem is not None:
        raise InputError(f"{source}: cannot be decoded as an image ({problem}: corrupt or truncated)")
    from .native_log import mark, said_since

    before = mark()
    try:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE) if data else None
    except (cv2.error, SystemError):
        image = None
    if image is None:
        said = said_since(before)
        raise InputError(f"{source}: cannot be decoded as an image ({said + ': ' if said else ''}corrupt, truncated or not an image)")
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
