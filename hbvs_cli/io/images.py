"""Image bytes <-> 8-bit arrays (gray or BGR), and the ``foxglove.CompressedImage`` around them;
headers that declare more pixels than the data can hold are refused before OpenCV allocates them."""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..core.grayscale import as_gray
from ..errors import InputError, RecordingError
from .messages import stamp, stamp_ns
from .topics import COMPRESSED_IMAGE_SCHEMA

IMAGE_FORMATS = ("png", "jpeg")
#: ``--format`` choices: ``auto`` keeps what a source has and compresses the rest as JPEG.
STORE_FORMATS = ("auto", *IMAGE_FORMATS)
#: JPEG quality of the frames hbvs compresses itself (bench/FILE_SIZES.md).
DEFAULT_JPEG_QUALITY = 90
#: Largest difference between a pixel's channels (levels) in a frame taken as gray (OpenCV's
#: MJPG writer puts a gray frame's channels 2 levels apart).
NEUTRAL_SPREAD = 3
#: Largest decoded image accepted (pixels): 8K x 8K.
MAX_IMAGE_PIXELS = 8192 * 8192


def encode_image(image: NDArray[np.uint8], image_format: str = "png", jpeg_quality: int = DEFAULT_JPEG_QUALITY) -> bytes:
    """Compress an 8-bit gray (H, W) or BGR (H, W, 3) image to PNG (lossless) or JPEG, keeping
    its channels (BGRA loses its alpha); the format and ``jpeg_quality`` (1-100) were checked as options."""
    import cv2

    if image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    # Sensor noise defeats LZ matching: Huffman-only PNG is both smaller and faster here.
    png = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY]
    # Optimised Huffman tables: a few per cent smaller at the same quality.
    jpeg = [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality), cv2.IMWRITE_JPEG_OPTIMIZE, 1]
    params = jpeg if image_format == "jpeg" else png
    ok, buffer = cv2.imencode(".png" if image_format == "png" else ".jpg", image, params)
    if not ok:  # pragma: no cover - OpenCV encodes any uint8 image
        raise RecordingError("OpenCV could not encode an image")
    return buffer.tobytes()


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
JPEG_SIGNATURE = b"\xff\xd8\xff"
#: Most pixels a byte of compressed data can hold, by the file's first two bytes. Deflate
#: expands at most 1032:1 and a 1-bit PNG packs 8 pixels a byte; a JPEG spends a few bits
#: at least on every 8x8 block, even with progressive end-of-band runs.
_MAX_PIXELS_PER_BYTE = {PNG_SIGNATURE[:2]: 8 * 1100, JPEG_SIGNATURE[:2]: 1 << 14}
#: JPEG start-of-frame markers (C4, C8 and CC are not frames), and markers without a length.
_JPEG_FRAME_MARKERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
_JPEG_BARE_MARKERS = frozenset(range(0xD0, 0xDA)) | {0x01}


def image_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) from a PNG, JPEG or BMP header without decoding, else None."""
    if data[:8] == PNG_SIGNATURE and len(data) >= 24:
        return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    if data[:2] == JPEG_SIGNATURE[:2]:
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


#: Bytes of a PNG chunk checksummed per call: CPython's zlib lets go of the GIL above 5 KiB, and
#: taking it back each time (17 chunks a frame) cost the fit's decoding thread more than the sums.
CRC_PIECE_BYTES = 4096


def _png_problem(data: bytes) -> str | None:
    """What is wrong with a PNG's chunks (lengths, CRCs, end), if anything: OpenCV trusts them."""
    view = memoryview(data)
    offset = len(PNG_SIGNATURE)
    while offset + 12 <= len(data):
        length = int.from_bytes(view[offset:offset + 4], "big")
        end = offset + 12 + length
        kind = bytes(view[offset + 4:offset + 8])
        if end > len(data):
            return f"a {kind!r} chunk runs past the end of the data"
        crc = 0
        for start in range(offset + 4, end - 4, CRC_PIECE_BYTES):
            crc = zlib.crc32(view[start:min(start + CRC_PIECE_BYTES, end - 4)], crc)
        if crc != int.from_bytes(view[end - 4:end], "big"):
            return f"a {kind!r} chunk fails its CRC check"
        if kind == b"IEND":
            return None
        offset = end
    return "the data ends before the PNG's end chunk"


def decode_image(data: bytes, source: str = "", colour: bool = False) -> NDArray[np.uint8]:
    """Decode any image OpenCV reads to 8-bit gray (H, W), or with ``colour`` a colour one to BGR (H, W, 3)."""
    import cv2

    size = image_size(data)
    if size is not None and size[0] * size[1] > MAX_IMAGE_PIXELS:
        raise InputError(f"{source}: an image declares {size[0]}x{size[1]} pixels, more than hbvs accepts")
    density = _MAX_PIXELS_PER_BYTE.get(data[:2])
    if size is not None and density is not None and size[0] * size[1] > density * len(data):
        raise InputError(
            f"{source}: cannot be decoded as an image ({len(data)} bytes cannot hold the "
            f"{size[0]}x{size[1]} pixels its header declares: corrupt or truncated)"
        )
    problem = _png_problem(data) if data[:8] == PNG_SIGNATURE else None
    if problem is not None:
        raise InputError(f"{source}: cannot be decoded as an image ({problem}: corrupt or truncated)")
    from .native_log import mark, said_since

    before = mark()
    try:
        mode = cv2.IMREAD_ANYCOLOR if colour else cv2.IMREAD_GRAYSCALE
        image = cv2.imdecode(np.frombuffer(data, np.uint8), mode) if data else None
    except (cv2.error, SystemError):
        image = None
    if image is None:
        said = said_since(before)
        raise InputError(f"{source}: cannot be decoded as an image ({said + ': ' if said else ''}corrupt, truncated or not an image)")
    return image


def is_png8(data: bytes, colour: bool = False) -> bool:
    """True for a PNG of 8-bit gray pixels (colour type 0), or with ``colour`` of RGB ones (type 2: no
    alpha, no palette), read from its header."""
    return data[:8] == PNG_SIGNATURE and len(data) >= 26 and data[24] == 8 and data[25] == (2 if colour else 0)


def sniff_format(data: bytes) -> str | None:
    """"jpeg" or "png" from the magic bytes (file names and ROS format strings may lie), else None."""
    if data.startswith(JPEG_SIGNATURE):
        return "jpeg"
    if data.startswith(PNG_SIGNATURE):
        return "png"
    return None


def as_image8(image: Any, what: str = "the camera frame") -> NDArray[np.uint8]:
    """An image as contiguous uint8 gray (H, W) or BGR (H, W, 3); a colour image whose channels
    differ nowhere by more than :data:`NEUTRAL_SPREAD` becomes gray. :class:`InputError` otherwise."""
    import cv2

    if not isinstance(image, np.ndarray) or image.ndim != 3 or image.shape[2] not in (3, 4):
        return as_gray(image, what)
    if image.dtype == np.uint16:
        image = (image >> 8).astype(np.uint8)
    elif image.dtype != np.uint8:
        raise InputError(f"{what}: unsupported pixel type {image.dtype} (8- or 16-bit images only)")
    if image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    blue, green, red = cv2.split(image)
    spread = cv2.subtract(cv2.max(cv2.max(blue, green), red), cv2.min(cv2.min(blue, green), red))
    if int(spread.max()) <= NEUTRAL_SPREAD:
        return as_gray(image, what)
    return np.ascontiguousarray(image)


def bytes_to_store(
    image: NDArray[np.uint8], encoded: bytes | None = None, encoded_format: str | None = None,
    image_format: str = "auto", jpeg_quality: int = DEFAULT_JPEG_QUALITY, gray: bool = False,
) -> tuple[bytes, str]:
    """The bytes and format a recording stores for ``image`` (gray (H, W) or BGR (H, W, 3) uint8),
    ``encoded`` the source's own bytes: ``auto`` keeps a JPEG and an 8-bit PNG of the image's channels,
    re-encodes other PNGs and compresses the rest as JPEG; ``gray`` stores the luminance only."""
    colour = image.ndim == 3
    if gray and colour:
        image, colour = as_gray(image), False
        if encoded_format == "jpeg":
            encoded = None  # a colour JPEG: its luminance is encoded again
    if encoded is not None and encoded_format == "jpeg" and image_format in ("auto", "jpeg"):
        return encoded, "jpeg"
    if encoded is not None and encoded_format == "png" and image_format in ("auto", "png"):
        kept = is_png8(encoded, colour)
        return (encoded if kept else encode_image(image, "png")), "png"
    chosen = "jpeg" if image_format == "auto" and encoded is None else image_format
    chosen = "png" if chosen == "auto" else chosen
    return encode_image(image, chosen, jpeg_quality), chosen


@dataclass(frozen=True)
class StoredImage:
    """One ``foxglove.CompressedImage`` as read from a file (``stamp_ns``: its own stamp, ns)."""

    data: bytes
    format: str
    stamp_ns: int


def compressed_image_message(stamp_ns: int, data: bytes, image_format: str, frame_id: str = "camera") -> Any:
    """A ``foxglove.CompressedImage`` (protobuf: the bytes as they are) stamped ``stamp_ns``."""
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage

    return CompressedImage(timestamp=stamp(stamp_ns), frame_id=frame_id, data=bytes(data), format=image_format)


def write_compressed_image(writer: Any, topic: str, log_time_ns: int, data: bytes, image_format: str, frame_id: str = "camera") -> None:
    """Write one ``foxglove.CompressedImage`` on an :class:`~hbvs_cli.io.mcap.McapWriter`, stamped with its log time."""
    writer.write(topic, COMPRESSED_IMAGE_SCHEMA, log_time_ns, compressed_image_message(log_time_ns, data, image_format, frame_id))


def read_compressed_image(data: bytes, source: str = "") -> StoredImage:
    """A ``foxglove.CompressedImage`` from its protobuf bytes; :class:`RecordingError` if it does not parse."""
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
    from google.protobuf.message import DecodeError

    try:
        message = CompressedImage.FromString(data)
    except (DecodeError, ValueError, RuntimeError):
        raise RecordingError(f"{source}: malformed image message (not a protobuf foxglove.CompressedImage)") from None
    return StoredImage(data=bytes(message.data), format=message.format, stamp_ns=max(stamp_ns(message.timestamp), 0))
