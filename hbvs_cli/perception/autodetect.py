"""``--target auto``'s candidates: each kind of target found in most of a recording's first frames, ordered by
the precision of theta_d its points predict (:attr:`TargetChoice.predicted_deg`); docs/targets.md says which."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Sequence

import cv2
import numpy as np
from numpy.typing import NDArray

from ..core.camera import CameraIntrinsics
from ..errors import InputError
from .aruco import find_markers
from .base import as_gray
from .charuco import MIN_INFER_MARKERS, find_charuco
from .chessboard import find_chessboard
from .dots import find_dots
from .target_kinds import TARGET_KINDS, TargetChoice, in_most
from .texture import TextureDetector, texture_points_for_template

#: Dots, markers or a board whose outline covers at least this fraction of the matched
#: texture's: the texture is their own print and is set aside (docs/targets.md).
OWN_PRINT_FRACTION = 0.25
#: A marker's quad grown about its centre by this factor holds its print (its quiet zone).
MARKER_PRINT_MARGIN = 1.5
#: A texture feature counts as matched within this distance (px) of where the homography puts it.
MATCHED_PX = 3.0


def find_texture(images: Sequence[NDArray[np.uint8]], template_pixels: NDArray[np.float64], seed: int = 0) -> TargetChoice | None:
    """The first frame's natural features matched in most of the following frames, or None.

    Its points are the first frame's ORB features inside the box ``template_pixels`` (4, 2)
    px whose match lies within :data:`MATCHED_PX` of where the detector's homography puts them.
    """
    box = np.asarray(template_pixels, dtype=float)
    if len(images) < 2:
        return TargetChoice("texture", "textured picture (a single frame: not checked against others)").measured_by(box)
    orb, matcher = cv2.ORB_create(nfeatures=1000), cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True)
    keys, codes = orb.detectAndCompute(images[0], None)
    first = np.array([k.pt for k in keys], dtype=float).reshape(-1, 2)
    inside = np.array([cv2.pointPolygonTest(box.astype(np.float32), (float(x), float(y)), False) >= 0 for x, y in first], dtype=bool)
    detector = TextureDetector(images[0], box, seed=seed)
    counts, matched = [], set()
    for image in images[1:]:
        detector.reset()
        detection = detector.detect(image, None)
        frame_keys, frame_codes = orb.detectAndCompute(image, None)
        pairs = matcher.match(codes, frame_codes) if codes is not None and frame_codes is not None else []
        if not detection.found or not pairs:
            continue
        index = np.array([pair.queryIdx for pair in pairs], dtype=int)
        where = np.array([frame_keys[pair.trainIdx].pt for pair in pairs], dtype=float).reshape(-1, 2)
        predicted = cv2.perspectiveTransform(first[index].reshape(-1, 1, 2), detection.homography).reshape(-1, 2)
        good = index[inside[index] & (np.linalg.norm(predicted - where, axis=1) <= MATCHED_PX)]
        counts.append(len(good))
        matched.update(good.tolist())
    if not in_most(len(counts), len(images) - 1) or len(matched) < 4:
        return None
    reason = f"textured picture: the first frame's features matched in {len(counts)} of the next {len(images) - 1} frames"
    return replace(TargetChoice("texture", reason).measured_by(first[sorted(matched)]), n_points=int(np.median(counts)))


@dataclass(frozen=True)
class Candidates:
    """The kinds the first frames show (``found``, the lowest :attr:`TargetChoice.predicted_deg`
    first), the kinds looked for and not found (``ruled_out``, in words), and ``aside``: what
    was set aside as another candidate's own print (words, or "")."""

    found: list[TargetChoice]
    ruled_out: list[str]
    aside: str = ""


def is_own_print(candidate: TargetChoice, texture: TargetChoice) -> bool:
    """Whether the matched ``texture`` is ``candidate``'s own print (then set aside), by docs/targets.md's
    rule: :data:`OWN_PRINT_FRACTION` of its outline covered, and for markers most of its features on them."""
    if candidate.area_px < OWN_PRINT_FRACTION * texture.area_px:
        return False
    if candidate.kind != "aruco" or candidate.points is None or texture.points is None or len(candidate.points) % 4:
        return True
    quads = candidate.points.reshape(-1, 4, 2)
    centres = quads.mean(axis=1, keepdims=True)
    grown = (centres + MARKER_PRINT_MARGIN * (quads - centres)).astype(np.float32)
    on_markers = [any(cv2.pointPolygonTest(quad, (float(x), float(y)), False) >= 0 for quad in grown) for x, y in texture.points]
    return float(np.mean(on_markers)) >= 0.5


def target_candidates(images: Sequence[NDArray[np.uint8]], camera: CameraIntrinsics, seed: int = 0) -> Candidates:
    """Every target kind found consistently in the first frames (gray or BGR uint8) of a
    recording, the lowest :attr:`TargetChoice.predicted_deg` first; InputError naming every
    kind tried when none is found. A texture target's points: :func:`~.texture.texture_points_for_template`."""
    grays = [as_gray(image) for image in images]
    aside = ""
    markers = find_markers(grays)
    if markers is not None and len(markers.details["marker_ids"]) >= MIN_INFER_MARKERS:
        # Enough markers of one dictionary for a ChArUco board: if it is one, its corners stand for its markers.
        markers = find_charuco(grays, markers.details["marker_dict"]) or markers
    tried = [("markers (every ArUco/AprilTag dictionary)", markers), ("chessboard", find_chessboard(grays))]
    if markers is None:  # decoded markers are blobs a dots test would see; in colour: dots may differ in hue alone
        tried.append(("dots (3-10 round dark or light blobs)", find_dots(images)))
    try:
        texture = find_texture(grays, texture_points_for_template(grays[0], camera), seed)
    except InputError:
        texture = None
    printed = [choice for name, choice in tried if choice is not None and name != "chessboard"]  # markers, dots
    if texture is not None and any(is_own_print(c, texture) for c in printed):
        aside = f"; the texture of their own print ({texture.predicted_deg:.2g} deg) set aside"
    else:
        tried.append(("texture (natural features matched from frame to frame)", texture))
    found = [choice for _, choice in tried if choice is not None]
    ruled_out = [name for name, choice in tried if choice is None]
    if not found:
        raise InputError(
            f"no known target found consistently in the first {len(grays)} frames; tried {', '.join(ruled_out)}. "
            f"Choose one with --target {'|'.join(TARGET_KINDS)} (and --marker-dict NAME, --marker-id N for markers)"
        )
    found.sort(key=lambda choice: choice.predicted_deg)
    return Candidates(found, ruled_out, aside)
