"""``--target-points``: the target points' positions on the wall, a CSV of ``x,y`` (m) per line in
the wall's plane, any origin, orientation and order (the fit matches them by their layout); a header,
blank lines and lines starting with ``#`` are skipped."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from .text_files import read_small_text

#: Largest file accepted (bytes): a target has a few dozen points.
MAX_POINTS_BYTES = 1 << 20
#: A target has at most this many points (hbvs's largest target: a board's corners).
MAX_POINTS = 1000
#: The distance between a target's two points farthest apart (m), at least and at most: a
#: file outside is in another unit (or scaled by mistake), and its d* would be refused by
#: repeat's --dhat0 bounds only after the fit (issue 46: positions scaled by 1e150).
SPAN_RANGE_M = (1e-3, 1e3)
#: Largest |x| or |y| (m) of a position: the origin may be anywhere, but on the wall.
MAX_COORDINATE_M = 1e4


def read_target_points(path: str | Path) -> NDArray[np.float64]:
    """The points of a ``--target-points`` CSV, shape (N, 2) (m): 3 to :data:`MAX_POINTS`, all
    distinct, within :data:`MAX_COORDINATE_M` of the origin, spanning :data:`SPAN_RANGE_M`."""
    name = str(path)
    text = read_small_text(path, MAX_POINTS_BYTES, "a CSV file of x,y positions in metres")
    rows = []
    try:
        for line_number, row in enumerate(csv.reader(io.StringIO(text)), start=1):
            cells = [cell.strip() for cell in row]
            if not cells or all(not cell for cell in cells) or cells[0].startswith("#"):
                continue
            try:
                values = [float(cell) for cell in cells if cell]
            except ValueError:
                if not rows and line_number == 1:
                    continue  # a header
                raise InputError(f"{name}: line {line_number} is not two numbers x,y (m): {','.join(cells)[:60]}") from None
            if len(values) != 2 or not all(np.isfinite(values)):
                raise InputError(f"{name}: line {line_number} must hold two finite numbers x,y (m), got {','.join(cells)[:60]}")
            rows.append(values)
    except csv.Error as exc:
        raise InputError(f"{name}: not a CSV file ({exc})") from None
    if not 3 <= len(rows) <= MAX_POINTS:
        raise InputError(f"{name}: a target needs 3 to {MAX_POINTS} points, the file has {len(rows)}")
    points = np.array(rows, dtype=np.float64)
    if np.abs(points).max() > MAX_COORDINATE_M:
        raise InputError(f"{name}: a position is {np.abs(points).max():.3g} m from the origin (at most {MAX_COORDINATE_M:g} m); "
                         "are the positions in metres?")
    gaps = np.linalg.norm(points[:, None, :] - points[None, :, :], axis=-1)
    if (gaps + np.eye(len(points))).min() <= 0.0:
        raise InputError(f"{name}: two points are at the same place")
    low, high = SPAN_RANGE_M
    if not low <= gaps.max() <= high:
        raise InputError(f"{name}: the points are {gaps.max():.3g} m apart at most; a target spans {low:g} to {high:g} m: "
                         "are the positions in metres?")
    return points
