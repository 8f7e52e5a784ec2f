"""Frame sources for ``hbvs teach``: video files (:mod:`.video`), image folders
(:mod:`.folder`), live cameras (:mod:`.camera_source`) and ROS 2 bags (:mod:`.rosbag`), each an
iterable of :class:`SourceFrame` read one frame at a time, with :meth:`FrameSource.describe`
for the metadata and a ``camera`` attribute for intrinsics the source carries (bags).
:func:`open_source` picks one; every public name is re-exported here.
"""

from __future__ import annotations

from .frame_source import FrameSource, SourceFrame
from .camera_source import CameraSource
from .factory import SOURCE_KINDS, open_source
from .folder import IMAGE_EXTENSIONS, ImageFolderSource
from .rosbag import BagSource
from .video import VideoSource

__all__ = [
    "SourceFrame",
    "FrameSource",
    "VideoSource",
    "ImageFolderSource",
    "CameraSource",
    "BagSource",
    "IMAGE_EXTENSIONS",
    "open_source",
    "SOURCE_KINDS",
]
