"""Perception: detectors of the target's points in camera frames (gray uint8 arrays, OpenCV
pixels: the top-left pixel's centre is (0, 0)); nothing here reads or writes files.

* :mod:`.base` -- what every detector shares (:class:`Detection`, :class:`TargetDetector`,
  :class:`PointTrack`, :func:`match_identity`);
* :mod:`.dots`, :mod:`.aruco`, :mod:`.chessboard`, :mod:`.charuco`, :mod:`.texture` -- one
  detector per target kind; :mod:`.detector` -- the factory (:func:`make_detector`);
* :mod:`.autodetect` -- ``--target auto``; :mod:`.tracked` -- the detector of ``fit`` and ``repeat``.
"""

from .aruco import ArucoMarkerDetector
from .base import Detection, TargetDetector, match_identity
from .detector import guess_target_kind, make_detector
from .dots import DotDetector
from .texture import TextureDetection, TextureDetector

__all__ = [
    "ArucoMarkerDetector", "Detection", "DotDetector", "TargetDetector", "TextureDetection", "TextureDetector",
    "guess_target_kind", "make_detector", "match_identity",
]
