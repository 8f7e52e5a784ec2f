"""Frame sources for ``hbvs teach``: video files, image folders, live cameras, ROS 2 bags.

Every source is an iterable of :class:`SourceFrame` (8-bit grayscale image plus a time
in seconds from the first frame) produced lazily, one frame at a time, so a long video
or bag never sits in memory. Each source also offers :meth:`FrameSource.describe` for
the recording's metadata and a ``camera`` attribute holding intrinsics found in the
source itself (only bags carry them, in a ``CameraInfo`` topic).

Conversion to 8 bits is the same everywhere: colour goes through ``cv2.cvtColor`` and
16-bit data keeps its high byte (a fixed scale, so the brightness of a scene does not
change from frame to frame as a per-frame stretch would).

One module per kind of source: :mod:`.base` (:class:`SourceFrame`, :class:`FrameSource`),
:mod:`.video`, :mod:`.folder`, :mod:`.camera`, :mod:`.rosbag` (with :mod:`.bag_storage` and
:mod:`.ros_images`) and :func:`open_source` in :mod:`.factory`; every public name is
re-exported here.
"""

from __future__ import annotations

from .frame_source import FrameSource, SourceFrame, to_image8
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
    "to_image8",
    "open_source",
    "SOURCE_KINDS",
]
