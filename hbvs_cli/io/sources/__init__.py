"""Frame sources for ``hbvs teach`` (video, image folder, camera, ROS 2 bag): iterables of
:class:`SourceFrame`, one frame at a time; :func:`open_source` picks one."""

from __future__ import annotations

from .frame_source import FrameSource, SourceFrame
from .camera_source import CameraSource
from .factory import SOURCE_KINDS, open_source
from .folder import IMAGE_EXTENSIONS, ImageFolderSource
from .rosbag import BagSource
from .video import VideoSource
