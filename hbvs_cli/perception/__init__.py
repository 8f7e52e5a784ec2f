"""Perception: detectors of the target's points in camera frames.

* :mod:`.base` -- what every detector shares (:class:`Detection`, :class:`TargetDetector`,
  :class:`PointTrack`, :func:`match_identity`);
* :mod:`.dots`, :mod:`.aruco`, :mod:`.texture` -- one detector per target kind;
* :mod:`.detector` -- the factory (:func:`make_detector`) and :func:`guess_target_kind`;
* :mod:`.autodetect` -- ``--target auto``: which target the first frames show;
* :mod:`.tracked` -- the detector as ``fit`` and ``repeat`` use it (:class:`TrackedDetector`,
  re-created from a fit model).

Images are numpy arrays (gray uint8, OpenCV pixels: the top-left pixel's centre is (0, 0));
nothing here reads or writes files.
"""

from .aruco import ArucoMarkerDetector, refine_marker_corners
from .base import Detection, PointTrack, TargetDetector, match_identity
from .detector import guess_target_kind, make_detector
from .dots import DotDetector, find_dark_blobs
from .texture import TextureDetection, TextureDetector
from .tracked import DetectorSpec, TrackedDetector, detector_from_model, estimator_from_model

__all__ = [
    "ArucoMarkerDetector", "Detection", "DetectorSpec", "DotDetector", "PointTrack",
    "TargetDetector", "TextureDetection", "TextureDetector", "TrackedDetector",
    "detector_from_model", "estimator_from_model", "find_dark_blobs", "guess_target_kind",
    "make_detector", "match_identity", "refine_marker_corners",
]
