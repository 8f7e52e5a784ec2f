"""Perception: detectors of the target's points in camera frames (gray uint8 arrays, OpenCV
pixels: the top-left pixel's centre is (0, 0)); nothing here reads or writes files. Modules: docs/layout.md."""

# Each detector module registers its target kind (.target_kinds) as it is imported, in this order.
from . import dot_windows, aruco, chessboard, charuco, texture  # noqa: F401, I001
from .aruco import ArucoMarkerDetector
from .base import Detection, TargetDetector, match_identity
from .dots import DotDetector
from .target_kinds import TARGET_KINDS, SpecRequest, TargetKind, register_target_kind, target_kind
from .texture import TextureDetection, TextureDetector

__all__ = [
    "ArucoMarkerDetector", "Detection", "DotDetector", "TargetDetector", "TextureDetection", "TextureDetector",
    "match_identity",
    "TARGET_KINDS", "SpecRequest", "TargetKind", "register_target_kind", "target_kind",
]
