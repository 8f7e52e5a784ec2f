"""A ChArUco board as the target (docs/targets.md): its inner corners in OpenCV's ChArUco ids (row by row, a grid
the fit knows: :func:`~.chessboard.board_layout`), named by its markers (NaN where not in view)."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import lru_cache
from typing import Sequence

import cv2
import numpy as np
from numpy.typing import NDArray

from ..core.desired import DetectorErrors
from ..core.fit_model import DetectorSpec
from ..errors import UsageError
from .aruco import (DEFAULT_DICTIONARY, MARKER_FAMILIES, _dictionary, _parameters, dictionary_name, dictionary_size,
                    unrefined_markers)
from .base import Detection, PointTrack, TargetDetector, as_gray, padded_box, plain_median, row_lengths
from .chessboard import GRID_FIT_PX, SETTLED_PX, board_diagonal, board_layout, inside_image, refine_twice, saddle_points
from .target_kinds import SpecRequest, TargetChoice, TargetKind, in_most, register_target_kind

#: A frame counts as found when at least this many corners are (a homography needs 4; a
#: few more keep a frame whose corners are nearly collinear out).
MIN_CORNERS = 6
#: A board needs at least this many markers seen to be inferred (4 fix a homography).
MIN_INFER_MARKERS = 5
#: A marker's centre fits a candidate layout when it is within this fraction of a square
#: of where the best homography (RANSAC) puts its white square's centre.
LAYOUT_FIT_SQUARES = 0.2
#: Squares across or down a board may be at most this many (the candidates tried).
MAX_SQUARES = 16
#: A refined corner may move this far (px) from OpenCV's at most.
MAX_REFINE_MOVE_PX = 1.5
#: ... or up to this far (px) where the corner's neighbours on the board agree with it
#: (:func:`_from_neighbours`) within :data:`NEIGHBOUR_AGREEMENT_PX`.
FAR_REFINE_MOVE_PX = 3.0
NEIGHBOUR_AGREEMENT_PX = 0.5
#: A corner is refined in a window whose half-size is this fraction of the gap between
#: its squares' markers, ``(1 - marker_ratio)`` of a square as seen, within bounds (px).
GAP_WINDOW_FRACTION = 0.4
GAP_WINDOW_PX = (2, 8)
#: A tracked board is searched in its predicted corners' box widened by this many squares (the
#: outer squares hold markers) and pixels (half OpenCV's largest threshold window, its 3 px
#: from the border); the whole frame when that box does not give every corner.
SEARCH_MARGIN_SQUARES = 1.5
SEARCH_MARGIN_PX = 16


@dataclass(frozen=True)
class CharucoGeometry:
    """A ChArUco board's layout: ``squares`` across and down (OpenCV's ``CharucoBoard`` size), the
    markers' ``dictionary``, their side over the squares' (``marker_ratio``), and whether it is
    OpenCV's ``legacy`` pattern (before 4.6, boards with an even number of rows started white)."""

    squares: tuple[int, int]
    dictionary: str
    marker_ratio: float = 0.75
    legacy: bool = False

    @property
    def n_markers(self) -> int:
        """Markers on the board (one on every white square)."""
        return self.squares[0] * self.squares[1] // 2

    def board(self) -> cv2.aruco.CharucoBoard:
        """OpenCV's board, its dictionary cut to its own markers (each candidate is compared with
        every marker; a dictionary's markers differ by more than twice the bits it corrects)."""
        full = _dictionary(self.dictionary)
        own = cv2.aruco.Dictionary(full.bytesList[: self.n_markers].copy(), full.markerSize, full.maxCorrectionBits)
        board = cv2.aruco.CharucoBoard(self.squares, 1.0, float(self.marker_ratio), own)
        board.setLegacyPattern(self.legacy)
        return board


@lru_cache(maxsize=None)
def _layout(squares: tuple[int, int], legacy: bool) -> dict[int, NDArray[np.float64]]:
    """Each marker's centre (squares) on a board of ``squares``, by id (any dictionary's)."""
    board = CharucoGeometry(squares, "DICT_4X4_1000", 0.5, legacy).board()
    return {int(i): np.asarray(points, float).reshape(4, 3)[:, :2].mean(axis=0) for i, points in zip(np.ravel(board.getIds()), board.getObjPoints())}


def infer_board(image: NDArray[np.uint8], dictionaries: Sequence[str] | None = None,
                squares: tuple[int, int] | None = None) -> CharucoGeometry | None:
    """The ChArUco board in a gray or BGR uint8 ``image``, its layout inferred from its markers
    (:func:`_fit_layout`, docs/targets.md "ChArUco boards"), or None. ``dictionaries``: those tried (default: the
    largest of every ArUco family; AprilTag families are not made into ChArUco boards); ``squares``: across and
    down, when known (``--board``)."""
    gray = as_gray(image)
    names = list(dictionaries) if dictionaries else [MARKER_FAMILIES[f][-1] for f in ("4x4", "5x5", "6x6", "7x7", "original")]
    for name in names:
        corners, ids = unrefined_markers(gray, name)
        if len(set(ids)) < MIN_INFER_MARKERS or len(set(ids)) != len(ids):
            continue
        geometry = _fit_layout(corners, ids, name, squares)
        if geometry is not None:  # in the smallest dictionary of the family that holds the board's markers
            family = next(members for members in MARKER_FAMILIES.values() if name in members)
            return replace(geometry, dictionary=next(n for n in family if dictionary_size(n) >= geometry.n_markers))
    return None


def _fit_layout(corners: list[NDArray[np.float64]], ids: list[int], dictionary: str,
                squares: tuple[int, int] | None) -> CharucoGeometry | None:
    """The candidate layout (up to :data:`MAX_SQUARES` each way, current or legacy pattern) whose white squares'
    centres fit the most markers' centres to :data:`LAYOUT_FIT_SQUARES` by one homography (a falsely decoded
    marker fits none), the smallest among equals, its markers' side measured through it; or None."""
    centres = np.array([c.mean(axis=0) for c in corners])
    # Pixels per square near each marker, for a marker about 0.7 of its square.
    sides = np.array([np.mean(np.linalg.norm(np.roll(c, -1, axis=0) - c, axis=1)) for c in corners])
    square_px = float(np.median(sides)) / 0.7
    candidates = [squares] if squares is not None else [
        (columns, rows) for columns in range(3, MAX_SQUARES + 1) for rows in range(3, MAX_SQUARES + 1)]
    best: tuple[int, int, CharucoGeometry] | None = None
    for size in candidates:
        for legacy in (False, True):
            if legacy and size[1] % 2:
                continue  # the legacy pattern differs only for an even number of rows
            layout = _layout(tuple(size), legacy)
            held = [k for k, i in enumerate(ids) if i in layout]
            if len(held) < MIN_INFER_MARKERS or (best is not None and len(held) < best[0]):
                continue
            planar = np.array([layout[ids[k]] for k in held], np.float32)
            target = centres[held].astype(np.float32)
            # Least squares first (most layouts miss by squares); RANSAC only to drop a
            # falsely decoded marker from a layout that nearly fits.
            H, _ = cv2.findHomography(planar, target, 0)
            if H is None:
                continue
            miss = np.linalg.norm(cv2.perspectiveTransform(planar.reshape(-1, 1, 2), H).reshape(-1, 2) - target, axis=1)
            mask = miss <= LAYOUT_FIT_SQUARES * square_px
            if not np.all(mask) and np.count_nonzero(miss <= square_px) >= 0.8 * len(held):
                H, mask = cv2.findHomography(planar, target, cv2.RANSAC, LAYOUT_FIT_SQUARES * square_px, maxIters=500)
                if H is None:
                    continue
            inliers = int(np.count_nonzero(mask))
            if inliers < MIN_INFER_MARKERS or inliers < 0.8 * len(held):
                continue
            score = (inliers, -size[0] * size[1])
            if best is not None and score <= (best[0], best[1]):
                continue
            back = np.linalg.inv(H)
            in_squares = [cv2.perspectiveTransform(corners[k].reshape(-1, 1, 2), back).reshape(4, 2)
                          for k, keep in zip(held, np.ravel(mask)) if keep]
            ratio = float(np.median([np.mean(np.linalg.norm(np.roll(q, -1, axis=0) - q, axis=1)) for q in in_squares]))
            if 0.3 <= ratio <= 0.95:
                best = (inliers, -size[0] * size[1], CharucoGeometry(tuple(size), dictionary, round(ratio, 3), legacy))  # type: ignore[arg-type]
    return None if best is None else best[2]


class CharucoTargetDetector(TargetDetector):
    """A ChArUco board's inner corners, by their ids: ``squares`` across and down, its markers'
    predefined ``dictionary``, and their side over its squares' (``marker_ratio``; when not
    given, measured in the first frame that shows the board, with its pattern, current or legacy).
    Found by OpenCV's ``CharucoDetector`` and refined (:meth:`_refined`), or, while the board is
    seen whole, tracked from the prediction (:meth:`_tracked`); each corner is measured as the
    image's saddle point (:func:`~.chessboard.saddle_points`), a frame found with :data:`MIN_CORNERS`."""

    kind = "charuco"

    def __init__(self, squares: tuple[int, int], dictionary: str, marker_ratio: float | None = None) -> None:
        columns, rows = int(squares[0]), int(squares[1])
        if columns < 3 or rows < 3:
            raise UsageError(f"a ChArUco board needs at least 3x3 squares, got {columns}x{rows}")
        self.squares = (columns, rows)
        self.dictionary = dictionary_name(dictionary)
        if dictionary_size(self.dictionary) < columns * rows // 2:
            raise UsageError(f"a {columns}x{rows} ChArUco board has {columns * rows // 2} markers, more than {self.dictionary} holds")
        self.n_points = (columns - 1) * (rows - 1)
        self._grid = board_layout((columns - 1, rows - 1)).astype(np.float32)  # each corner id's (column, row)
        self._geometry = None if marker_ratio is None else CharucoGeometry(self.squares, self.dictionary, float(marker_ratio))
        self._detector = None if self._geometry is None else self._make(self._geometry)
        self._track = PointTrack(self.n_points, max_coast=2)
        self._last_window = GAP_WINDOW_PX[0]  # the refinement's window in the last frame (px)

    @staticmethod
    def _make(geometry: CharucoGeometry) -> cv2.aruco.CharucoDetector:
        parameters = cv2.aruco.CharucoParameters()
        parameters.tryRefineMarkers = True
        return cv2.aruco.CharucoDetector(geometry.board(), parameters, _parameters(cv2.aruco.CORNER_REFINE_NONE))

    def detect(self, image: NDArray[np.uint8], predicted: NDArray[np.float64] | None = None) -> Detection:
        gray = as_gray(image)
        pixels = np.full((self.n_points, 2), np.nan)
        if self._detector is None:
            geometry = infer_board(gray, [self.dictionary], self.squares)
            if geometry is not None:
                self._geometry, self._detector = geometry, self._make(geometry)
        corners, ids, considered = None, None, 0
        prediction = self._track.predict()
        whole = prediction is not None and np.isfinite(prediction).all()  # every corner predicted: tracked, or searched near
        tracked = self._tracked(gray, prediction) if whole and self._detector is not None and self._track.streak >= 2 else None
        if tracked is not None:
            self._track.update(tracked)
            return Detection(tracked, True, self.n_points, 0)
        if self._detector is not None:
            box = self._search_box(gray.shape, prediction) if whole else None
            corners, ids, considered = self._detect_board(gray, box)
            if box is not None and (ids is None or len(ids) < self.n_points):
                corners, ids, considered = self._detect_board(gray, None)
        if corners is not None and ids is not None and len(ids) >= MIN_CORNERS:
            ids = np.ravel(ids).astype(int)
            found = corners.reshape(-1, 2).astype(np.float64)
            pixels[ids] = self._refined(gray, found, ids)
        ok = np.count_nonzero(np.all(np.isfinite(pixels), axis=1)) >= MIN_CORNERS
        if not ok:
            pixels[:] = np.nan
        self._track.update(pixels)
        return Detection(pixels, ok, considered, 0)

    def _tracked(self, gray: NDArray[np.uint8], prediction: NDArray[np.float64]) -> NDArray[np.float64] | None:
        """Every corner refined from the track's ``prediction`` (in the last frame's window), or None
        (the frame is searched) unless every corner moves at most :data:`MAX_REFINE_MOVE_PX`,
        comes back when refined again from a little off, and all fit one homography of the grid."""
        if not inside_image(prediction, self._last_window + 2, gray.shape).all():
            return None
        once, again = refine_twice(gray, prediction, self._last_window, (0.5, -0.5))
        if row_lengths(once - prediction).max() > MAX_REFINE_MOVE_PX or row_lengths(again - once).max() > SETTLED_PX:
            return None
        self._last_window, fit_px = self._window(once, np.arange(self.n_points))
        return saddle_points(gray, once) if fit_px <= GRID_FIT_PX else None

    def _window(self, corners: NDArray[np.float64], ids: NDArray[np.int_]) -> tuple[int, float]:
        """The half-size (px) of the window a corner is refined in (:data:`GAP_WINDOW_FRACTION`),
        and the RMS (px) of ``corners`` (K, 2) from one homography of their ids' grid (inf
        for fewer than 4)."""
        assert self._geometry is not None
        grid = self._grid[ids]
        square, fit_px = 8.0, float("inf")
        if len(ids) >= 4:
            H, _ = cv2.findHomography(grid, corners.astype(np.float32), 0)
            if H is not None:  # the square as seen: the mapped grid's step at each corner
                mapped = cv2.perspectiveTransform(np.concatenate([grid, grid + np.float32((1, 0))]).reshape(-1, 1, 2), H).reshape(2, -1, 2)
                square = plain_median(row_lengths(mapped[1] - corners))
                fit_px = math.sqrt(((mapped[0] - corners) ** 2).sum(axis=1).mean())
        return int(np.clip(np.floor(GAP_WINDOW_FRACTION * (1.0 - self._geometry.marker_ratio) * square), *GAP_WINDOW_PX)), fit_px

    def _search_box(self, shape: tuple[int, ...], prediction: NDArray[np.float64]) -> tuple[int, int, int, int]:
        """The box (x0, y0, x1, y1, px) of the predicted corners (every one), widened (:data:`SEARCH_MARGIN_SQUARES`)."""
        grid = prediction.reshape(self.squares[1] - 1, self.squares[0] - 1, 2)
        square = max(float(np.median(np.linalg.norm(np.diff(grid, axis=axis), axis=-1))) for axis in (0, 1))
        margin = int(np.ceil(SEARCH_MARGIN_SQUARES * square)) + SEARCH_MARGIN_PX
        return padded_box(prediction, margin, shape)

    def _detect_board(self, gray: NDArray[np.uint8], box: tuple[int, int, int, int] | None):
        """OpenCV's board in ``box`` of ``gray`` (None: all): corners (K, 1, 2, px) or None, ids (K, 1) or None, markers found."""
        x0, y0, x1, y1 = box or (0, 0, gray.shape[1], gray.shape[0])
        corners, ids, marker_corners, _ = self._detector.detectBoard(gray[y0:y1, x0:x1])  # type: ignore[union-attr]
        if corners is not None:
            corners = corners.astype(np.float64) + (x0, y0)
        return corners, ids, 0 if marker_corners is None else len(marker_corners)

    def _refined(self, gray: NDArray[np.uint8], corners: NDArray[np.float64], ids: NDArray[np.int_]) -> NDArray[np.float64]:
        """The corners refined again (``cornerSubPix``) in a window inside the gap between a
        corner and its markers (:data:`GAP_WINDOW_FRACTION`: OpenCV's reaches into the markers
        on small boards). A corner that moves farther than :data:`MAX_REFINE_MOVE_PX`
        (:data:`FAR_REFINE_MOVE_PX` where its neighbours agree), or does not come back when
        refined again from a little off, keeps OpenCV's position."""
        window = self._last_window = self._window(corners, ids)[0]
        inside = inside_image(corners, window + 2, gray.shape)
        refined = corners.copy()
        if not np.any(inside):
            return refined
        once_px, again_px = refine_twice(gray, corners[inside], window, (0.5, -0.5))
        moved = np.linalg.norm(once_px - corners[inside], axis=1)
        settled = np.linalg.norm(again_px - once_px, axis=1) <= SETTLED_PX
        good = settled & (moved <= MAX_REFINE_MOVE_PX)
        rows = np.flatnonzero(inside)[good]
        refined[rows] = once_px[good]
        # OpenCV's corner can be off by more than the refinement may move it: a settled
        # refinement a little farther is taken where the corner's neighbours agree with it.
        far = settled & ~good & (moved <= FAR_REFINE_MOVE_PX)
        grid = self._grid[ids]
        for row, once in zip(np.flatnonzero(inside)[far], once_px[far]):
            expected = _from_neighbours(grid, refined, row)
            if expected is not None and np.linalg.norm(once - expected) < min(NEIGHBOUR_AGREEMENT_PX, np.linalg.norm(refined[row] - expected)):
                refined[row] = once
        return saddle_points(gray, refined)


def _from_neighbours(grid: NDArray[np.float32], corners: NDArray[np.float64], row: int) -> NDArray[np.float64] | None:
    """Where corner ``row`` should be by the homography of its neighbours (board corners at
    most two squares away, itself left out; (K, 2) ``grid`` positions and ``corners`` px), or
    None with fewer than six of them. Local: the lens bends the board too little over two
    squares to matter."""
    near = np.flatnonzero(np.max(np.abs(grid - grid[row]), axis=1) <= 2)
    near = near[(near != row) & np.all(np.isfinite(corners[near]), axis=1)]
    if near.size < 6:
        return None
    H, _ = cv2.findHomography(grid[near], corners[near].astype(np.float32), 0)
    return None if H is None else cv2.perspectiveTransform(grid[row].reshape(1, 1, 2), H).reshape(2).astype(np.float64)


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
    if not in_most(found, len(images)):
        return None
    columns, rows = geometry.squares
    reason = (f"ChArUco board of {columns}x{rows} squares ({geometry.dictionary}, {geometry.n_markers} markers) with up to "
              f"{max(seen)} of its {detector.n_points} corners found in {found} of the first {len(images)} frames "
              "(a known grid of sub-pixel corners, each named by its markers)")
    return TargetChoice("charuco", reason, {"board": [columns, rows], "marker_dict": geometry.dictionary}).measured_by(pixels[int(np.argmax(seen))])


def _charuco_spec(request: SpecRequest) -> DetectorSpec:
    """A ChArUco board: its squares and dictionary from --board and --marker-dict, or
    inferred from the first frames' markers (said on stderr)."""
    details = request.details
    if "board" not in details or request.board is not None:
        given = f" {request.board[0]}x{request.board[1]}" if request.board is not None else ""
        details = request.found(find_charuco(request.images, request.marker_dict, request.board), f"ChArUco board{given}",
                                "give --board COLUMNSxROWS and --marker-dict NAME, or another --target", "charuco")
    columns, rows = (int(n) for n in details["board"])
    return DetectorSpec(kind="charuco", n_points=(columns - 1) * (rows - 1), board=(columns, rows), marker_dict=details["marker_dict"])


def _charuco(spec: DetectorSpec, template: NDArray[np.uint8] | None, seed: int, windowed: bool) -> CharucoTargetDetector:
    if spec.board is None or (spec.board[0] - 1) * (spec.board[1] - 1) != spec.n_points:
        raise UsageError(f"a ChArUco target needs its squares across and down ({spec.n_points} inner corners), got {spec.board!r}")
    return CharucoTargetDetector(spec.board, spec.marker_dict or DEFAULT_DICTIONARY)


# Saddle corners named by their markers: a bias of 0.75 point noise (bench/CALIBRATION.md),
# correlated over frames; theta_d 0.35 deg and x_hd1 5e-3.
register_target_kind(TargetKind(
    name="charuco", spec=_charuco_spec, make=_charuco,
    errors=DetectorErrors("charuco", bias_fraction=0.75, expected_precision=(0.35, 5e-3)), precision_scale=7.4,
    shapes=lambda spec: [(range(spec.n_points), board_layout((spec.board[0] - 1, spec.board[1] - 1)))],  # its inner corners
    size_pair=lambda spec, m_ref, normal: board_diagonal(spec.board[0] - 1, spec.board[1] - 1),
    options=frozenset({"marker_dict", "board"}),
))
