"""Perception: synthetic camera frames of the target, and detectors of its points.

* :mod:`.poster` -- the target's picture as a raster with an anti-aliasing pyramid;
* :mod:`.render` -- camera frames of the poster from a robot pose (exposure, blur, noise,
  lens distortion);
* :mod:`.detector` -- the detector interface (:class:`Detection`, :class:`TargetDetector`,
  :func:`make_detector`, :func:`guess_target_kind`, :func:`match_identity`);
* :mod:`.dots`, :mod:`.aruco`, :mod:`.texture` -- one detector per target kind.

Images are numpy arrays (gray uint8, OpenCV pixel convention: the centre of the top-left
pixel is (0, 0)); nothing here reads or writes files.
"""

from .aruco import ArucoMarkerDetector, refine_marker_corners
from .detector import Detection, PointTrack, TargetDetector, guess_target_kind, make_detector, match_identity
from .dots import DotDetector, find_dark_blobs
from .poster import PosterRaster
from .render import RenderSettings, SceneRenderer
from .texture import TextureDetection, TextureDetector

__all__ = [
    "ArucoMarkerDetector",
    "Detection",
    "DotDetector",
    "PointTrack",
    "PosterRaster",
    "RenderSettings",
    "SceneRenderer",
    "TargetDetector",
    "TextureDetection",
    "TextureDetector",
    "find_dark_blobs",
    "guess_target_kind",
    "make_detector",
    "match_identity",
    "refine_marker_corners",
]
