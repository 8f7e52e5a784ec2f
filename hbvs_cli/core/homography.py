"""The Euclidean homography ``m_i = alpha_i H m*_i``, ``H = R + x_h n*^T`` (12) between F*
and a current view. Planar motion makes H's third row ``[0, 0, 1]`` (15), so the three-point
method (16)-(18) gets H at its Euclidean scale by linear least squares, batched over frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import (
    CollinearPointsError, NonFiniteInputError, NotEnoughPointsError, PointAtCameraHeightError, PointBehindCameraError,
)

#: Smallest |m*_z| accepted: a point this close to the camera's height (0.06 deg of
#: elevation, 5 mm at 5 m) makes alpha_i = m_iz / m*_iz (18) meaningless.
MIN_REFERENCE_HEIGHT = 1e-3

#: Smallest accepted ratio of the reference design matrix's singular values; below it the
#: reference points are (nearly) collinear and (16)-(17) have no unique solution.
MIN_REFERENCE_CONDITION = 1e-4


@dataclass(frozen=True)
class HomographyEstimate:
    """``H`` (..., 3, 3) in the paper's axes, NaN where ``valid`` (...) is False (non-finite
    input or a depth ratio alpha_i <= 0)."""

    H: NDArray[np.float64]
    valid: NDArray[np.bool_]


def validate_reference_points(m_ref: ArrayLike) -> NDArray[np.float64]:
    """Reference points m*_i (N, 3) checked for the degenerate cases of (16)-(18): fewer than 3,
    non-finite, not ``[1, m*_iy, m*_iz]``, at the camera's height, collinear (typed errors)."""
    m_ref = np.asarray(m_ref, dtype=float)
    if m_ref.ndim != 2 or m_ref.shape[-1] != 3:
        raise NotEnoughPointsError(f"reference points must have shape (N, 3), got {m_ref.shape}")
    if m_ref.shape[0] < 3:
        raise NotEnoughPointsError(f"need at least 3 target points, got {m_ref.shape[0]}")
    if not np.all(np.isfinite(m_ref)):
        raise NonFiniteInputError("reference points contain NaN or infinity")
    if np.any(np.abs(m_ref[:, 0] - 1.0) > 1e-9):
        raise PointBehindCameraError(
            "reference points must be normalised as m = [1, m_y, m_z] (a point in front of the camera)"
        )
    low = np.flatnonzero(np.abs(m_ref[:, 2]) < MIN_REFERENCE_HEIGHT)
    if low.size:
        raise PointAtCameraHeightError(
            f"target point {int(low[0])} lies at the camera's height (m*_z = {m_ref[low[0], 2]:.2e}); "
            "equation (18) needs every point clearly above or below the camera"
        )
    singular = np.linalg.svd(m_ref, compute_uv=False)
    if singular[-1] < MIN_REFERENCE_CONDITION * singular[0]:
        raise CollinearPointsError(
            "the reference target points are collinear (or nearly): a plane needs three points "
            "that span a triangle"
        )
    return m_ref


def depth_ratios(m: ArrayLike, m_ref: ArrayLike) -> NDArray[np.float64]:
    """Depth ratios ``alpha_i = m_iz / m*_iz`` (18), shape (..., N), of points (..., N, 3)."""
    m = np.asarray(m, dtype=float)
    m_ref = np.asarray(m_ref, dtype=float)
    return m[..., 2] / m_ref[:, 2]


def ratio_rows(m: NDArray[np.float64], m_ref: NDArray[np.float64]) -> tuple[NDArray[np.bool_], NDArray[np.float64]]:
    """The right-hand sides ``(1 / alpha_i, m_iy / alpha_i)`` (..., N, 2) of rows 1 and 2 of (12)
    (:func:`estimate_euclidean_homography`), and ``valid`` (...): finite points, every alpha_i > 0."""
    alpha = depth_ratios(m, m_ref)
    valid = np.all(np.isfinite(m), axis=(-1, -2)) & np.all(alpha > 0.0, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_alpha = 1.0 / alpha
        return valid, np.stack([inv_alpha, m[..., 1] * inv_alpha], axis=-1)


def estimate_euclidean_homography(m: ArrayLike, m_ref: ArrayLike) -> HomographyEstimate:
    """Euclidean homography by the paper's three-point method, (16)-(18).

    Rows 1 and 2 of (12) read ``m*_i . h_1 = 1 / alpha_i`` and ``m*_i . h_2 = m_iy / alpha_i``:
    least squares over the N >= 3 points ``m`` (..., N, 3), in the order of ``m_ref`` (N, 3).
    """
    m_ref = validate_reference_points(m_ref)
    m = np.asarray(m, dtype=float)
    if m.shape[-2:] != m_ref.shape:
        raise NotEnoughPointsError(
            f"current points have shape {m.shape[-2:]} but the reference has {m_ref.shape}: "
            "every reference point needs its current image"
        )
    valid, rhs = ratio_rows(m, m_ref)  # (...), (..., N, 2)
    # One pseudo-inverse of the reference design serves every frame and both rows.
    design_pinv = np.linalg.pinv(m_ref)  # (3, N)
    rows = np.einsum("kn,...nr->...rk", design_pinv, rhs)  # (..., 2, 3)
    H = np.zeros(m.shape[:-2] + (3, 3))
    H[..., :2, :] = rows
    H[..., 2, 2] = 1.0
    H[~valid] = np.nan
    return HomographyEstimate(H=H, valid=valid)


def transfer_points(H: ArrayLike, m_ref: ArrayLike) -> NDArray[np.float64]:
    """Predicted points ``m_i = alpha_i H m*_i`` (..., N, 3), normalised to ``[1, m_y, m_z]``."""
    projected = np.einsum("...ij,nj->...ni", np.asarray(H, dtype=float), np.asarray(m_ref, dtype=float))
    return projected / projected[..., :1]
