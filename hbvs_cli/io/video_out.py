"""``teach --sim --video-out``: the frames of a simulated drive as a video file, to practise
the walkthrough (docs/walkthrough.md) on footage whose truth is known. Written through a
temporary folder beside the file and renamed into place, as every hbvs output."""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

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


@contextmanager
def video_output(path: Path, fps: float, size: tuple[int, int]) -> Iterator[Callable[[np.ndarray], None]]:
    """A video file at ``path`` (checked first: :func:`check_video_path`) of frames ``size`` (width,
    height, px) at ``fps`` (Hz), written by the yielded function, one uint8 gray (H, W)
    image a call; it appears only when the body succeeds."""
    import cv2

    check_video_path(path)
    final = Path(path).absolute()
    with atomic_folder(final, "video") as temporary:
        writer = cv2.VideoWriter(str(temporary), cv2.VideoWriter_fourcc(*VIDEO_CODECS[final.suffix.lower()]), float(fps),
                                 size, isColor=False)
        if not writer.isOpened():
            raise OutputError(f"--video-out {path}: OpenCV cannot write this video (codec {VIDEO_CODECS[final.suffix.lower()]})")

        def write(image: np.ndarray) -> None:
            if (image.shape[1], image.shape[0]) != size or image.ndim == 3:
                raise OutputError(f"--video-out {Path(path)}: a frame of shape {image.shape} in a video of {size}")
            writer.write(np.ascontiguousarray(image))

        try:
            yield write
        finally:
            writer.release()
