"""Perception: detectors of the target's points in camera frames (gray uint8 arrays, OpenCV
pixels: the top-left pixel's centre is (0, 0)); nothing here reads or writes files. Modules: docs/layout.md."""

from .aruco import ArucoMarkerDetector
from .base import Detection, TargetDetector, match_identity
from .detector import guess_target_kind, make_detector
from .dots import DotDetector
from .texture import TextureDetection, TextureDetector

__all__ = [
    "ArucoMarkerDetector", "Detection", "DotDetector", "TargetDetector", "TextureDetection", "TextureDetector",
    "guess_target_kind", "make_detector", "match_identity",
]
