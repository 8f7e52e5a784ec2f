"""Frames of a video file."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ...errors import InputError
from ..native_log import opencv_error_text
from .frame_source import FrameSource, SourceFrame, capture_property
from ..images import as_image8


class VideoSource(FrameSource):
    """Frames of a video file (anything ``cv2.VideoCapture`` reads), ``t`` = ``index / fps`` with ``fps``
    given or the container's rate, else ``CAP_PROP_POS_MSEC``."""

    kind = "video"

    def __init__(self, path: str | os.PathLike[str], fps: float | None = None) -> None:
        self.path = str(path)
        self.fps_override = fps  # --fps is checked as an option (finite, at least 0.1 Hz)
        passthrough = "://" in self.path or "%" in self.path
        if not passthrough:
            file = Path(path)
            if not file.exists():
                raise InputError(f"{self.path}: no such file")
            if file.is_dir():
                raise InputError(f"{self.path}: is a directory, expected a video file (use an image folder source for images)")
        capture = self._open()
        try:
            self._container_fps = capture_property(capture, cv2.CAP_PROP_FPS)
            count = capture_property(capture, cv2.CAP_PROP_FRAME_COUNT)
            self.frame_count = int(count) if count is not None else None
            frame = self._read(capture)
            if frame is None:
                raise InputError(f"no frames could be decoded from {self.path}")
            self.width, self.height = int(frame.shape[1]), int(frame.shape[0])
        finally:
            capture.release()

    @property
    def fps(self) -> float | None:
        """The rate used for timestamps, None when they come from the container's clock."""
        if self.fps_override is not None:
            return self.fps_override
        if self._container_fps is not None and self._container_fps < 1000.0:
            # Containers without a real rate report 0, or their time base (e.g. 90000).
            return self._container_fps
        return None

    def _open(self) -> Any:
        try:
            capture = cv2.VideoCapture(self.path)
        except (cv2.error, SystemError) as exc:
            raise InputError(f"{self.path}: cannot open the video ({opencv_error_text(exc)})") from None
        if not capture.isOpened():
            capture.release()
            raise InputError(f"{self.path}: cannot open the video (not a video, or a codec this OpenCV build lacks)")
        return capture

    def _read(self, capture: Any) -> np.ndarray | None:
        """The next frame, None at the end."""
        try:
            ok, frame = capture.read()
        except (cv2.error, SystemError) as exc:
            raise InputError(f"{self.path}: error while decoding the video ({opencv_error_text(exc)})") from None
        return frame if ok and frame is not None and frame.size else None

    def __iter__(self) -> Iterator[SourceFrame]:
        capture = self._open()
        try:
            fps = self.fps
            first_msec: float | None = None
            index = 0
            while True:
                frame = self._read(capture)
                if frame is None:
                    break
                if fps is not None:
                    t = index / fps
                else:
                    msec = float(capture.get(cv2.CAP_PROP_POS_MSEC))
                    first_msec = msec if first_msec is None else first_msec
                    t = (msec - first_msec) / 1000.0
                yield SourceFrame(t=t, image=as_image8(frame, f"{self.path} frame {index}"))
                index += 1
            if index == 0:
                raise InputError(f"no frames could be decoded from {self.path}")
        finally:
            capture.release()

    def describe(self) -> dict[str, Any]:
        """Kind, path, frame count (the container's estimate), fps and image size."""
        timestamps = "fps override" if self.fps_override is not None else "frame rate" if self.fps is not None else "container clock"
        return {
            "kind": self.kind, "path": self.path, "frame_count": self.frame_count, "fps": self.fps, "width": self.width,
            "height": self.height, "timestamps": timestamps,
        }

