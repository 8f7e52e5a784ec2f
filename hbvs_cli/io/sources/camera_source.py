"""A live camera."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from typing import Any

import cv2
import numpy as np

from ...errors import InputError, UsageError
from .. import ClosedOnExit
from ..native_log import opencv_error_text
from .frame_source import FrameSource, SourceFrame, capture_property
from ..images import as_image8


class CameraSource(FrameSource, ClosedOnExit):
    """A live camera (``index``: a device number or an OpenCV path/URL), timestamped with ``clock`` (s)
    from the first frame, until ``duration`` s; opened here, so that a missing camera is reported
    before anything is recorded."""

    kind = "camera"

    def __init__(
        self, index: int | str, duration: float | None = None, capture_factory: Callable[[Any], Any] = cv2.VideoCapture,
        clock: Callable[[], float] = time.monotonic, max_failed_reads: int = 5,
    ) -> None:
        self.index = index
        if duration is not None and not 0.0 < duration < math.inf:  # the option allows 0, a camera records something
            raise UsageError(f"--duration must be a positive number, got {duration!r}")
        self.duration = duration
        self._factory = capture_factory
        self._clock = clock
        self.max_failed_reads = int(max_failed_reads)
        self._capture: Any = self._open()
        self.fps = capture_property(self._capture, cv2.CAP_PROP_FPS)
        width = capture_property(self._capture, cv2.CAP_PROP_FRAME_WIDTH)
        height = capture_property(self._capture, cv2.CAP_PROP_FRAME_HEIGHT)
        self.width = int(width) if width else None
        self.height = int(height) if height else None

    def _open(self) -> Any:
        try:
            capture = self._factory(self.index)
        except (cv2.error, SystemError, OSError) as exc:
            raise InputError(f"camera {self.index}: cannot open the device ({opencv_error_text(exc)})") from None
        if not capture.isOpened():
            capture.release()
            raise InputError(f"camera {self.index}: cannot open the device (is it connected and not in use by another program?)")
        return capture

    def close(self) -> None:
        """Release the device if it is still held (it is after construction)."""
        if self._capture is not None:
            self._capture.release()
            self._capture = None

    def __iter__(self) -> Iterator[SourceFrame]:
        # Take over the capture opened by the constructor; a second iteration reopens.
        capture = self._capture if self._capture is not None else self._open()
        self._capture = None
        try:
            first: float | None = None
            count = 0
            failures = 0
            while True:
                try:
                    ok, frame = capture.read()
                except (cv2.error, SystemError) as exc:
                    raise InputError(f"camera {self.index}: read failed ({opencv_error_text(exc)})") from None
                now = float(self._clock())
                if not ok or frame is None or getattr(frame, "size", 0) == 0:
                    failures += 1
                    if failures > self.max_failed_reads:
                        if count == 0:
                            raise InputError(f"camera {self.index}: the device opened but delivered no frames")
                        raise InputError(f"camera {self.index}: stopped delivering frames after {count} frames")
                    continue
                failures = 0
                if first is None:
                    first = now
                t = now - first
                if self.duration is not None and t >= self.duration:
                    return
                yield SourceFrame(t=t, image=as_image8(np.asarray(frame), f"camera {self.index}"))
                count += 1
        finally:
            capture.release()

    def describe(self) -> dict[str, Any]:
        """Kind, device, fps reported by the driver, requested duration, image size."""
        return {
            "kind": self.kind, "path": None, "device": self.index, "frame_count": None, "fps": self.fps,
            "duration": self.duration, "width": self.width, "height": self.height,
        }

