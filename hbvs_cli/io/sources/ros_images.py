"""ROS 2 image messages to 8-bit gray or BGR: raw encodings through ``rosbags-image``,
compressed ones through :func:`hbvs_cli.io.images.decode_image`."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np

from ...errors import InputError
from ..images import as_image8, decode_image, sniff_format


def compressed_to_image8(msg: Any, what: str) -> tuple[np.ndarray, bytes | None, str | None]:
    """Image (gray or BGR), its original bytes (when JPEG or PNG) and their format, of a ``CompressedImage``."""
    data = msg.data if isinstance(msg.data, bytes) else bytes(msg.data)
    image = as_image8(decode_image(data, f"{what} (format {msg.format!r})", colour=True), what)
    fmt = sniff_format(data)
    return image, (data if fmt else None), fmt


def raw_to_image8(msg: Any, what: str) -> np.ndarray:
    """A ``sensor_msgs/msg/Image`` in any encoding rosbags-image reads, as 8-bit gray or BGR
    (16 bits keep their high byte); :class:`InputError` for an unknown encoding or bad sizes."""
    import cv2
    from rosbags.image import ImageError, message_to_cvimage
    from rosbags.image.image import to_cvtype

    encoding = str(msg.encoding)
    try:
        depth, _, _, channels = to_cvtype(encoding)
    except ImageError:
        raise InputError(
            f"{what}: unsupported image encoding {encoding!r} (hbvs reads mono, rgb, bgr, rgba, bgra, "
            "yuv422, yuv422_yuy2 and bayer_* in 8 or 16 bits)"
        ) from None
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    if height <= 0 or width <= 0:
        raise InputError(f"{what}: empty image ({width}x{height})")
    row = width * channels * (depth // 8)
    if depth not in (8, 16) or channels not in (1, 2, 3, 4):
        raise InputError(f"{what}: unsupported image encoding {encoding!r} ({depth}-bit, {channels} channels)")
    if step < row:
        raise InputError(f"{what}: step {step} is shorter than a row of {width} {encoding} pixels")
    data = np.frombuffer(msg.data if isinstance(msg.data, bytes) else bytes(msg.data), dtype=np.uint8)
    if data.size < step * height:
        raise InputError(f"{what}: {data.size} bytes of data, expected {step * height} ({height} rows of {step})")
    # Rows may be padded to `step` bytes: rosbags-image reads unpadded rows only.
    rows = np.ascontiguousarray(data[: step * height].reshape(height, step)[:, :row])
    unpadded = SimpleNamespace(
        encoding=encoding, height=height, width=width, step=row, is_bigendian=int(msg.is_bigendian), data=rows.reshape(-1)
    )
    try:
        if channels == 1 and not encoding.startswith("bayer"):
            image = message_to_cvimage(unpadded)  # mono8/mono16/8UC1/16UC1: no colour to remove
        elif depth == 8:
            image = message_to_cvimage(unpadded, "bgr8")
        else:
            image = message_to_cvimage(unpadded, "bgr16")  # then the high byte, as for mono16
        result = as_image8(np.asarray(image), what)
        if result.ndim == 2 and channels > 1 and depth == 8:
            # No colour in it: the encoding's own luminance (a yuv image's Y, exactly).
            result = as_image8(np.asarray(message_to_cvimage(unpadded, "mono8")), what)
    except (ImageError, ValueError, TypeError, cv2.error) as exc:
        raise InputError(f"{what}: cannot convert the {encoding!r} image ({exc})") from None
    return result
