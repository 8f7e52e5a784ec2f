"""Decomposing ``H = R + x_h n*^T`` (12) into (theta, x_h, n*): of its four decompositions
(Faugeras-Lustman [15]) the plane in front of F* leaves two; the true normal is the one common
to the sequence, or closest to a prior (docs/method.md, "Decomposition into (theta, x_h, n*)").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import NonFiniteInputError

#: Default prior for the plane normal in F*: the target faces the reference camera.
FACING_PRIOR = np.array([1.0, 0.0, 0.0])

#: Below this sigma_1 - sigma_3 the homography is a pure rotation: no translation, no normal.
PURE_ROTATION_TOLERANCE = 1e-9


@dataclass(frozen=True)
class HomographyCandidates:
    """The unit ``normals`` n in F* (..., 4, 3; NaN for a pure rotation) of the four decompositions
    ``H = R + t n^T`` of each homography; ``strength`` (...): sigma_1 - sigma_3 of the scaled H, how
    well t and n are determined. The plane's normal is all the fit takes from them; the tests'
    oracle (tests/oracles.py) rebuilds R and t from it."""

    normals: NDArray[np.float64]
    strength: NDArray[np.float64]


@dataclass(frozen=True)
class PlanarMotion:
    """F* seen from F per frame: ``theta`` (...) = phi* - phi (rad), ``x_h`` (..., 2) = x_f / d*
    (14), unit n* ``normal`` (..., 3) and ``residual`` (...), the RMS of the equations solved
    (normalised units), large for outliers or a wrong normal."""

    theta: NDArray[np.float64]
    x_h: NDArray[np.float64]
    normal: NDArray[np.float64]
    valid: NDArray[np.bool_]
    residual: NDArray[np.float64]


def homography_candidates(H: ArrayLike) -> HomographyCandidates:
    """The normals of all four decompositions of homographies ``H`` (..., 3, 3) of any positive scale.

    Ma, Soatto, Kosecka and Sastry, *An Invitation to 3-D Vision*, Sec. 5.3: with ``H^T H =
    V diag(s1^2, 1, s3^2) V^T``, ``u = (sqrt(1 - s3^2) v1 +- sqrt(s1^2 - 1) v3) / sqrt(s1^2 - s3^2)``
    gives ``n = v2 x u``, ``R = [H v2, H u, H v2 x H u] [v2, u, n]^T``, ``t = (H - R) n``, and (R, -t, -n).
    """
    H = np.asarray(H, dtype=float)
    if not np.all(np.isfinite(H)):
        raise NonFiniteInputError("the homography contains NaN or infinity")
    sigma = np.linalg.svd(H, compute_uv=False)
    H = H / sigma[..., 1, None, None]
    eigenvalues, V = np.linalg.eigh(np.swapaxes(H, -1, -2) @ H)
    # eigh sorts ascending: reorder so that v1 has the largest eigenvalue.
    V = V[..., :, ::-1]
    V = V * np.sign(np.linalg.det(V))[..., None, None]
    s1_sq, s3_sq = eigenvalues[..., 2], eigenvalues[..., 0]
    v1, v2, v3 = V[..., :, 0], V[..., :, 1], V[..., :, 2]
    spread = np.sqrt(np.maximum(s1_sq - s3_sq, 0.0))
    strength = np.sqrt(np.maximum(s1_sq, 0.0)) - np.sqrt(np.maximum(s3_sq, 0.0))
    pure_rotation = strength < PURE_ROTATION_TOLERANCE
    safe_spread = np.where(pure_rotation, 1.0, spread)[..., None]
    a = np.sqrt(np.clip(1.0 - s3_sq, 0.0, None))[..., None]
    b = np.sqrt(np.clip(s1_sq - 1.0, 0.0, None))[..., None]
    u1 = (a * v1 + b * v3) / safe_spread
    u2 = (a * v1 - b * v3) / safe_spread
    normals = np.stack([sign * np.cross(v2, u) for u in (u1, u2) for sign in (1.0, -1.0)], axis=-2)
    normals[pure_rotation] = np.nan  # no translation: the normal is undefined
    return HomographyCandidates(normals=normals, strength=strength)


def front_facing(candidates: HomographyCandidates, m_ref: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Candidates whose plane lies in front of F*: ``n^T m*_i > 0`` for all i, (7)."""
    with np.errstate(invalid="ignore"):
        dots = np.einsum("...ck,nk->...cn", candidates.normals, m_ref)
        return np.all(dots > 0.0, axis=-1)


def select_branch(candidates: HomographyCandidates, m_ref: ArrayLike, reference_normal: ArrayLike
                  ) -> tuple[NDArray[np.intp], NDArray[np.bool_]]:
    """Index of each homography's decomposition in front of F* closest to ``reference_normal``
    ((3,) or (..., 3)), a pure rotation's first; ``valid`` is False where none is in front."""
    m_ref = np.asarray(m_ref, dtype=float)
    reference_normal = np.asarray(reference_normal, dtype=float)
    front = front_facing(candidates, m_ref)
    agreement = np.einsum("...ck,...k->...c", np.nan_to_num(candidates.normals), reference_normal)
    agreement = np.where(front, agreement, -np.inf)
    index = np.argmax(agreement, axis=-1)
    pure_rotation = candidates.strength < PURE_ROTATION_TOLERANCE
    valid = np.any(front, axis=-1) | pure_rotation
    index = np.where(pure_rotation, 0, index)
    return index, valid


def take_branch(array: NDArray[np.float64], index: NDArray[np.intp]) -> NDArray[np.float64]:
    """array[..., index[...], ...] along the candidate axis (axis = index.ndim)."""
    expanded = index.reshape(index.shape + (1,) * (array.ndim - index.ndim))
    return np.take_along_axis(array, expanded, axis=index.ndim).squeeze(axis=index.ndim)
