"""Frame sources for ``hbvs teach`` (video, image folder, camera, ROS 2 bag): iterables of
:class:`SourceFrame`, one frame at a time; :func:`open_source` picks one."""

from __future__ import annotations

import os
from typing import Any

from .frame_source import FrameSource, SourceFrame
from .camera_source import CameraSource
from .folder import IMAGE_EXTENSIONS, ImageFolderSource
from .rosbag import BagSource
from .video import VideoSource

__all__ = [
    "SourceFrame", "FrameSource", "VideoSource", "ImageFolderSource", "CameraSource", "BagSource", "IMAGE_EXTENSIONS",
    "open_source",
]


def open_source(
    kind: str, spec: str | int | os.PathLike[str], *, fps: float | None = None, duration: float | None = None,
    topic: str | None = None, cmd_topic: str | None = None,
) -> FrameSource:
    """The source of ``kind`` (video, images, camera or bag: the teach option that names it) on ``spec``
    (a path, glob, device index or bag): ``fps`` for videos and image folders, ``duration`` for cameras,
    ``topic`` and ``cmd_topic`` for bags."""
    openers: dict[str, Any] = {
        "video": lambda: VideoSource(spec, fps=fps), "images": lambda: ImageFolderSource(spec, fps=fps),
        "camera": lambda: CameraSource(spec, duration=duration),
        "bag": lambda: BagSource(spec, topic=topic, cmd_topic=cmd_topic),
    }
    return openers[kind]()
