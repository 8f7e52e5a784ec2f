"""What every frame source shares: the frame type, the base class and small checks."""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...core.camera import CameraIntrinsics
from ...errors import InputError

_NS = 1_000_000_000


@dataclass(frozen=True)
class SourceFrame:
    """One frame from a source: ``t`` (s) from the first; ``image`` uint8 gray (H, W) or BGR (H, W, 3);
    ``encoded`` the source's own JPEG/PNG bytes; ``command`` the operator's (v, w) (m/s, rad/s)."""

    t: float
    image: np.ndarray
    encoded: bytes | None = None
    format: str | None = None
    stamp_ns: int | None = None
    command: tuple[float, float] | None = None


@dataclass
class LiveFrame:
    """One camera frame of a live loop (``repeat --live``) as it arrived: ``image`` (H, W) or (H, W, 3)
    uint8; ``stamp`` its header stamp (s) or arrival; ``arrival`` (s, ``time.monotonic()``): its publication
    when on this host's clock, else when hbvs took it; ``skipped`` frames dropped since the previous one."""

    image: np.ndarray
    stamp: float
    arrival: float
    skipped: int


class FrameSource:
    """Base of the frame sources, iterables of :class:`SourceFrame`; ``camera``: intrinsics the source carries."""

    kind: str = "source"
    camera: CameraIntrinsics | None = None

    def __iter__(self) -> Iterator[SourceFrame]:  # pragma: no cover - abstract
        raise NotImplementedError

    def describe(self) -> dict[str, Any]:  # pragma: no cover - abstract
        """JSON-ready description for the recording's metadata."""
        raise NotImplementedError

    @property
    def image_size(self) -> tuple[int, int] | None:
        """(width, height) of the frames when known before iterating (for a calibration without one)."""
        width, height = getattr(self, "width", None), getattr(self, "height", None)
        return (int(width), int(height)) if width and height else None


def capture_property(capture: Any, prop: int) -> float | None:
    """A ``cv2.VideoCapture`` property when finite and positive (drivers report 0 for unknown), else None."""
    import cv2

    try:
        value = float(capture.get(prop))
    except (cv2.error, SystemError, AttributeError, TypeError, ValueError):
        return None
    return value if math.isfinite(value) and value > 0 else None


def _natural_key(text: str) -> tuple[Any, ...]:
    """Sort key that orders embedded numbers by value: frame2 before frame10."""
    # Text and numbers alternate, so two names' parts always compare; the name breaks ties.
    parts = re.split(r"(\d+)", text)
    return tuple(int(p) if i % 2 else p.lower() for i, p in enumerate(parts)), text


def _same_size(size: tuple[int, int] | None, image: np.ndarray, what: str) -> tuple[int, int]:
    """The size of the first frame; later frames of another size are refused."""
    current = (int(image.shape[1]), int(image.shape[0]))
    if size is not None and current != size:
        raise InputError(
            f"{what}: image is {current[0]}x{current[1]} but earlier frames are {size[0]}x{size[1]}; "
            "all frames must have the same size"
        )
    return current

