"""What every frame source shares: the frame type, the base class and small checks."""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...core.camera import CameraIntrinsics
from ...errors import InputError, UsageError
from ..images import as_image8

_NS = 1_000_000_000


@dataclass(frozen=True)
class SourceFrame:
    """One frame from a source.

    Attributes
    ----------
    t : float
        Seconds from the source's first frame.
    image : ndarray of uint8, shape (H, W) or (H, W, 3)
        Gray, or BGR when the source has colour (:func:`hbvs_cli.io.images.as_image8`).
    encoded, format : bytes and "jpeg"/"png", or None
        The source's own compressed bytes, stored without re-encoding.
    stamp_ns : int or None
        The frame's stamp on the source's clock (ns), when it has one.
    command : (v, w) or None
        The operator's command at this frame (m/s, rad/s), when recorded.
    """

    t: float
    image: np.ndarray
    encoded: bytes | None = None
    format: str | None = None
    stamp_ns: int | None = None
    command: tuple[float, float] | None = None


class FrameSource:
    """Base of the frame sources: iterate it for :class:`SourceFrame` objects.

    Attributes
    ----------
    kind : str
        Short name of the source type, as in :meth:`describe`.
    camera : CameraIntrinsics or None
        Intrinsics found in the source itself, None when it has none.
    """

    kind: str = "source"
    camera: CameraIntrinsics | None = None

    def __iter__(self) -> Iterator[SourceFrame]:  # pragma: no cover - abstract
        raise NotImplementedError

    def describe(self) -> dict[str, Any]:  # pragma: no cover - abstract
        """JSON-ready description for the recording's metadata."""
        raise NotImplementedError

    @property
    def image_size(self) -> tuple[int, int] | None:
        """(width, height) of the frames when known before iterating (for a calibration
        file that gives no size), else None."""
        width, height = getattr(self, "width", None), getattr(self, "height", None)
        return (int(width), int(height)) if width and height else None



# ----------------------------------------------------------------------------- helpers
def to_image8(image: np.ndarray, what: str) -> np.ndarray:
    """A decoded frame as contiguous 8 bits, gray or BGR as it has colour or not (see
    :func:`hbvs_cli.io.images.as_image8`)."""
    return as_image8(image, what)


def _cv_message(exc: BaseException) -> str:
    cause = exc.__cause__ if exc.__cause__ is not None else exc
    message = " ".join(str(cause).split())
    return message.split("error: ", 1)[1] if "error: " in message else message


def _natural_key(text: str) -> tuple[Any, ...]:
    """Sort key that orders embedded numbers by value: frame2 before frame10."""
    # re.split with a capturing group alternates text, number, text...: the types line up
    # position by position, so the part tuples of two names always compare; the name
    # itself breaks ties ("a01" vs "a1").
    parts = re.split(r"(\d+)", text)
    return tuple(int(p) if i % 2 else p.lower() for i, p in enumerate(parts)), text


def _check_rate(value: float | None, what: str) -> float | None:
    if value is None:
        return None
    try:
        rate = float(value)
    except (TypeError, ValueError):
        raise UsageError(f"{what} must be a number, got {value!r}") from None
    if not math.isfinite(rate) or rate <= 0:
        raise UsageError(f"{what} must be a positive number, got {value!r}")
    return rate


def _same_size(size: tuple[int, int] | None, image: np.ndarray, what: str) -> tuple[int, int]:
    """The size of the first frame; later frames of another size are refused."""
    current = (int(image.shape[1]), int(image.shape[0]))
    if size is not None and current != size:
        raise InputError(
            f"{what}: image is {current[0]}x{current[1]} but earlier frames are {size[0]}x{size[1]}; "
            "all frames must have the same size"
        )
    return current

