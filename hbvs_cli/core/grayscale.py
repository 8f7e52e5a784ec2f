"""Camera frames as gray arrays, the form every detector and the renderer's texture take."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import NotAnImageError


def as_gray(image: Any, what: str = "the camera frame") -> NDArray[np.uint8]:
    """An image as a contiguous gray uint8 array, shape (H, W).

    Gray, BGR or BGRA, 8 or 16 bits; 16-bit data keeps its high byte (a fixed scale, so
    brightness does not change between frames). NotAnImageError names the image ``what``.
    """
    import cv2

    if not isinstance(image, np.ndarray) or image.size == 0:
        raise NotAnImageError(f"{what}: empty or not an image array")
    if image.dtype == np.uint16:
        image = (image >> 8).astype(np.uint8)
    elif image.dtype != np.uint8:
        raise NotAnImageError(f"{what}: unsupported pixel type {image.dtype} (8- or 16-bit images only)")
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    elif image.ndim == 3 and image.shape[2] in (3, 4):
        image = cv2.cvtColor(image, {3: cv2.COLOR_BGR2GRAY, 4: cv2.COLOR_BGRA2GRAY}[image.shape[2]])
    elif image.ndim != 2:
        raise NotAnImageError(f"{what}: unsupported image shape {image.shape}")
    return np.ascontiguousarray(image)
