"""Choosing a detector: :func:`make_detector` for a target kind, :func:`guess_target_kind` for a frame."""

from __future__ import annotations

from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import UsageError
from .aruco import DEFAULT_DICTIONARY, ArucoMarkerDetector, marker_ids_in_view
from .charuco import CharucoTargetDetector
from .chessboard import ChessboardDetector
from .base import TargetDetector, as_gray
from .dot_windows import WindowedDotDetector
from .dots import DotDetector, find_dark_blobs
from .texture import TextureDetector


def make_detector(
    kind: str,
    *,
    n_points: int,
    reference_image: NDArray[np.uint8] | None = None,
    reference_pixels: ArrayLike | None = None,
    marker_id: int | None = None,
    seed: int = 0,
    marker_dict: str | None = None,
    marker_ids: Sequence[int] | None = None,
    polarity: str | None = None,
    contrast: str | None = None,
    windowed: bool = False,
    board: tuple[int, int] | None = None,
) -> TargetDetector:
    """A detector for ``kind`` (``"dots"``, ``"aruco"``, ``"chessboard"``, ``"charuco"`` or ``"texture"``).

    ``texture`` needs ``reference_image`` and the target's ``reference_pixels`` (N, 2) in it
    (``seed``: its robust sampling); ``aruco`` takes ``marker_id`` (None: the only marker in
    view) or ``marker_ids`` (4 corners each) from ``marker_dict``; ``dots`` takes
    ``polarity``, ``contrast`` and ``windowed`` (each dot in its own window); ``chessboard``
    needs ``board`` (inner corners per row, rows), ``charuco`` the board's squares across and
    down. UsageError for inconsistent arguments.
    """
    if kind == "dots":
        dots = WindowedDotDetector if windowed else DotDetector
        return dots(n_points, polarity=polarity or "dark", contrast=contrast or "gray")
    if kind == "aruco":
        markers = ArucoMarkerDetector(marker_id, dictionary=marker_dict or DEFAULT_DICTIONARY, marker_ids=marker_ids)
        if n_points != markers.n_points:
            raise UsageError(f"a target of {len(markers.marker_ids) or 1} marker(s) has {markers.n_points} points (their corners), not {n_points}")
        return markers
    if kind == "texture":
        if reference_image is None or reference_pixels is None:
            raise UsageError("a texture detector needs a reference image and the target's pixels in it")
        detector = TextureDetector(reference_image, reference_pixels, seed=seed)
        if detector.n_points != n_points:
            raise UsageError(f"{detector.n_points} reference pixels given for a {n_points}-point target")
        return detector
    if kind == "chessboard":
        if board is None or board[0] * board[1] != n_points:
            raise UsageError(f"a chessboard target needs its pattern of inner corners ({n_points} points), got {board!r}")
        return ChessboardDetector(board)
    if kind == "charuco":
        if board is None or (board[0] - 1) * (board[1] - 1) != n_points:
            raise UsageError(f"a ChArUco target needs its squares across and down ({n_points} inner corners), got {board!r}")
        return CharucoTargetDetector(board, marker_dict or DEFAULT_DICTIONARY)
    raise UsageError(f"unknown target kind {kind!r}: choose one of dots, aruco, chessboard, charuco, texture")


def guess_target_kind(image: NDArray[np.uint8]) -> str:
    """Which kind of target a frame shows: ``"aruco"`` if a marker is detected; ``"dots"`` if 3
    or more similar dark round blobs make up most of the dark structure; else ``"texture"``."""
    gray = as_gray(image)
    if marker_ids_in_view(gray):
        return "aruco"
    blobs = find_dark_blobs(gray)
    round_blobs = blobs.areas[blobs.round]
    if round_blobs.size >= 3:
        median = np.median(round_blobs)
        similar = int(np.count_nonzero((round_blobs > median / 3) & (round_blobs < median * 3)))
        # Components cut by the frame's edge (typically the wall) are not counted.
        interior = int(np.count_nonzero(~blobs.touches_edge))
        if similar >= 3 and similar >= 0.75 * interior:
            return "dots"
    return "texture"
