"""A printed chessboard as the target: its inner corners, row by row in the first detection's order.

The grid (:func:`board_layout`) is a shape known up to a similarity: it pins n*.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache, partial
from typing import Sequence

import cv2
import numpy as np
from numpy.typing import NDArray

from ..core.desired import DetectorErrors
from ..core.fit_model import DetectorSpec
from ..errors import UsageError
from ..thread_pool import StopSafePool
from .base import Detection, PointTrack, TargetDetector, as_gray, check_prediction, padded_box, plain_median, row_lengths
from .target_kinds import SpecRequest, TargetChoice, TargetKind, in_most, register_target_kind

#: Half-size of the window ``cornerSubPix`` refines a corner in, as a fraction of the
#: board's square as seen, and its bounds (px).
REFINE_WINDOW_SQUARES = 0.6
REFINE_WINDOW_PX = (2, 8)
#: A tracked frame's corners must fit the board's homography to this RMS (px).
GRID_FIT_PX = 0.35
#: A tracked corner may lie this far (px) from its prediction at most (from farther, the
#: refinement on small squares can settle on the grid but off the corners): else searched.
MAX_TRACKED_MOVE_PX = 1.5
#: A refined corner, refined again from RESTART_OFFSET_PX away, must come back within SETTLED_PX.
RESTART_OFFSET_PX = (0.7, -0.7)
SETTLED_PX = 0.1
#: A board needs at least this many inner corners along each side.
MIN_SIDE = 3


@dataclass(frozen=True)
class Board:
    """A chessboard found in an image: its ``pattern`` (inner corners per row, rows: OpenCV's
    ``patternSize``) and ``corners`` (columns * rows, 2), row by row (px)."""

    pattern: tuple[int, int]
    corners: NDArray[np.float64]


def find_board(image: NDArray[np.uint8], pattern: tuple[int, int] | None = None) -> Board | None:
    """The chessboard in a gray or BGR uint8 ``image`` by ``findChessboardCornersSB``, or None;
    ``pattern``: inner corners per row and rows (None: the largest board of at least 3x3, its
    pattern reported)."""
    gray = as_gray(image)
    found = _cached_search(gray.shape, gray.tobytes(), None if pattern is None else (int(pattern[0]), int(pattern[1])))
    return None if found is None else Board(found.pattern, found.corners.copy())


def find_board_near(image: NDArray[np.uint8], pattern: tuple[int, int], corners: NDArray[np.float64]) -> Board | None:
    """The board of ``pattern`` searched for only in a window around ``corners`` (px, a
    nearby frame's), grown by their extent and by :data:`NEAR_MARGIN_PX` at least on each
    side, or None. A search's time goes with its image's area: a board a sixth of the frame
    wide is found about 8 times sooner. A window of the whole frame is :func:`find_board`'s."""
    gray = as_gray(image)
    grow = max(float(np.ptp(corners, axis=0).max()), NEAR_MARGIN_PX)
    x0, y0, x1, y1 = padded_box(corners, grow, gray.shape)
    if x0 == 0 and y0 == 0 and x1 == gray.shape[1] and y1 == gray.shape[0]:
        return find_board(gray, pattern)
    found = _search(np.ascontiguousarray(gray[y0:y1, x0:x1]), pattern)
    return None if found is None else Board(found.pattern, found.corners + (x0, y0))


#: The least margin (px) of :func:`find_board_near`'s window.
NEAR_MARGIN_PX = 32


@lru_cache(maxsize=8)
def _cached_search(shape: tuple[int, ...], pixels: bytes, pattern: tuple[int, int] | None) -> Board | None:
    """The last few searches by image and pattern: fit searches its first frames twice (to pick the target, then to track it)."""
    return _search(np.frombuffer(pixels, dtype=np.uint8).reshape(shape), pattern)


def _search(gray: NDArray[np.uint8], pattern: tuple[int, int] | None) -> Board | None:
    flags = cv2.CALIB_CB_ACCURACY | cv2.CALIB_CB_NORMALIZE_IMAGE
    if pattern is None:
        found, corners, meta = cv2.findChessboardCornersSBWithMeta(gray, (MIN_SIDE, MIN_SIDE), flags | cv2.CALIB_CB_LARGER)
        pattern = None if meta is None else (int(meta.shape[1]), int(meta.shape[0]))  # meta: rows by columns
    else:
        found, corners = cv2.findChessboardCornersSB(gray, pattern, flags=flags)
    if not found or corners is None or pattern is None:
        return None
    return Board(pattern, corners.reshape(-1, 2).astype(np.float64))


def board_layout(pattern: tuple[int, int]) -> NDArray[np.float64]:
    """The inner corners' grid coordinates (in squares), row by row: shape (columns * rows, 2)."""
    columns, rows = pattern
    return np.array([[c, r] for r in range(rows) for c in range(columns)], dtype=np.float64)


class ChessboardDetector(TargetDetector):
    """A chessboard's inner corners (``pattern``: per row, rows), tracked from frame to frame.

    A frame is searched by ``findChessboardCornersSB`` (:func:`find_board`) until the track
    is known; then every corner is refined from its prediction (``cornerSubPix``), must fit one
    homography of the grid, and is re-measured as the image's saddle point (:func:`saddle_points`).
    A later search is put back in the track's order (the board's half-turn symmetry can flip OpenCV's).
    """

    kind = "chessboard"

    def __init__(self, pattern: tuple[int, int]) -> None:
        self.pattern = (int(pattern[0]), int(pattern[1]))
        self.n_points = self.pattern[0] * self.pattern[1]
        self._layout = board_layout(self.pattern).astype(np.float32)
        self._track = PointTrack(self.n_points, max_coast=2)

    def detect(self, image: NDArray[np.uint8], predicted: NDArray[np.float64] | None = None) -> Detection:
        gray = as_gray(image)
        given = check_prediction(predicted, self.n_points)
        prediction = given if given is not None else self._track.predict()
        # Refined from the track's prediction only once its velocity is known (from a
        # prediction a board's motion off, it can settle on the grid but off the corners).
        trusted = given is not None or self._track.streak >= 2
        usable = prediction is not None and np.all(np.isfinite(prediction))
        corners = self._refined(gray, prediction) if trusted and usable else None
        searched = corners is None
        if searched:
            board = find_board(gray, self.pattern)
            if board is not None:  # the search's corners, in the track's order, refined as a tracked frame's are
                corners = self._refined(gray, self._in_track_order(board.corners, prediction) if usable else board.corners)
        found = corners is not None
        pixels = corners if found else np.full((self.n_points, 2), np.nan)
        self._track.update(pixels)
        return Detection(pixels, found, self.n_points if found else int(searched), 0)

    def _in_track_order(self, corners: NDArray[np.float64], prediction: NDArray[np.float64]) -> NDArray[np.float64]:
        """A search's corners in the track's order: of the grid's four orderings (rows and
        columns each forward or reversed), the one closest to the prediction as a whole."""
        columns, rows = self.pattern
        grid = np.arange(self.n_points).reshape(rows, columns)
        orders = [grid, grid[::-1], grid[:, ::-1], grid[::-1, ::-1]]
        distances = [float(np.sum((corners[order.ravel()] - prediction) ** 2)) for order in orders]
        return corners[orders[int(np.argmin(distances))].ravel()]

    def _refined(self, gray: NDArray[np.uint8], prediction: NDArray[np.float64]) -> NDArray[np.float64] | None:
        """Every corner refined from its prediction, or None when they do not fit the grid."""
        grid = prediction.reshape(self.pattern[1], self.pattern[0], 2)
        square = plain_median(row_lengths(np.diff(grid, axis=1).reshape(-1, 2)))
        window = int(np.clip(min(np.floor(REFINE_WINDOW_SQUARES * square), square - 2.0), *REFINE_WINDOW_PX))
        if not inside_image(prediction, window + 2, gray.shape).all():
            return None
        corners, settled = refine_twice(gray, prediction, window, RESTART_OFFSET_PX)
        # A corner draws the refinement from all around: started again a little off, it must come back.
        if row_lengths(corners - prediction).max() > MAX_TRACKED_MOVE_PX or row_lengths(settled - corners).max() > SETTLED_PX:
            return None
        H, _ = cv2.findHomography(self._layout, corners.astype(np.float32), 0)
        if H is None:
            return None
        fitted = cv2.perspectiveTransform(self._layout.reshape(-1, 1, 2), H).reshape(-1, 2)
        if math.sqrt(((fitted - corners) ** 2).sum(axis=1).mean()) > GRID_FIT_PX:
            return None
        if not board_corners_cross(gray, corners, self.pattern):
            return None
        return saddle_points(gray, corners, CHESSBOARD_SMOOTHING_PX)


#: The saddle fit (:func:`saddle_points`): the image's Gaussian smoothing (px; more for a plain
#: chessboard, whose crossings stay symmetric farther out than a ChArUco board's), the radius
#: (px) of the weight ``exp(-d^2 / r^2)`` on the pixels fitted, the passes, a pass's largest step (px).
#: Two passes: from ``cornerSubPix``'s corners the second moves them a few thousandths of a
#: pixel at most, and a third a few millionths.
SADDLE_SMOOTHING_PX = 0.8
CHESSBOARD_SMOOTHING_PX = 1.2
SADDLE_RADIUS_PX = 1.5
SADDLE_PASSES = 2
SADDLE_MAX_STEP_PX = 1.0


def inside_image(corners: NDArray[np.float64], margin: int, shape: tuple[int, ...]) -> NDArray[np.bool_]:
    """Which corners (K, 2, px) are at least ``margin`` px inside an image of ``shape``."""
    return ((corners >= margin) & (corners <= (shape[1] - 1 - margin, shape[0] - 1 - margin))).all(axis=1)


def refine_twice(gray: NDArray[np.uint8], points: NDArray[np.float64], window: int,
                 offset: tuple[float, float]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``cornerSubPix`` of ``points`` (N, 2), and of the result moved by ``offset`` (px): a
    true corner draws the second refinement back to the first."""
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 40, 0.001)
    once = points.astype(np.float32).reshape(-1, 1, 2)
    cv2.cornerSubPix(gray, once, (window, window), (-1, -1), criteria)
    again = once + np.float32(offset)
    cv2.cornerSubPix(gray, again, (window, window), (-1, -1), criteria)
    return once.reshape(-1, 2).astype(np.float64), again.reshape(-1, 2).astype(np.float64)


def _saddle_window() -> tuple[int, NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The saddle fit's window: its reach (px), pixel offsets (P,), the quadratic's design
    (P^2, 6) and its columns' products (P^2, 36), the same for every window (fitted in its
    own offsets; only the weight, centred on the estimate, differs)."""
    reach = int(np.ceil(SADDLE_RADIUS_PX)) + 1
    offsets = np.arange(-reach, reach + 1, dtype=np.float64)
    x, y = np.tile(offsets, offsets.size), np.repeat(offsets, offsets.size)
    design = np.column_stack([x * x, x * y, y * y, x, y, np.ones_like(x)])
    return reach, offsets, design, (design[:, :, None] * design[:, None, :]).reshape(-1, 36)


_SADDLE_WINDOW = _saddle_window()


def saddle_points(gray: NDArray[np.uint8], corners: NDArray[np.float64], smoothing: float = SADDLE_SMOOTHING_PX) -> NDArray[np.float64]:
    """Chessboard corners (K, 2, px) re-measured as the saddle points of the image around them.

    Where two dark and two light squares meet, the image smoothed (Gaussian, sigma
    ``smoothing`` px) is a saddle: a quadratic ``a x^2 + b x y + c y^2 + d x + e y + f``
    fitted by weighted least squares to the pixels near the corner has its stationary point
    there, whatever the squares' angles. Each pass fits around the last estimate and moves
    to the saddle; a fit that is not a saddle (``4 a c >= b^2``) or would move more than
    :data:`SADDLE_MAX_STEP_PX` leaves the corner.
    """
    reach, offsets, design, products = _SADDLE_WINDOW
    size = offsets.size
    refined = np.array(corners, dtype=np.float64)
    start = refined.copy()
    # Only the board's box (and what a step and the smoothing reach) is smoothed.
    border = reach + int(np.ceil(SADDLE_MAX_STEP_PX)) + int(np.ceil(4 * smoothing))
    x0, y0, x1, y1 = padded_box(refined, border, gray.shape)
    if x1 <= x0 or y1 <= y0:
        return refined
    smooth = cv2.GaussianBlur(gray[y0:y1, x0:x1].astype(np.float32), (0, 0), smoothing)
    pixels = smooth.ravel()
    window = (np.arange(size)[:, None] * smooth.shape[1] + np.arange(size)).ravel()  # a window's pixels from its corner
    limit = np.array([smooth.shape[1] - reach, smooth.shape[0] - reach])
    refined -= (x0, y0)
    for _ in range(SADDLE_PASSES):
        centre = np.rint(refined).astype(np.intp)
        inside = ((centre >= reach) & (centre < limit)).all(axis=1)
        every = inside.all()
        if not every:
            if not inside.any():
                break
            centre = centre[inside]
        values = pixels[((centre[:, 1] - reach) * smooth.shape[1] + centre[:, 0] - reach)[:, None] + window].astype(np.float64)
        fraction = (refined if every else refined[inside]) - centre  # the estimate in its window's offsets
        along = np.exp(-((offsets - fraction[:, :, None]) ** 2) / SADDLE_RADIUS_PX**2)  # (K, 2, P)
        weight = (along[:, 1, :, None] * along[:, 0, None, :]).reshape(len(centre), -1)  # exp(-d^2 / r^2)
        normal = (weight @ products).reshape(-1, 6, 6)
        a, b, c, d, e, _ = np.linalg.solve(normal, ((weight * values) @ design)[..., None])[..., 0].T
        determinant = 4.0 * a * c - b * b
        saddle = determinant < 0.0
        safe = np.where(saddle, determinant, -1.0)
        # The stationary point of the quadratic: [2a b; b 2c] point = -[d e].
        step = np.empty_like(fraction)
        step[:, 0], step[:, 1] = (-2.0 * c * d + b * e) / safe, (-2.0 * a * e + b * d) / safe
        step -= fraction
        accept = saddle & (np.hypot(step[:, 0], step[:, 1]) <= SADDLE_MAX_STEP_PX)
        if every:
            refined[accept] += step[accept]
        else:
            moved = refined[inside]
            moved[accept] += step[accept]
            refined[inside] = moved
    refined += (x0, y0)
    far = np.hypot(*(refined - start).T) > SADDLE_MAX_STEP_PX
    refined[far] = start[far]
    return refined


#: A corner is where two dark and two light squares meet: dark along one diagonal, light along
#: the other, by at least this fraction of the local contrast (a square's centre, where
#: ``cornerSubPix`` also settles, is one colour all round).
MIN_CROSSING_CONTRAST = 0.3


def board_corners_cross(gray: NDArray[np.uint8], corners: NDArray[np.float64], pattern: tuple[int, int]) -> bool:
    """True when every corner is a crossing of two dark and two light squares."""
    grid = corners.reshape(pattern[1], pattern[0], 2)
    along = _grid_step(grid, 1)  # one square along a row, at every corner
    across = _grid_step(grid, 0) if pattern[1] > 1 else np.stack([-along[..., 1], along[..., 0]], axis=-1)
    first, second = 0.3 * (along + across), 0.3 * (along - across)
    points = np.rint(np.stack([grid + first, grid - first, grid + second, grid - second]))
    height, width = gray.shape
    levels = gray[np.clip(points[..., 1], 0, height - 1).astype(int), np.clip(points[..., 0], 0, width - 1).astype(int)].astype(np.float64)
    contrast = np.maximum(levels.max(axis=0) - levels.min(axis=0), 1.0)
    one, other = 0.5 * (levels[0] + levels[1]), 0.5 * (levels[2] + levels[3])
    # Opposite squares alike (a board's outer corner, two squares and the white margin, is not).
    alike = (np.abs(levels[0] - levels[1]) <= MIN_CROSSING_CONTRAST * contrast) & (np.abs(levels[2] - levels[3]) <= MIN_CROSSING_CONTRAST * contrast)
    crossing = alike & (np.abs(one - other) >= (1.0 - MIN_CROSSING_CONTRAST) * contrast) & (contrast >= 10.0)
    return bool(crossing.all())


def _grid_step(grid: NDArray[np.float64], axis: int) -> NDArray[np.float64]:
    """``np.gradient(grid, axis=axis)`` (central differences, one-sided at the ends) of a
    (rows, columns, 2) grid, without its overhead."""
    values = grid if axis == 0 else grid.swapaxes(0, 1)
    step = np.empty_like(values)
    step[1:-1] = (values[2:] - values[:-2]) / 2.0
    step[0], step[-1] = values[1] - values[0], values[-1] - values[-2]
    return step if axis == 0 else step.swapaxes(0, 1)


def board_diagonal(columns: int, rows: int) -> tuple[tuple[int, int], float]:
    """A grid's first and last corners, and their distance in squares (--target-size is a square's side)."""
    return (0, columns * rows - 1), math.hypot(columns - 1, rows - 1)


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
    if not in_most(found, len(images)):
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


def _chessboard_spec(request: SpecRequest) -> DetectorSpec:
    """The board ``--target auto`` found, else the one most of the first frames show."""
    board = request.details.get("board")
    if board is None:
        board = request.found(find_chessboard(request.images), "chessboard", "or choose another --target")["board"]
    return DetectorSpec(kind="chessboard", n_points=int(board[0] * board[1]), board=(int(board[0]), int(board[1])))


def _chessboard(spec: DetectorSpec, template: NDArray[np.uint8] | None, seed: int, windowed: bool) -> ChessboardDetector:
    if spec.board is None or spec.board[0] * spec.board[1] != spec.n_points:
        raise UsageError(f"a chessboard target needs its pattern of inner corners ({spec.n_points} points), got {spec.board!r}")
    return ChessboardDetector(spec.board)


# Saddle corners: a bias of 1.25 point noise (1 gave 92.8 % coverage; bench/CALIBRATION.md),
# correlated over frames; theta_d 0.35 deg and x_hd1 5e-3.
register_target_kind(TargetKind(
    name="chessboard", spec=_chessboard_spec, make=_chessboard,
    errors=DetectorErrors("chessboard", bias_fraction=1.25, expected_precision=(0.35, 5e-3)), precision_scale=10.4,
    shapes=lambda spec: [(range(spec.n_points), board_layout(spec.board))],
    size_pair=lambda spec, m_ref, normal: board_diagonal(*spec.board),
))
