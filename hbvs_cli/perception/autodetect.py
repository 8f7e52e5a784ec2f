"""``--target auto``'s candidates: each kind of target found in most of a recording's first frames, ordered by
the precision of theta_d its points predict (:attr:`TargetChoice.predicted_deg`); docs/targets.md says which."""

from __future__ import annotations

from collections import Counter
from functools import partial
from dataclasses import dataclass, field, replace
from typing import Any, Sequence

import cv2
import numpy as np
from numpy.typing import NDArray

from ..core.camera import CameraIntrinsics
from ..errors import InputError
from ..thread_pool import StopSafePool
from .aruco import MARKER_FAMILIES, dictionary_name, dictionary_size, marker_corners_in_view, unrefined_markers
from .base import as_gray, row_lengths
from .charuco import MIN_INFER_MARKERS, CharucoTargetDetector, infer_board
from .chessboard import Board, board_corners_cross, find_board, find_board_near
from .dots import ACQUIRE_AREA_RATIO, dark_image, find_dark_blobs, speck_floor
from .target_kinds import TARGET_KINDS, target_kind
from .texture import TextureDetector, texture_points_for_template

#: Dots targets have this many dots at most (and 3 at least).
MAX_DOTS = 10
#: Markers smaller than this (px) in every frame are not trusted as a decoded code.
MIN_MARKER_SIDE_PX = 8.0
#: Dots, markers or a board whose outline covers at least this fraction of the matched
#: texture's: the texture is their own print and is set aside (docs/targets.md).
OWN_PRINT_FRACTION = 0.25
#: A marker's quad grown about its centre by this factor holds its print (its quiet zone).
MARKER_PRINT_MARGIN = 1.5
#: A texture feature counts as matched within this distance (px) of where the homography puts it.
MATCHED_PX = 3.0


@dataclass(frozen=True)
class TargetChoice:
    """What ``--target auto`` picked: the ``kind``, one sentence for stderr (``reason``), the
    detector's ``details`` (``polarity``, ``n_points``, ``contrast``; ``marker_dict``,
    ``marker_ids``; ``board``), and the points seen: how many (texture: median matched
    features per frame), their RMS ``spread_px`` about their centroid and their convex hull's
    ``area_px`` (px^2)."""

    kind: str
    reason: str
    details: dict[str, Any] = field(default_factory=dict)
    n_points: int = 0
    spread_px: float = float("nan")
    area_px: float = 0.0
    #: The points seen (K, 2) px (texture: its matched features), for the own-print test.
    points: NDArray[np.float64] | None = field(default=None, repr=False, compare=False)

    @property
    def predicted_deg(self) -> float:
        """theta_d's predicted RMS error (deg): the kind's ``precision_scale`` over spread_px * sqrt(n_points)."""
        spread = self.spread_px * np.sqrt(self.n_points)
        return target_kind(self.kind).precision_scale / spread if spread > 0 else float("inf")

    def measured_by(self, points: NDArray[np.float64] | None) -> TargetChoice:
        """This choice with ``n_points``, ``spread_px`` and ``area_px`` of ``points`` (N, 2) px (NaN rows unseen)."""
        if points is None:
            return self
        seen = points[np.all(np.isfinite(points), axis=1)]
        spread = float(np.sqrt(np.mean(np.sum((seen - seen.mean(axis=0)) ** 2, axis=1))))
        return replace(self, n_points=len(seen), spread_px=spread, area_px=float(cv2.contourArea(cv2.convexHull(seen.astype(np.float32)))),
                       points=seen)


def _majority(count: int, frames: int) -> bool:
    return count >= max(1, (frames + 1) // 2) and count >= min(frames, 2)


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
    ids = sorted(i for i, n in ids_seen.get(family, Counter()).items() if _majority(n, len(images)))
    if not _majority(count, len(images)) or not ids:
        return None
    name = wanted or next(n for n in MARKER_FAMILIES[family] if dictionary_size(n) > ids[-1])
    others = [f for f in votes if f != family]
    also = f"; also decoded as {', '.join(others)} in fewer frames" if others else ""
    which = f"id {ids[0]}" if len(ids) == 1 else f"ids {', '.join(map(str, ids))} ({4 * len(ids)} corners)"
    reason = f"markers: {name} {which} decoded in {count} of the first {len(images)} frames{also}"
    corners = next((c for c in (marker_corners_in_view(image, name, ids) for image in images) if c is not None), None)
    return TargetChoice("aruco", reason, {"marker_dict": name, "marker_ids": ids}).measured_by(corners)


def find_charuco(images: Sequence[NDArray[np.uint8]], dictionary: str | None = None,
                 squares: tuple[int, int] | None = None) -> TargetChoice | None:
    """A ChArUco board (its layout inferred from the first frame's markers) whose corners
    are found in most of ``images``, or None."""
    geometry = infer_board(images[0], None if dictionary is None else [dictionary_name(dictionary)], squares)
    if geometry is None:
        return None
    detector = CharucoTargetDetector(geometry.squares, geometry.dictionary, geometry.marker_ratio)
    pixels = [detector.detect(image).pixels for image in images]
    seen = [int(np.count_nonzero(np.all(np.isfinite(p), axis=1))) for p in pixels]
    found = sum(count > 0 for count in seen)
    if not _majority(found, len(images)):
        return None
    columns, rows = geometry.squares
    reason = (f"ChArUco board of {columns}x{rows} squares ({geometry.dictionary}, {geometry.n_markers} markers) with up to "
              f"{max(seen)} of its {detector.n_points} corners found in {found} of the first {len(images)} frames "
              "(a known grid of sub-pixel corners, each named by its markers)")
    return TargetChoice("charuco", reason, {"board": [columns, rows], "marker_dict": geometry.dictionary}).measured_by(pixels[int(np.argmax(seen))])


def find_chessboard(images: Sequence[NDArray[np.uint8]]) -> TargetChoice | None:
    """A chessboard in most of ``images`` (the first frame's largest, ``findChessboardCornersSB``;
    that pattern in the others), or None."""
    first = _checked_board(images[0])
    if first is None:
        return None
    # The other frames' searches are independent and OpenCV releases the GIL: two at a time.
    # The first frame is searched for the pattern too: the tracker starts from that search
    # (which can settle on other corners than the largest board's), cached by find_board, as
    # the second frame's. The later ones are searched near the first frame's board first.
    with StopSafePool(max_workers=2, thread_name_prefix="hbvs-board") as pool:
        pool.submit(find_board, images[0], first.pattern)
        near = [None] + [first.corners] * (len(images) - 2)
        found = 1 + sum(board is not None for board in pool.map(partial(_checked_board, pattern=first.pattern), images[1:], near))
    if not _majority(found, len(images)):
        return None
    columns, rows = first.pattern
    reason = f"chessboard of {columns}x{rows} inner corners found in {found} of the first {len(images)} frames"
    return TargetChoice("chessboard", reason, {"board": [columns, rows]}).measured_by(first.corners)


def _checked_board(image: NDArray[np.uint8], near: NDArray[np.float64] | None = None, pattern: tuple[int, int] | None = None
                   ) -> Board | None:
    """:func:`~.chessboard.find_board` (first :func:`~.chessboard.find_board_near` the corners
    ``near``, when given), its corners checked to be crossings of two dark and two light
    squares (``findChessboardCornersSB`` also "finds" small boards in a few dots)."""
    board = find_board_near(image, pattern, near) if near is not None and pattern is not None else None
    board = board or find_board(image, pattern)
    return board if board is not None and board_corners_cross(as_gray(image), board.corners, board.pattern) else None


def round_dots(image: NDArray[np.uint8], polarity: str, contrast: str = "gray") -> tuple[NDArray[np.float64], bool]:
    """Centres (N, 2) px of the round blobs of similar size in one frame, and whether they
    make up most of what is compact and interior (a textured picture has many dark shapes
    that are not round; components cut by the frame's edge are not counted)."""
    blobs = find_dark_blobs(dark_image(image, polarity, contrast))
    round_areas, centres = blobs.areas[blobs.round], blobs.centres[blobs.round]
    if round_areas.size < 3:
        return centres, False
    # Specks of noise far smaller than the dots count neither as dots nor against them.
    specks = speck_floor(round_areas)
    round_areas, centres = round_areas[round_areas >= specks], centres[round_areas >= specks]
    median = np.median(round_areas)
    similar = (round_areas >= median / ACQUIRE_AREA_RATIO) & (round_areas <= median * ACQUIRE_AREA_RATIO)
    interior = int(np.count_nonzero(~blobs.touches_edge & (blobs.areas >= max(0.1 * median, specks))))
    return centres[similar], int(similar.sum()) >= max(3, 0.75 * interior)


def find_dots(images: Sequence[NDArray[np.uint8]]) -> TargetChoice | None:
    """The same number of dots (3-10) in most of ``images``, dark ones first, in gray first
    (then in colour, when the frames have it), or None."""
    colour = any(np.ndim(image) == 3 for image in images)
    # In colour, light dots first: a dot that differs from a neutral wall in hue alone is
    # brighter than it in its own channel, and darker in the others only as far as it is saturated.
    order = [("gray", "dark"), ("gray", "light")] + ([("colour", "light"), ("colour", "dark")] if colour else [])
    for contrast, kind in order:
        dots = [round_dots(image, kind, contrast) for image in images]
        centres = [found if dominant and 3 <= len(found) <= MAX_DOTS else found[:0] for found, dominant in dots]
        tally = Counter(len(c) for c in centres if len(c))
        n_dots, frames = tally.most_common(1)[0] if tally else (0, 0)
        if frames and _majority(frames, len(images)):
            before = " (no dark dots)" if kind == "light" else ""
            details = {"polarity": kind, "n_points": n_dots}
            if contrast == "colour":
                channel = "darkest" if kind == "dark" else "brightest"
                before = f" in colour, on their {channel} channel (no dots stand out in gray)"
                details["contrast"] = contrast
            reason = f"{n_dots} {kind} round dots of comparable size in {frames} of the first {len(images)} frames{before}"
            return TargetChoice("dots", reason, details).measured_by(next(c for c in centres if len(c) == n_dots))
    return None


def find_target(kind: str, images: Sequence[NDArray[np.uint8]], dictionary: str | None = None,
                squares: tuple[int, int] | None = None) -> TargetChoice | None:
    """What the first ``images`` show of a target ``kind`` (None: not found, or a kind looked
    for only by its own module: :attr:`~.target_kinds.SpecRequest.find`)."""
    finders = {"dots": partial(find_dots, images), "aruco": partial(find_markers, images, dictionary),
               "chessboard": partial(find_chessboard, images), "charuco": partial(find_charuco, images, dictionary, squares)}
    return finders[kind]() if kind in finders else None


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
    if not _majority(len(counts), len(images) - 1) or len(matched) < 4:
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
    """Whether the matched ``texture`` is ``candidate``'s own print (then set aside): the
    candidate's outline covers at least :data:`OWN_PRINT_FRACTION` of the texture's, and, for
    markers, most of the texture's features lie on the markers (their quads grown by
    :data:`MARKER_PRINT_MARGIN` for the quiet zone). Small markers printed in a larger
    picture are not its print: the two compete on their measured precision."""
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
