"""``teach --sim --video-out``: the frames of a simulated drive as a video file, to practise
the walkthrough (docs/walkthrough.md) on footage whose truth is known. Written through a
temporary folder beside the file and renamed into place, as every hbvs output."""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from ..errors import OutputError, UsageError
from .output_target import atomic_folder

#: The codec of each container hbvs writes (OpenCV picks the container from the suffix).
VIDEO_CODECS = {".avi": "MJPG", ".mkv": "MJPG", ".mp4": "mp4v", ".mov": "mp4v"}


def check_video_path(path: Path) -> None:
    """UsageError for a suffix hbvs does not write, OutputError for a missing folder, before any work."""
    if Path(path).suffix.lower() not in VIDEO_CODECS:
        raise UsageError(f"--video-out {path}: write one of {', '.join(VIDEO_CODECS)} (the suffix picks the container)")
    if not Path(path).absolute().parent.is_dir():
        raise OutputError(f"--video-out {path}: the folder {Path(path).absolute().parent} does not exist")


class _Frames:
    """What :func:`video_output` yields: ``write(image)`` for each frame, uint8 gray (H, W)."""

    def __init__(self, writer: Any, size: tuple[int, int], name: Path) -> None:
        self._writer, self._size, self._name = writer, size, name

    def write(self, image: np.ndarray) -> None:
        if (image.shape[1], image.shape[0]) != self._size or image.ndim == 3:
            raise OutputError(f"--video-out {self._name}: a frame of shape {image.shape} in a video of {self._size}")
        self._writer.write(np.ascontiguousarray(image))


@contextmanager
def video_output(path: Path, fps: float, size: tuple[int, int]) -> Iterator[_Frames]:
    """A video file at ``path`` (suffix: :data:`VIDEO_CODECS`) of frames ``size`` (width,
    height, px) at ``fps`` (Hz); it appears only when the body succeeds."""
    import cv2

    final = Path(path).absolute()  # its suffix and folder checked by check_video_path, before the drive
    with atomic_folder(final, "video") as temporary:
        writer = cv2.VideoWriter(str(temporary), cv2.VideoWriter_fourcc(*VIDEO_CODECS[final.suffix.lower()]), float(fps),
                                 size, isColor=False)
        if not writer.isOpened():
            raise OutputError(f"--video-out {path}: OpenCV cannot write this video (codec {VIDEO_CODECS[final.suffix.lower()]})")
        try:
            yield _Frames(writer, size, Path(path))
        finally:
            writer.release()
