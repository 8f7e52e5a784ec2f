"""The target's known layout (``--target-points``, any order) matched to its detected points:
the right order is the one under which one homography carries the layout onto the image."""

from __future__ import annotations

from itertools import permutations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import GeometryError
from .assignment import optimal_assignment
from .plane import procrustes_2d

#: A match whose RMS distance (after the best homography) is above this fraction of the
#: image points' RMS spread is refused: the layout is not the target's.
MAX_MATCH_SPREAD = 0.05


def _normalised(points: NDArray[np.float64]) -> NDArray[np.float64]:
    centred = points - points.mean(axis=0)
    spread = float(np.sqrt(np.mean(np.sum(centred**2, axis=1))))
    return centred / spread if spread > 0 else centred


def _homographies(source: NDArray[np.float64], target: NDArray[np.float64]) -> NDArray[np.float64]:
    """The homographies (K, 3, 3) that carry each of K sets of M >= 4 source points (K, M, 2)
    onto the M target points (M, 2) (direct linear transform: exact for 4 points, least
    squares of the algebraic error for more)."""
    k = source.shape[0]
    x, y = source[..., 0], source[..., 1]
    u, v = np.broadcast_to(target[:, 0], x.shape), np.broadcast_to(target[:, 1], x.shape)
    zeros, ones = np.zeros_like(x), np.ones_like(x)
    rows_u = np.stack([x, y, ones, zeros, zeros, zeros, -u * x, -u * y, -u], axis=-1)
    rows_v = np.stack([zeros, zeros, zeros, x, y, ones, -v * x, -v * y, -v], axis=-1)
    design = np.concatenate([rows_u, rows_v], axis=1)  # (K, 8, 9)
    _, _, vt = np.linalg.svd(design)
    return vt[:, -1, :].reshape(k, 3, 3)


def _similarities(source: NDArray[np.float64], target: NDArray[np.float64]) -> NDArray[np.float64]:
    """The similarities (K, 3, 3) (reflection allowed) best carrying each of K ordered sets of
    source points (K, M, 2) onto the target points (M, 2) (Procrustes)."""
    t_mean = target.mean(axis=0)
    s_mean = source.mean(axis=1)  # (K, 2)
    s_centred = source - s_mean[:, None, :]
    factor, singular_sum = procrustes_2d(np.einsum("kmi,mj->kij", s_centred, target - t_mean))
    scale = singular_sum / np.maximum(np.sum(s_centred**2, axis=(1, 2)), 1e-300)
    linear = scale[:, None, None] * np.swapaxes(factor, 1, 2)
    out = np.zeros((source.shape[0], 3, 3))
    out[:, :2, :2] = linear
    out[:, :2, 2] = t_mean - np.einsum("kij,kj->ki", linear, s_mean)
    out[:, 2, 2] = 1.0
    return out


def _apply(transforms: NDArray[np.float64], points: NDArray[np.float64]) -> NDArray[np.float64]:
    """``points`` (N, 2) through each of K transforms, shape (K, N, 2)."""
    homogeneous = np.concatenate([points, np.ones((points.shape[0], 1))], axis=1)
    mapped = np.einsum("kij,nj->kni", transforms, homogeneous)
    with np.errstate(divide="ignore", invalid="ignore"):
        return mapped[..., :2] / mapped[..., 2:3]


def _spread_corners(points: NDArray[np.float64]) -> list[int]:
    """Four well-spread, distinct points: the extremes along the two diagonals."""
    picks: list[int] = []
    for score in (points[:, 0] + points[:, 1], points[:, 0] - points[:, 1], -points[:, 0] - points[:, 1], points[:, 1] - points[:, 0]):
        for index in np.argsort(-score):
            if int(index) not in picks:
                picks.append(int(index))
                break
    return picks


def match_layout(layout: ArrayLike, image: ArrayLike) -> NDArray[np.intp]:
    """The order (N,) that puts ``layout`` (N, 2), points in the wall's plane in any unit, in
    the order of ``image`` (N, 2), e.g. F*'s ``(m_y, m_z)``; GeometryError when none fits.

    Four well-spread image points are matched to every ordered four of the layout's; each
    homography carries the layout over and the least-squares assignment pairs the rest. Three
    or four points, which any homography matches, take the best similarity, mirror included.
    """
    layout = np.asarray(layout, dtype=np.float64)
    image = np.asarray(image, dtype=np.float64)
    n = image.shape[0]
    if layout.shape != image.shape or layout.ndim != 2 or layout.shape[1] != 2:
        raise GeometryError(f"the known layout has {layout.shape[0]} points, the target {image.shape[0]}")
    if n > 10:
        # Many points (a board's corners, several markers'): the order must be the
        # detector's own (row by row, marker by marker); it is checked, not searched.
        candidates = np.arange(n)[None, :]
        chosen = list(range(n))
    elif n >= 5:
        chosen = _spread_corners(image)
        candidates = np.array(list(permutations(range(n), 4)), dtype=np.intp)
    else:
        chosen = list(range(n))
        candidates = np.array(list(permutations(range(n), n)), dtype=np.intp)
    # Both point sets centred and scaled to unit spread: the direct linear transform is
    # then well conditioned, whatever the units.
    layout_n, image_n = _normalised(layout), _normalised(image)
    transforms = (_homographies if n >= 5 else _similarities)(layout_n[candidates], image_n[chosen])
    mapped = _apply(transforms, layout_n)  # (K, N, 2)
    distance = np.sum((mapped[:, :, None, :] - image_n[None, None, :, :]) ** 2, axis=-1)  # (K, layout, image)
    distance = np.where(np.isfinite(distance), distance, np.inf)
    # Nearest image point of each mapped layout point: a quick score, then the assignment
    # on the best few.
    quick = distance.min(axis=2).sum(axis=1)
    best_order, best_cost = None, np.inf
    for k in np.argsort(quick)[:10]:
        if not np.all(np.isfinite(distance[k])):
            continue
        rows, cols = optimal_assignment(distance[k])
        cost = float(distance[k][rows, cols].sum())
        if cost < best_cost:
            order = np.empty(n, dtype=np.intp)
            order[cols] = rows
            best_order, best_cost = order, cost
    if best_order is None or np.sqrt(best_cost / n) > MAX_MATCH_SPREAD:
        raise GeometryError("the known layout of the target points does not match the points seen in F* under any order")
    return best_order
