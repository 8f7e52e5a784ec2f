"""``--target auto``: which target a recording shows, judged on its first frames.

The kinds are tried from the most specific evidence to the least, and the first that
pins the plane best wins:

1. **ChArUco board** -- markers laid out as a ChArUco board's (:func:`~.charuco.infer_board`),
   its corners found in most of the first frames: a known grid of sub-pixel chessboard
   corners, each identified by its markers;
2. **markers** -- a decoded ArUco/AprilTag code is hard to produce by chance; every
   predefined dictionary is scanned (:func:`~.aruco.scan_markers`) and a family must decode
   the same ids in most of the first frames. Markers that cover only a small part of a
   textured picture they are printed in (less than :data:`SMALL_MARKERS_FRACTION` of its
   area) give way to the picture: the whole picture's alignment pins the plane over its
   full width, a few small squares over theirs;
3. **chessboard** -- ``findChessboardCornersSB`` finds the same pattern in most of the
   first frames: a known grid of sub-pixel corners;
4. **dots** -- dark dots on a lighter ground, then light dots on a darker one: the same
   number (3-10) of round blobs of comparable size, making up most of the blob-like structure,
   in most of the first frames; in gray first, then (colour footage) in colour, for dots that
   differ from their wall in hue alone (:func:`~.dots.dark_image`);
5. **texture** -- natural features of the first frame, matched (robust homography) in most
   of the following first frames.

:class:`TargetChoice` says why in one sentence (what was found, in how many frames, and
what was ruled out before), so that a wrong pick is impossible to miss. When none passes,
:class:`~hbvs_cli.errors.InputError` names every kind tried.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from .aruco import MARKER_FAMILIES, dictionary_name, dictionary_size, marker_corners_in_view, scan_markers
from .base import as_gray
from .charuco import MIN_INFER_MARKERS, CharucoTargetDetector, infer_board
from .chessboard import Board, board_corners_cross, find_board
from .dots import ACQUIRE_AREA_RATIO, dark_image, find_dark_blobs
from .texture import TextureDetector

#: Dots targets have this many dots at most (and 3 at least).
MAX_DOTS = 10
#: Markers smaller than this (px) in every frame are not trusted as a decoded code.
MIN_MARKER_SIDE_PX = 8.0
#: Markers whose outline (convex hull) covers less than this fraction of the textured
#: picture's region around them give way to the picture.
SMALL_MARKERS_FRACTION = 0.25


@dataclass(frozen=True)
class TargetChoice:
    """What ``--target auto`` picked.

    Attributes
    ----------
    kind : str
        ``dots``, ``aruco``, ``chessboard``, ``charuco`` or ``texture``.
    reason : str
        One sentence for stderr: what was found, how consistently, what was ruled out.
    details : dict
        ``polarity``, ``n_points`` and, for dots seen in colour only, ``contrast`` (dots);
        ``marker_dict`` and ``marker_ids`` (aruco); ``board`` (chessboard: inner corners
        per row and rows; charuco: squares across and down, and its ``marker_dict``).
    """

    kind: str
    reason: str
    details: dict[str, Any] = field(default_factory=dict)


def _majority(count: int, frames: int) -> bool:
    return count >= max(1, (frames + 1) // 2) and count >= min(frames, 2)


def find_markers(images: Sequence[NDArray[np.uint8]], dictionary: str | None = None) -> TargetChoice | None:
    """Markers decoded consistently in ``images`` (one dictionary family), or None."""
    families = None
    if dictionary is not None:
        wanted = dictionary_name(dictionary)
        families = [name for name, members in MARKER_FAMILIES.items() if wanted in members]
    votes: Counter[str] = Counter()
    ids_seen: dict[str, Counter[int]] = {}
    for image in images:
        for sighting in scan_markers(image, families):
            if sighting.smallest_side_px < MIN_MARKER_SIDE_PX:
                continue
            family = next(name for name, members in MARKER_FAMILIES.items() if sighting.dictionary in members)
            votes[family] += 1
            ids_seen.setdefault(family, Counter()).update(sighting.ids)
    if not votes:
        return None
    family, count = votes.most_common(1)[0]
    if not _majority(count, len(images)):
        return None
    ids = sorted(i for i, n in ids_seen[family].items() if _majority(n, len(images)))
    if not ids:
        return None
    names = MARKER_FAMILIES[family]
    name = dictionary_name(dictionary) if dictionary is not None else next(n for n in names if dictionary_size(n) > ids[-1])
    others = [f for f in votes if f != family]
    also = f"; also decoded as {', '.join(others)} in fewer frames" if others else ""
    which = f"id {ids[0]}" if len(ids) == 1 else f"ids {', '.join(map(str, ids))} ({4 * len(ids)} corners)"
    reason = f"markers: {name} {which} decoded in {count} of the first {len(images)} frames{also}"
    return TargetChoice("aruco", reason, {"marker_dict": name, "marker_ids": ids})


def find_charuco(images: Sequence[NDArray[np.uint8]], dictionary: str | None = None,
                 squares: tuple[int, int] | None = None) -> TargetChoice | None:
    """A ChArUco board (its layout inferred from the first frame's markers) whose corners
    are found in most of ``images``, or None."""
    geometry = infer_board(images[0], None if dictionary is None else [dictionary_name(dictionary)], squares)
    if geometry is None:
        return None
    detector = CharucoTargetDetector(geometry.squares, geometry.dictionary, geometry.marker_ratio)
    seen = [int(np.count_nonzero(np.all(np.isfinite(detector.detect(image).pixels), axis=1))) for image in images]
    found = sum(count > 0 for count in seen)
    if not _majority(found, len(images)):
        return None
    columns, rows = geometry.squares
    reason = (f"ChArUco board of {columns}x{rows} squares ({geometry.dictionary}, {geometry.n_markers} markers) with up to "
              f"{max(seen)} of its {detector.n_points} corners found in {found} of the first {len(images)} frames "
              "(a known grid of sub-pixel corners, each named by its markers)")
    return TargetChoice("charuco", reason, {"board": [columns, rows], "marker_dict": geometry.dictionary})


def find_chessboard(images: Sequence[NDArray[np.uint8]]) -> TargetChoice | None:
    """A chessboard of the same pattern in most of ``images``, or None.

    The first frame is searched for the largest board (``findChessboardCornersSB``); the
    others for that pattern.
    """
    first = _checked_board(images[0])
    if first is None:
        return None
    found = 1 + sum(_checked_board(image, first.pattern) is not None for image in images[1:])
    if not _majority(found, len(images)):
        return None
    columns, rows = first.pattern
    reason = (f"chessboard of {columns}x{rows} inner corners found in {found} of the first {len(images)} frames "
              f"({columns * rows} sub-pixel corners on a known grid pin the plane better than texture)")
    return TargetChoice("chessboard", reason, {"board": [columns, rows]})


def _checked_board(image: NDArray[np.uint8], pattern: tuple[int, int] | None = None) -> Board | None:
    """:func:`~.chessboard.find_board`, its corners checked to be crossings of two dark and
    two light squares (``findChessboardCornersSB`` also "finds" small boards in a few dots
    on a wall: a 4x3 board in 3 of 5 frames of a simulated dots target)."""
    board = find_board(image, pattern)
    if board is None or not board_corners_cross(as_gray(image), board.corners, board.pattern):
        return None
    return board


def count_round_dots(image: NDArray[np.uint8], polarity: str, contrast: str = "gray") -> tuple[int, bool]:
    """Round blobs of similar size in one frame, and whether they make up most of its blob-like structure.

    A textured picture has many dark shapes that are not round; a dots target's dots are
    most of what is compact and interior (components cut by the frame's edge, e.g. the
    wall or a door frame, are not counted).
    """
    blobs = find_dark_blobs(dark_image(image, polarity, contrast), flatten=True)
    round_areas = blobs.areas[blobs.round]
    if round_areas.size < 3:
        return int(round_areas.size), False
    median = np.median(round_areas)
    similar = int(np.count_nonzero((round_areas >= median / ACQUIRE_AREA_RATIO) & (round_areas <= median * ACQUIRE_AREA_RATIO)))
    interior = int(np.count_nonzero(~blobs.touches_edge & (blobs.areas >= 0.1 * median)))
    return similar, similar >= 3 and similar >= 0.75 * interior


def find_dots(images: Sequence[NDArray[np.uint8]], polarity: str | None = None) -> TargetChoice | None:
    """The same number of dots (3-10) in most of ``images``, dark ones first, in gray first
    (then in colour, when the frames have it), or None."""
    tried = []
    colour = any(np.ndim(image) == 3 for image in images)
    # In colour, light dots first: a dot that differs from a neutral wall in hue alone is
    # brighter than it in its own channel (red in red), where dark frames and shadows do not
    # compete, and darker in the others only as far as it is saturated (a blue dot of a grey's
    # luminance is not darker in any channel). On the red-on-grey footage the brightest
    # channel measured the dots to 0.087 px RMS, the darkest to 0.17 px.
    order = [("gray", "dark"), ("gray", "light")] + ([("colour", "light"), ("colour", "dark")] if colour else [])
    for contrast, kind in (pair for pair in order if polarity is None or pair[1] == polarity):
        counts = []
        for image in images:
            count, dominant = count_round_dots(image, kind, contrast)
            counts.append(count if dominant and 3 <= count <= MAX_DOTS else 0)
        tally = Counter(c for c in counts if c)
        tried.append(kind)
        if not tally:
            continue
        n_dots, frames = tally.most_common(1)[0]
        if _majority(frames, len(images)):
            before = " (no dark dots)" if kind == "light" and polarity is None else ""
            details = {"polarity": kind, "n_points": n_dots}
            if contrast == "colour":
                channel = "darkest" if kind == "dark" else "brightest"
                before = f" in colour, on their {channel} channel (no dots stand out in gray)"
                details["contrast"] = contrast
            reason = f"{n_dots} {kind} round dots of comparable size in {frames} of the first {len(images)} frames{before}"
            return TargetChoice("dots", reason, details)
    return None


def find_texture(images: Sequence[NDArray[np.uint8]], template_pixels: NDArray[np.float64], seed: int = 0) -> TargetChoice | None:
    """The first frame's natural features matched in most of the following frames, or None."""
    if len(images) < 2:
        return TargetChoice("texture", "textured picture (a single frame: not checked against others)")
    detector = TextureDetector(images[0], template_pixels, seed=seed)
    found = 0
    inliers = []
    for image in images[1:]:
        detector.reset()
        detection = detector.detect(image, None)
        found += int(detection.found)
        if detection.found:
            inliers.append(detection.inliers)
    if not _majority(found, len(images) - 1):
        return None
    reason = (
        f"textured picture: the first frame's features matched in {found} of the next {len(images) - 1} frames "
        f"(median {int(np.median(inliers))} inliers)"
    )
    return TargetChoice("texture", reason)


def choose_target(
    images: Sequence[NDArray[np.uint8]],
    template_pixels_of: Any,
    *,
    marker_dict: str | None = None,
    seed: int = 0,
) -> TargetChoice:
    """Pick the target kind from the first frames of a recording.

    Parameters
    ----------
    images : sequence of ndarray
        The first few frames (gray or BGR uint8).
    template_pixels_of : callable
        ``template_pixels_of(first_image) -> (4, 2) pixels``: where a texture target's
        points would be (or raises :class:`InputError` when the image has too few features).
    marker_dict : str, optional
        Only this dictionary is scanned (``--marker-dict``).
    seed : int

    Raises
    ------
    InputError
        When no kind is found consistently; the message names every kind tried.
    """
    grays = [as_gray(image) for image in images]
    ruled_out = []
    markers = find_markers(grays, marker_dict)
    if markers is not None and len(markers.details["marker_ids"]) >= MIN_INFER_MARKERS:
        # Enough markers of one dictionary for a ChArUco board: is it one?
        board = find_charuco(grays, markers.details["marker_dict"])
        if board is not None:
            return board
    if markers is not None:
        picture = None if marker_dict is not None else _picture_around_small_markers(grays, markers, template_pixels_of, seed)
        return markers if picture is None else picture
    ruled_out.append(f"markers ({marker_dict or 'every ArUco/AprilTag dictionary'})")
    if marker_dict is None:
        chessboard = find_chessboard(grays)
        if chessboard is not None:
            return _with_ruled_out(chessboard, ruled_out)
        ruled_out.append("chessboard")
        dots = find_dots(images)  # in colour: dots may differ from their wall in hue alone
        if dots is not None:
            return _with_ruled_out(dots, ruled_out)
        ruled_out.append("dots (3-10 round dark or light blobs)")
        try:
            texture = find_texture(grays, template_pixels_of(grays[0]), seed)
        except InputError:
            texture = None
        if texture is not None:
            return _with_ruled_out(texture, ruled_out)
        ruled_out.append("texture (natural features matched from frame to frame)")
    raise InputError(
        f"no known target found consistently in the first {len(grays)} frames; tried {', '.join(ruled_out)}. "
        "Choose one with --target dots|aruco|chessboard|charuco|texture (and --marker-dict NAME, --marker-id N for markers)"
    )


def _picture_around_small_markers(grays: Sequence[NDArray[np.uint8]], markers: TargetChoice, template_pixels_of: Any,
                                  seed: int) -> TargetChoice | None:
    """The textured picture the markers are printed in, when they cover only a small part
    of it (less than :data:`SMALL_MARKERS_FRACTION` of its area) and it is matched from
    frame to frame; else None (the markers are the target)."""
    import cv2

    corners = marker_corners_in_view(grays[0], markers.details["marker_dict"], markers.details["marker_ids"])
    if corners is None:
        return None
    try:
        box = np.asarray(template_pixels_of(grays[0]), dtype=np.float32)
    except InputError:
        return None
    picture_area = abs(float(cv2.contourArea(box)))
    marker_area = abs(float(cv2.contourArea(cv2.convexHull(corners.astype(np.float32)))))
    if picture_area <= 0 or marker_area >= SMALL_MARKERS_FRACTION * picture_area:
        return None
    texture = find_texture(grays, box.astype(np.float64), seed)
    if texture is None:
        return None
    ids = markers.details["marker_ids"]
    reason = (f"{texture.reason}; it holds {markers.details['marker_dict']} marker{'s' if len(ids) > 1 else ''} "
              f"{', '.join(map(str, ids))} covering only {100 * marker_area / picture_area:.0f} % of it "
              "(the whole picture pins the plane over its full width)")
    return TargetChoice("texture", reason)


def _with_ruled_out(choice: TargetChoice, ruled_out: list[str]) -> TargetChoice:
    return TargetChoice(choice.kind, f"{choice.reason}; no {' and no '.join(ruled_out)}", choice.details)
