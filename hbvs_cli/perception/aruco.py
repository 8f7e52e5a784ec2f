"""Square fiducial markers: every predefined ArUco dictionary and AprilTag family of OpenCV.

The target's points are the outer corners of one or several markers, each marker's in
OpenCV's order (top-left, top-right, bottom-right, bottom-left as printed), the markers in
the order of their ids as given; the code gives identity, tracking only narrows the search.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import replace
from typing import Sequence

import cv2
import numpy as np
from numpy.typing import NDArray

from ..core.desired import DetectorErrors
from ..core.fit_model import DetectorSpec
from ..core.plane import UNIT_SQUARE
from ..errors import InputError, UsageError
from .base import (Detection, PointTrack, TargetDetector, as_gray, check_prediction, row_lengths, search_window,
                   signed_polygon_area)
from .target_kinds import SpecRequest, TargetChoice, TargetKind, in_most, register_target_kind

#: The default dictionary (hbvs's simulated marker).
DEFAULT_DICTIONARY = "DICT_4X4_50"

#: Every predefined dictionary, by family, smallest first; the families in the order
#: :func:`scan_markers` tries them (AprilTag 16h5 last: its short code decodes noise most easily).
MARKER_FAMILIES: dict[str, tuple[str, ...]] = {
    **{f"{n}x{n}": tuple(f"DICT_{n}X{n}_{size}" for size in (50, 100, 250, 1000)) for n in range(4, 8)},
    "original": ("DICT_ARUCO_ORIGINAL",),
    "mip_36h12": ("DICT_ARUCO_MIP_36h12",),
    "apriltag_36h11": ("DICT_APRILTAG_36h11",),
    "apriltag_36h10": ("DICT_APRILTAG_36h10",),
    "apriltag_25h9": ("DICT_APRILTAG_25h9",),
    "apriltag_16h5": ("DICT_APRILTAG_16h5",),
}
#: Every dictionary name hbvs accepts (``--marker-dict``), in scanning order.
MARKER_DICTIONARIES: tuple[str, ...] = tuple(name for family in MARKER_FAMILIES.values() for name in family)


def dictionary_name(name: str) -> str:
    """The canonical name of a predefined dictionary from a user's spelling (``6x6_250``,
    ``DICT_APRILTAG_36H11``: case and the ``DICT_`` prefix do not matter); UsageError if none."""
    key = "DICT_" + str(name).strip().upper().removeprefix("DICT_")
    for candidate in MARKER_DICTIONARIES:
        if candidate.upper() == key:
            return candidate
    raise UsageError(f"unknown marker dictionary {name!r}: choose one of {', '.join(MARKER_DICTIONARIES)}")


def dictionary_size(name: str) -> int:
    """Number of markers in a predefined dictionary."""
    return int(_dictionary(name).bytesList.shape[0])


def _dictionary(name: str = DEFAULT_DICTIONARY) -> cv2.aruco.Dictionary:
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary_name(name)))


#: The one adaptive-threshold window size (px) of the search around a tracked marker.
WINDOW_THRESHOLD_SIZE = 13


def _parameters(refinement: int = cv2.aruco.CORNER_REFINE_SUBPIX, tracked: bool = False) -> cv2.aruco.DetectorParameters:
    """Detector parameters; ``tracked``: one adaptive threshold instead of OpenCV's three,
    for the search around a tracked marker (a quarter faster)."""
    parameters = cv2.aruco.DetectorParameters()
    parameters.cornerRefinementMethod = refinement
    # The defaults stop refining once a step is under 0.1 px, too coarse for servoing.
    parameters.cornerRefinementMinAccuracy = 0.001
    parameters.cornerRefinementMaxIterations = 100
    if tracked:
        parameters.adaptiveThreshWinSizeMin = WINDOW_THRESHOLD_SIZE
        parameters.adaptiveThreshWinSizeMax = WINDOW_THRESHOLD_SIZE
    return parameters


def unrefined_markers(image: NDArray[np.uint8], dictionary: str = DEFAULT_DICTIONARY) -> tuple[list[NDArray[np.float64]], list[int]]:
    """The markers of ``dictionary`` detected in a frame without corner refinement: each one's
    corners (4, 2) px, and their ids."""
    detector = cv2.aruco.ArucoDetector(_dictionary(dictionary), _parameters(cv2.aruco.CORNER_REFINE_NONE))
    corners, ids, _ = detector.detectMarkers(as_gray(image))
    if ids is None:
        return [], []
    return [np.asarray(c, float).reshape(4, 2) for c in corners], [int(i) for i in np.ravel(ids)]


def _largest_copy(corners: Sequence[NDArray[np.float32]], ids: NDArray[np.int32], ident: int) -> int | None:
    """Index of the largest marker ``ident`` among the detected ``ids`` (several copies: the
    nearest, usually the target), or None when it is not there."""
    matches = np.flatnonzero(ids == ident)
    if matches.size == 0:
        return None
    return int(matches[int(np.argmax([abs(cv2.contourArea(np.float32(corners[i]).reshape(4, 2))) for i in matches]))])


class ArucoMarkerDetector(TargetDetector):
    """The corners of one marker of a ``dictionary`` (``marker_id``; None: whichever single marker
    is in view) or of several (``marker_ids``, 4 corners each in this order, found when any is
    seen, NaN rows for the others), refined by OpenCV to sub-pixel, then by their edges."""

    kind = "aruco"

    def __init__(
        self,
        marker_id: int | None = None,
        dictionary: str = DEFAULT_DICTIONARY,
        marker_ids: Sequence[int] | None = None,
    ) -> None:
        self.dictionary = dictionary_name(dictionary)
        size = dictionary_size(self.dictionary)
        wanted = [int(i) for i in marker_ids] if marker_ids else ([] if marker_id is None else [int(marker_id)])
        for ident in wanted:
            if not 0 <= ident < size:
                raise UsageError(f"marker id {ident} is not in {self.dictionary} (0-{size - 1})")
        if len(set(wanted)) != len(wanted):
            raise UsageError(f"marker ids must differ, got {wanted}")
        self.marker_ids = tuple(wanted)
        self.n_points = 4 * max(len(wanted), 1)
        self._detector = cv2.aruco.ArucoDetector(_dictionary(self.dictionary), _parameters())
        self._window_detector = cv2.aruco.ArucoDetector(_dictionary(self.dictionary), _parameters(tracked=True))
        self._track = PointTrack(self.n_points, max_coast=5)

    def detect(self, image: NDArray[np.uint8], predicted: NDArray[np.float64] | None = None) -> Detection:
        """Find the markers' corners (:class:`~.base.TargetDetector`): with a prediction, in a window
        around it (plus half its size) with one adaptive threshold, then all; without one, or
        when that fails, in the whole frame."""
        gray = as_gray(image)
        prediction = check_prediction(predicted, self.n_points, self._track)
        result = None
        considered = 0
        searches = [(None, self._detector)]
        if prediction is not None:
            window = search_window(gray.shape, prediction, 0.5, 16)
            if window is not None:
                searches = [(window, self._window_detector), (window, self._detector), (None, self._detector)]
        # Narrowest search first; a wider one only while markers are missing (a board partly
        # out of view is searched whole once a frame, its missing markers may be back).
        for window, detector in searches:
            found, more = self._search(gray, window, detector)
            considered = max(considered, more)
            if found is not None and (result is None or _markers_seen(found) > _markers_seen(result)):
                result = found
            if result is not None and _markers_seen(result) == len(result) // 4:
                break
        pixels = np.full((self.n_points, 2), np.nan) if result is None else result
        self._track.update(pixels)
        found = result is not None
        return Detection(pixels=pixels, found=found, candidates=considered, rejected=considered - int(found))

    def _search(self, gray: NDArray[np.uint8], window: tuple[int, int, int, int] | None,
                detector: cv2.aruco.ArucoDetector) -> tuple[NDArray[np.float64] | None, int]:
        """Corners of the wanted marker in ``window`` (frame pixels), and markers considered (found by ``detector``)."""
        x0, y0, x1, y1 = window or (0, 0, gray.shape[1], gray.shape[0])
        view = gray if window is None else np.ascontiguousarray(gray[y0:y1, x0:x1])
        corners, ids, rejected = detector.detectMarkers(view)
        considered = (0 if ids is None else len(ids)) + len(rejected)
        if ids is None:
            return None, considered
        ids = np.ravel(ids)
        if self.marker_ids:  # a board partly out of view keeps the markers it shows (NaN rows for the others)
            picks = [_largest_copy(corners, ids, ident) for ident in self.marker_ids]
        else:
            picks = [0] if len(ids) == 1 else []
        if all(pick is None for pick in picks):
            return None, considered
        cells = self._detector.getDictionary().markerSize + 2
        missing = np.full((4, 2), np.nan)
        refined = [missing if pick is None else refine_marker_corners(view, corners[pick].reshape(4, 2).astype(np.float64), cells=cells)
                   for pick in picks]
        return np.concatenate(refined) + (x0, y0), considered


def _markers_seen(corners: NDArray[np.float64]) -> int:
    """Markers whose 4 corners are in ``corners`` (4M, 2) (NaN rows for the others)."""
    return int(np.count_nonzero(np.all(np.isfinite(corners.reshape(-1, 8)), axis=1)))


#: Passes of :func:`refine_marker_corners` at most, and the move (px) under which it stops;
#: the farthest (px) from a corner its edges are measured (:func:`_refine_corners_once`); the
#: mean side (px) of a marker too small to refine (not the shortest: a second edge beside a
#: marker pulls OpenCV's corners a pixel inward, squeezing one side, that the edges mend).
REFINE_PASSES = 3
REFINE_CONVERGED_PX = 0.05
EDGE_STRETCH_PX = 30.0
MIN_REFINED_SIDE_PX = 12.0


def refine_marker_corners(gray: NDArray[np.uint8], corners: NDArray[np.float64], max_shift: float = 2.5,
                          cells: int = 6) -> NDArray[np.float64]:
    """Sub-pixel outer corners of a marker from its edges, refined until they settle.

    ``cornerSubPix`` pulls an L-shaped outer corner inward: each corner is re-measured where lines
    fitted to its two edges meet. OpenCV's corners can be most of a pixel off on a small marker,
    where one pass's profiles (:func:`_refine_corners_once`, whose parameters these are) cut one
    tail of the edge's rise; each pass starts from the last one's corners. ``max_shift`` bounds the whole move.
    """
    start = np.asarray(corners, dtype=np.float64)
    refined = start
    for _ in range(REFINE_PASSES):
        moved = _refine_corners_once(gray, refined, max_shift=max_shift, cells=cells)
        far = np.linalg.norm(moved - start, axis=1) > max_shift
        moved[far] = refined[far]
        step = float(np.max(np.linalg.norm(moved - refined, axis=1)))
        refined = moved
        if step < REFINE_CONVERGED_PX:
            break
    return refined.copy()


def _refine_corners_once(gray: NDArray[np.uint8], corners: NDArray[np.float64], max_shift: float, cells: int) -> NDArray[np.float64]:
    """Sub-pixel outer corners (4, 2) of a marker from its edges: one pass.

    Bilinear profiles across each of a corner's two edges, 3 to ``min(side - 3, 30)`` px from
    it (the lens bends long edges), locate the edge at the centroid of the profile's rises;
    the corner is where the edges' total-least-squares lines meet. ``corners`` (4, 2): around
    the marker (px); a corner that would move farther than ``max_shift`` px stays; ``cells``:
    across the marker, border included (the profiles reach 60 % into the border cell).
    """
    # Norms and neighbours by hand: np.linalg.norm and np.roll cost more on 4 points.
    corners = np.asarray(corners, dtype=np.float64)
    sides = np.sqrt(np.add.reduce(np.square(corners[_NEXT] - corners), axis=1))
    if sides.mean() < MIN_REFINED_SIDE_PX:
        return corners.copy()
    # Each corner looks along two edges: toward the previous and toward the next corner.
    starts = np.repeat(corners, 2, axis=0)
    ends = corners[[3, 1, 0, 2, 1, 3, 2, 0]]
    edges = ends - starts
    along = edges / np.sqrt(np.add.reduce(edges * edges, axis=1))[:, None]
    # Outward normal: a quarter turn of the edge direction, the sign set by the polygon's
    # orientation and by whether the edge is walked forward or backward around it.
    orientation = 1.0 if signed_polygon_area(corners) >= 0 else -1.0
    outward = (orientation * _WALK)[:, None] * np.stack([along[:, 1], -along[:, 0]], axis=1)
    step = 0.5
    half = step * np.floor(min(4.0, 0.6 * float(sides.min()) / cells) / step)
    if half < 1.0:
        return corners.copy()
    steps = np.arange(-half, half + 1e-9, step)
    distances = np.arange(3.0, min(float(sides.min()) - 3.0, EDGE_STRETCH_PX) + 1e-9, 1.0)
    centres = starts[:, None, :] + distances[None, :, None] * along[:, None, :]
    samples = centres[:, :, None, :] + steps[None, None, :, None] * outward[:, None, None, :]
    profiles = _bilinear(gray, samples)
    if profiles is None:
        return corners.copy()
    rises = np.maximum(np.diff(profiles, axis=-1), 0.0)
    rise = rises.sum(axis=-1)
    usable = rise > 20.0
    offset = (rises @ (0.5 * (steps[1:] + steps[:-1]))) / np.where(usable, rise, 1.0)
    points = centres + offset[..., None] * outward[:, None, :]
    # Weighted total least squares per edge (weights: usable profiles).
    weight = usable.astype(np.float64)
    count = weight.sum(axis=1)
    if np.any(count < 3):
        return corners.copy()
    mean = (points * weight[..., None]).sum(axis=1) / count[:, None]
    delta = (points - mean[:, None, :]) * np.sqrt(weight)[..., None]
    sxx = np.sum(delta[..., 0] ** 2, axis=1)
    syy = np.sum(delta[..., 1] ** 2, axis=1)
    sxy = np.sum(delta[..., 0] * delta[..., 1], axis=1)
    angle = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    direction = np.column_stack([np.cos(angle), np.sin(angle)])
    # Each corner's two lines (p + t d, q + s e) met by Cramer's rule, all four at once.
    p, q = mean[0::2], mean[1::2]
    d, e = direction[0::2], direction[1::2]
    determinant = e[:, 0] * d[:, 1] - d[:, 0] * e[:, 1]
    crossing = abs(determinant) >= 0.1  # nearly parallel lines meet nowhere useful
    gap = q - p
    t = (e[:, 0] * gap[:, 1] - gap[:, 0] * e[:, 1]) / np.where(crossing, determinant, 1.0)
    corner = p + t[:, None] * d
    keep = crossing & (np.hypot(*(corner - corners).T) <= max_shift)
    refined = corners.copy()
    refined[keep] = corner[keep]
    return refined


#: Each corner's successor around the marker, and the direction each of a corner's two
#: edges is walked in (backward to the previous corner, forward to the next).
_NEXT = [1, 2, 3, 0]
_WALK = np.array([-1.0, 1.0] * 4)


def _bilinear(gray: NDArray[np.uint8], points: NDArray[np.float64]) -> NDArray[np.float64] | None:
    """Bilinear samples of ``gray`` at ``points`` (..., 2); None if any falls outside."""
    x, y = points[..., 0], points[..., 1]
    height, width = gray.shape
    if x.min() < 0 or y.min() < 0 or x.max() > width - 1.001 or y.max() > height - 1.001:
        return None
    x0, y0 = np.floor(x).astype(np.intp), np.floor(y).astype(np.intp)
    fx, fy = x - x0, y - y0
    # Gathers from the flat image (one index array, four offsets) are cheaper than 2-D ones.
    flat = gray.ravel()
    at = y0 * width + x0
    top = flat[at] * (1 - fx) + flat[at + 1] * fx
    bottom = flat[at + width] * (1 - fx) + flat[at + width + 1] * fx
    return top * (1 - fy) + bottom * fy


#: Markers smaller than this (px) in every frame are not trusted as a decoded code.
MIN_MARKER_SIDE_PX = 8.0


def find_markers(images: Sequence[NDArray[np.uint8]], dictionary: str | None = None) -> TargetChoice | None:
    """Markers decoded consistently in ``images`` (one dictionary family), or None."""
    wanted = None if dictionary is None else dictionary_name(dictionary)
    families = None if wanted is None else [name for name, members in MARKER_FAMILIES.items() if wanted in members]
    votes: Counter[str] = Counter()
    ids_seen: dict[str, Counter[int]] = {}
    for image in images:
        # Each family searched once with its largest dictionary (the smaller ones are its prefixes), the one with
        # the most markers first; tiny markers are the likeliest false decodes.
        gray = as_gray(image)
        seen = [(family, *unrefined_markers(gray, MARKER_FAMILIES[family][-1])) for family in families or MARKER_FAMILIES]
        for family, corners, ids in sorted(seen, key=lambda sighting: -len(set(sighting[2]))):
            if ids and min(float(np.min(row_lengths(np.roll(c, -1, axis=0) - c))) for c in corners) >= MIN_MARKER_SIDE_PX:
                votes[family] += 1
                ids_seen.setdefault(family, Counter()).update(set(ids))
    family, count = votes.most_common(1)[0] if votes else ("", 0)
    ids = sorted(i for i, n in ids_seen.get(family, Counter()).items() if in_most(n, len(images)))
    if not in_most(count, len(images)) or not ids:
        return None
    name = wanted or next(n for n in MARKER_FAMILIES[family] if dictionary_size(n) > ids[-1])
    others = [f for f in votes if f != family]
    also = f"; also decoded as {', '.join(others)} in fewer frames" if others else ""
    which = f"id {ids[0]}" if len(ids) == 1 else f"ids {', '.join(map(str, ids))} ({4 * len(ids)} corners)"
    reason = f"markers: {name} {which} decoded in {count} of the first {len(images)} frames{also}"
    choice = TargetChoice("aruco", reason, {"marker_dict": name, "marker_ids": ids})
    for image in images:  # measured by the corners (4M, 2) of the first frame that shows any: each id's largest copy, unrefined
        corners, seen = unrefined_markers(image, name)
        picked = [corners[pick] for pick in (_largest_copy(corners, np.array(seen), ident) for ident in ids) if pick is not None]
        if picked:
            return choice.measured_by(np.concatenate(picked))
    return choice


def _markers_spec(request: SpecRequest) -> DetectorSpec:
    """A simulated marker (the world's id), the marker ``--marker-id`` names, or the markers
    decoded in most of the first frames (said on stderr)."""
    if request.seen_pixels is not None:
        return DetectorSpec(kind="aruco", n_points=4, marker_id=request.marker_id)
    if request.marker_id is not None:
        return DetectorSpec(kind="aruco", n_points=4, marker_id=request.marker_id, marker_dict=request.marker_dict or DEFAULT_DICTIONARY)
    details = request.details
    if "marker_ids" not in details:
        details = request.found(find_markers(request.images, request.marker_dict),
                                f"marker of {request.marker_dict or 'any ArUco/AprilTag dictionary'}",
                                "choose --marker-dict NAME, or another --target", "markers")
    ids = tuple(details["marker_ids"])
    return DetectorSpec(kind="aruco", n_points=4 * len(ids), marker_id=ids[0] if len(ids) == 1 else None,
                        marker_dict=details["marker_dict"], marker_ids=ids)


def _with_marker(spec: DetectorSpec, image: NDArray[np.uint8]) -> DetectorSpec:
    """The spec with its marker (the first of its dictionary in view when none is named) and 4 corners a marker."""
    if spec.marker_id is None and not spec.marker_ids:
        ids = unrefined_markers(image, spec.marker_dict or DEFAULT_DICTIONARY)[1]
        if not ids:
            raise InputError(f"no marker of {spec.marker_dict or DEFAULT_DICTIONARY} in the first image (choose the dictionary with --marker-dict)")
        spec = replace(spec, marker_id=int(ids[0]))
    return replace(spec, n_points=4 * len(spec.marker_ids or (spec.marker_id,)))


def _markers(spec: DetectorSpec, template: NDArray[np.uint8] | None, seed: int, windowed: bool) -> ArucoMarkerDetector:
    markers = ArucoMarkerDetector(spec.marker_id, dictionary=spec.marker_dict or DEFAULT_DICTIONARY, marker_ids=spec.marker_ids)
    if spec.n_points != markers.n_points:
        raise UsageError(f"a target of {len(markers.marker_ids) or 1} marker(s) has {markers.n_points} points (their corners), not {spec.n_points}")
    return markers


# Corners located from edges: a bias of half the point noise, alike over nearby frames, not
# correlated over frames otherwise; theta_d 0.35 deg and x_hd1 5e-3 (bench/CALIBRATION.md).
# --target-size is a marker's side: corners 0 (TL) to 1 (TR). Each marker's four corners (OpenCV's order) are a square.
register_target_kind(TargetKind(
    name="aruco", spec=_markers_spec, make=_markers, complete=_with_marker,
    errors=DetectorErrors("aruco", bias_fraction=0.5, correlated=False, expected_precision=(0.35, 5e-3)), precision_scale=17.7,
    shapes=lambda spec: [(range(k, k + 4), UNIT_SQUARE) for k in range(0, int(spec.n_points or 0), 4)],
    size_pair=lambda spec, m_ref, normal: ((0, 1), 1.0), options=frozenset({"marker_dict", "marker_id"}),
))
