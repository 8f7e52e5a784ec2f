"""The newest frame of an OpenCV camera for a live loop (``repeat --live --camera DEV``), older ones
counted as dropped, never queued; a video file is played at its own rate to stand in for a camera."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import cv2
import numpy as np

from ...errors import InputError
from .. import ClosedOnExit
from .frame_source import LiveFrame
from ..images import as_image8


class LatestCameraFrame(ClosedOnExit):
    """Frames of ``cv2.VideoCapture(device)`` (an index, ``/dev/videoN``, a URL or a video file), newest only."""

    def __init__(self, device: str) -> None:
        self.device = device
        self._capture = cv2.VideoCapture(int(device) if device.isdigit() else device)
        if not self._capture.isOpened():
            raise InputError(f"--camera {device}: cannot open it (no such device, or OpenCV cannot read it)")
        fps = float(self._capture.get(cv2.CAP_PROP_FPS) or 0.0)
        # A video file (not a device index, URL or /dev node) is played at its own rate.
        is_file = (not device.isdigit() and "://" not in device and not device.startswith("/dev/")
                   and Path(device).is_file())
        self._pace = 1.0 / fps if is_file and 0 < fps < 1000 else None
        self._lock = threading.Condition()
        self._latest: LiveFrame | None = None
        self._unread = 0
        self._ended = False
        self._error: str | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read, name="hbvs-camera", daemon=True)
        self._thread.start()

    def _read(self) -> None:
        start = time.monotonic()
        count = 0
        failures = 0
        while not self._stop.is_set():
            if self._pace is not None:
                delay = start + count * self._pace - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            ok, image = self._capture.read()
            if not ok or image is None:
                failures += 1
                if self._pace is not None or failures > 30:
                    break
                continue
            failures = 0
            count += 1
            try:
                image8 = as_image8(np.asarray(image), f"--camera {self.device}")
            except InputError as exc:
                with self._lock:
                    self._error = str(exc)
                    self._lock.notify_all()
                return
            frame = LiveFrame(image=image8, stamp=time.time(), arrival=time.monotonic(), skipped=0)
            with self._lock:
                if self._latest is not None:
                    self._unread += 1
                self._latest = frame
                self._lock.notify_all()
        with self._lock:
            self._ended = True
            self._lock.notify_all()

    @property
    def ended(self) -> bool:
        """The source has no more frames (the end of a video file, or a device that failed)."""
        with self._lock:
            return self._ended and self._latest is None

    def latest(self, timeout_s: float) -> LiveFrame | None:
        """The newest frame, waiting up to ``timeout_s`` for one; None when none came."""
        with self._lock:
            if self._latest is None and not self._ended and self._error is None:
                self._lock.wait(max(timeout_s, 0.0))
            if self._error is not None:
                raise InputError(self._error)
            frame, self._latest = self._latest, None
            if frame is None:
                return None
            frame.skipped, self._unread = self._unread, 0
            return frame

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        self._capture.release()
