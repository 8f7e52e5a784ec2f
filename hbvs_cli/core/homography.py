"""The Euclidean homography between the reference view F* and a current view, (12)-(18).

``m_i = alpha_i H m*_i``, ``H = R + x_h n*^T`` (12). Planar motion makes H's third row
``[0, 0, 1]`` (15), so the paper's three-point method (16)-(18) gets H at its Euclidean scale
by linear least squares; the projective route (N >= 4, normalised DLT, then scale and sign)
does not assume planar motion. Batched: points ``(..., N, 3)`` against one reference (N, 3)
whose system is factored once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import (
    CollinearPointsError, NonFiniteInputError, NotEnoughPointsError, PointAtCameraHeightError, PointBehindCameraError,
)
from .camera import CameraIntrinsics
from .frames import opencv_to_paper_homography

#: Smallest |m*_z| accepted: a point this close to the camera's height (0.06 deg of
#: elevation, 5 mm at 5 m) makes alpha_i = m_iz / m*_iz (18) meaningless.
MIN_REFERENCE_HEIGHT = 1e-3

#: Smallest accepted ratio of the reference design matrix's singular values; below it the
#: reference points are (nearly) collinear and (16)-(17) have no unique solution.
MIN_REFERENCE_CONDITION = 1e-4


@dataclass(frozen=True)
class HomographyEstimate:
    """A batch of Euclidean homographies and what came with them.

    ``H`` (..., 3, 3) in the paper's axes and ``depth_ratios`` alpha_i (..., N), NaN where
    ``valid`` (...) is False (non-finite input or a depth ratio <= 0); ``residual`` (...):
    RMS transfer error (normalised units), for outlier gating.
    """

    H: NDArray[np.float64]
    depth_ratios: NDArray[np.float64]
    valid: NDArray[np.bool_]
    residual: NDArray[np.float64]


def validate_reference_points(
    m_ref: ArrayLike, min_points: int = 3, check_height: bool = True
) -> NDArray[np.float64]:
    """Check reference points for the degenerate cases of (16)-(18) and return them.

    ``m_ref`` (N, 3): ``m*_i = [1, m*_iy, m*_iz]``; ``min_points``: 3 for the three-point
    method, 4 for the projective route, which does not divide by m*_z (``check_height``).
    Raises NotEnoughPointsError, NonFiniteInputError, PointAtCameraHeightError,
    CollinearPointsError, PointBehindCameraError.
    """
    m_ref = np.asarray(m_ref, dtype=float)
    if m_ref.ndim != 2 or m_ref.shape[-1] != 3:
        raise NotEnoughPointsError(f"reference points must have shape (N, 3), got {m_ref.shape}")
    if m_ref.shape[0] < min_points:
        raise NotEnoughPointsError(
            f"need at least {min_points} target points, got {m_ref.shape[0]}"
        )
    if not np.all(np.isfinite(m_ref)):
        raise NonFiniteInputError("reference points contain NaN or infinity")
    if np.any(np.abs(m_ref[:, 0] - 1.0) > 1e-9):
        raise PointBehindCameraError(
            "reference points must be normalised as m = [1, m_y, m_z] (a point in front of the camera)"
        )
    if check_height:
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


def _check_batch_shapes(m: NDArray[np.float64], m_ref: NDArray[np.float64]) -> None:
    if m.shape[-2:] != m_ref.shape:
        raise NotEnoughPointsError(
            f"current points have shape {m.shape[-2:]} but the reference has {m_ref.shape}: "
            "every reference point needs its current image"
        )


def estimate_euclidean_homography(m: ArrayLike, m_ref: ArrayLike) -> HomographyEstimate:
    """Euclidean homography by the paper's three-point method, (16)-(18).

    Rows 1 and 2 of (12) read ``m*_i . h_1 = 1 / alpha_i`` and ``m*_i . h_2 = m_iy / alpha_i``:
    least squares over the N >= 3 points ``m`` (..., N, 3), in the order of ``m_ref`` (N, 3).
    A degenerate reference raises (:func:`validate_reference_points`).
    """
    m_ref = validate_reference_points(m_ref, min_points=3)
    m = np.asarray(m, dtype=float)
    _check_batch_shapes(m, m_ref)
    alpha = depth_ratios(m, m_ref)
    finite = np.all(np.isfinite(m), axis=(-1, -2))
    valid = finite & np.all(alpha > 0.0, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_alpha = 1.0 / alpha
        rhs = np.stack([inv_alpha, m[..., 1] * inv_alpha], axis=-1)  # (..., N, 2)
    # One pseudo-inverse of the reference design serves every frame and both rows.
    design_pinv = np.linalg.pinv(m_ref)  # (3, N)
    rows = np.einsum("kn,...nr->...rk", design_pinv, rhs)  # (..., 2, 3)
    H = np.zeros(m.shape[:-2] + (3, 3))
    H[..., :2, :] = rows
    H[..., 2, 2] = 1.0
    return _masked_estimate(H, alpha, valid, _transfer_residual(H, m, m_ref))


def _masked_estimate(H: NDArray[np.float64], alpha: NDArray[np.float64], valid: NDArray[np.bool_],
                     residual: NDArray[np.float64]) -> HomographyEstimate:
    """The estimate with NaN wherever ``valid`` is False (H is masked in place)."""
    H[~valid] = np.nan
    alpha = np.where(valid[..., None], alpha, np.nan)
    return HomographyEstimate(H=H, depth_ratios=alpha, valid=valid, residual=np.where(valid, residual, np.nan))


def _normalizing_transform(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Hartley normalisation of the (y, z) coordinates of paper-axis points, batched."""
    yz = points[..., 1:] / points[..., :1]
    centre = yz.mean(axis=-2)  # (..., 2)
    spread = np.sqrt(np.sum((yz - centre[..., None, :]) ** 2, axis=-1)).mean(axis=-1)
    scale = np.sqrt(2.0) / np.maximum(spread, 1e-12)
    T = np.zeros(points.shape[:-2] + (3, 3))
    T[..., 0, 0] = 1.0
    T[..., 1, 1] = scale
    T[..., 2, 2] = scale
    T[..., 1, 0] = -scale * centre[..., 0]
    T[..., 2, 0] = -scale * centre[..., 1]
    return T


def scale_to_euclidean(H: ArrayLike, m_ref: ArrayLike) -> NDArray[np.float64]:
    """Fix the scale and sign of a projective homography in the paper's axes.

    ``R + t n^T`` has middle singular value 1, and the sign makes ``(H m*_i)_x = 1 / alpha_i``
    positive for the points ``m_ref`` (N, 3).
    """
    H = np.asarray(H, dtype=float)
    sigma = np.linalg.svd(H, compute_uv=False)
    H = H / sigma[..., 1, None, None]
    first = np.einsum("...k,nk->...n", H[..., 0, :], np.asarray(m_ref, dtype=float))
    sign = np.where(np.sum(np.sign(first), axis=-1) >= 0, 1.0, -1.0)
    return H * sign[..., None, None]


def estimate_projective_homography(m: ArrayLike, m_ref: ArrayLike) -> HomographyEstimate:
    """Euclidean homography by the projective route: normalised DLT, then scale and sign.

    Does not assume planar motion: an independent check of the three-point method. N >= 4.
    """
    m_ref = validate_reference_points(m_ref, min_points=4, check_height=False)
    m = np.asarray(m, dtype=float)
    _check_batch_shapes(m, m_ref)
    finite = np.all(np.isfinite(m), axis=(-1, -2))
    m_safe = np.where(finite[..., None, None], m, m_ref)
    T_ref = _normalizing_transform(m_ref)
    T_cur = _normalizing_transform(m_safe)
    p = m_ref @ T_ref.T  # (N, 3)
    q = np.einsum("...ij,...nj->...ni", T_cur, m_safe)  # (..., N, 3)
    n_points = m_ref.shape[0]
    A = np.zeros(m.shape[:-2] + (2 * n_points, 9))
    a, b, c = q[..., 0], q[..., 1], q[..., 2]
    # m x (H m*) = 0: b (h3.p) - c (h2.p) = 0 and c (h1.p) - a (h3.p) = 0.
    A[..., 0::2, 3:6] = -c[..., None] * p
    A[..., 0::2, 6:9] = b[..., None] * p
    A[..., 1::2, 0:3] = c[..., None] * p
    A[..., 1::2, 6:9] = -a[..., None] * p
    _, _, vt = np.linalg.svd(A)
    H_norm = vt[..., -1, :].reshape(m.shape[:-2] + (3, 3))
    H = np.linalg.inv(T_cur) @ H_norm @ T_ref
    H = scale_to_euclidean(H, m_ref)
    with np.errstate(divide="ignore", invalid="ignore"):
        alpha = 1.0 / np.einsum("...k,nk->...n", H[..., 0, :], m_ref)
    residual = _transfer_residual(H, m_safe, m_ref)
    valid = finite & np.all(alpha > 0.0, axis=-1)
    return _masked_estimate(H, alpha, valid, residual)


def euclidean_from_pixel_homography(
    G: ArrayLike, camera: CameraIntrinsics, m_ref: ArrayLike
) -> NDArray[np.float64]:
    """Map a pixel homography (e.g. from ``cv2.findHomography``) to the paper's H.

    ``H = P^T (K^-1 G K) P``, scaled and signed by :func:`scale_to_euclidean` on ``m_ref``;
    ``G`` (..., 3, 3) maps reference pixels to current pixels.
    """
    K = camera.K
    H_cv = np.linalg.inv(K) @ np.asarray(G, dtype=float) @ K
    return scale_to_euclidean(opencv_to_paper_homography(H_cv), m_ref)


def _transfer_residual(H: NDArray[np.float64], m: NDArray[np.float64], m_ref: NDArray[np.float64]) -> NDArray[np.float64]:
    """RMS distance (normalised units) between measured points and the reference points
    transferred through H."""
    with np.errstate(divide="ignore", invalid="ignore"):
        predicted = transfer_points(H, m_ref)
        return np.sqrt(np.mean((predicted[..., 1:] - m[..., 1:]) ** 2, axis=(-1, -2)))


def transfer_points(H: ArrayLike, m_ref: ArrayLike) -> NDArray[np.float64]:
    """Predicted points ``m_i = alpha_i H m*_i`` (..., N, 3), normalised to ``[1, m_y, m_z]``."""
    projected = np.einsum("...ij,nj->...ni", np.asarray(H, dtype=float), np.asarray(m_ref, dtype=float))
    return projected / projected[..., :1]
