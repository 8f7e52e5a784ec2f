"""The plane normal n* common to a sequence of homographies, and its refinement.

The true normal is the same in every frame, the spurious decomposition's moves with the
robot (docs/method.md, "Decomposition into (theta, x_h, n*)"): :func:`estimate_common_normal`
picks the branch the whole sequence agrees on, and :func:`refine_plane_and_reference`
refines n* and the reference points m*_i together over every frame, with the known-normal
solver as the inner step.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import GeometryError, NoValidBranchError
from .decomposition import FACING_PRIOR, PURE_ROTATION_TOLERANCE, front_facing, homography_candidates, select_branch, take_branch
from .homography import validate_reference_points
from .known_normal import KnownNormalSolver

#: Frames the plane estimates use at most (evenly spaced): the normal and the reference
#: points need no more, and long recordings stay fast and memory flat.
REFINEMENT_FRAMES = 1500


def estimate_common_normal(
    H: ArrayLike,
    m_ref: ArrayLike,
    valid: ArrayLike | None = None,
    prior: ArrayLike = FACING_PRIOR,
    with_rival: bool = False,
) -> tuple[NDArray[np.float64], float] | tuple[NDArray[np.float64], float, NDArray[np.float64] | None]:
    """The plane normal n* shared by a sequence of homographies.

    The true normal is the same in every frame, the spurious candidate's moves with the
    robot. Each front-facing normal of the best-conditioned frames is scored by how well
    every frame agrees with it (weighted by each frame's ``sigma_1 - sigma_3``); the winner
    is refined as the weighted mean of the closest candidate of every frame.

    Parameters
    ----------
    H : array_like, shape (F, 3, 3)
    m_ref : array_like, shape (N, 3)
    valid : array_like of bool, shape (F,), optional
        Frames to use.
    prior : array_like, shape (3,)
        Used to break a tie, and returned when no frame has a usable translation.
    with_rival : bool
        Also return the best rival proposal (the other branch's normal, or None).

    Returns
    -------
    normal : ndarray, shape (3,)
        Unit normal in F*.
    margin : float
        Score of the winner minus that of the best rival, in [0, 1]: near 0 the sequence
        does not tell the two branches apart (e.g. a straight drive) and the prior decided.
    """
    m_ref = np.asarray(m_ref, dtype=float)
    H = np.asarray(H, dtype=float)
    prior = np.asarray(prior, dtype=float) / np.linalg.norm(prior)
    mask = np.all(np.isfinite(H), axis=(-1, -2))
    if valid is not None:
        mask &= np.asarray(valid, dtype=bool)
    if not np.any(mask):
        raise NoValidBranchError("no frame has a usable homography to estimate the plane normal from")
    usable = H[mask]
    if usable.shape[0] > REFINEMENT_FRAMES:  # the normal needs no more frames; memory stays flat
        usable = usable[np.linspace(0, usable.shape[0] - 1, REFINEMENT_FRAMES).astype(int)]
    candidates = homography_candidates(usable)
    front = front_facing(candidates, m_ref)
    weight = np.where(np.any(front, axis=-1), candidates.strength, 0.0)
    if not np.any(weight > PURE_ROTATION_TOLERANCE):
        return (prior, 0.0, None) if with_rival else (prior, 0.0)
    normals = np.nan_to_num(candidates.normals)
    # Proposals: the front normals of the few best-conditioned frames, and the prior.
    best_frames = np.argsort(weight)[::-1][: min(5, weight.size)]
    proposals = [normals[f, c] for f in best_frames for c in range(4) if front[f, c]]
    proposals.append(prior)
    proposals_arr = np.array(proposals)
    agreement = np.einsum("fck,pk->pfc", normals, proposals_arr)
    agreement = np.where(front[None], agreement, -1.0)
    scores = (agreement.max(axis=-1) * weight[None]).sum(axis=-1) / weight.sum()
    scores = scores + 1e-9 * (proposals_arr @ prior)  # prefer the prior on an exact tie
    order = np.argsort(scores)[::-1]
    best = proposals_arr[order[0]]
    rival_indices = [i for i in order[1:] if float(proposals_arr[i] @ best) < np.cos(np.radians(5.0))]
    rivals = [scores[i] for i in rival_indices]
    margin = float(scores[order[0]] - max(rivals)) if rivals else 1.0
    rival = proposals_arr[rival_indices[0]] if rival_indices else None
    for _ in range(3):
        index, ok = select_branch(candidates, m_ref, best)
        chosen = take_branch(normals, index)
        w = np.where(ok, weight, 0.0) ** 2
        refined = (chosen * w[:, None]).sum(axis=0)
        best = refined / np.linalg.norm(refined)
    if with_rival:
        return best, max(0.0, min(1.0, margin)), rival
    return best, max(0.0, min(1.0, margin))


#: A target shape known up to a similarity: the indices of some of its points, and their
#: coordinates in the target's plane (any unit, any origin and orientation, mirrored or not).
KnownShape = tuple[Sequence[int], ArrayLike]

#: The corners of a square marker in OpenCV's order (top-left, top-right, bottom-right,
#: bottom-left), as a :data:`KnownShape`'s plane coordinates.
UNIT_SQUARE = ((0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0))


def shape_residuals(normal: ArrayLike, m: ArrayLike, shapes: Sequence[KnownShape]) -> NDArray[np.float64]:
    """How far image points are from target shapes known up to a similarity, in image units.

    Points m_i seen from a camera lie on the plane ``n^T m_bar = d`` (7): with d = 1,
    ``P_i = m_i / (n^T m_i)``. Their coordinates in the plane are matched to each known
    shape by the best similarity (Procrustes, reflection allowed), and the matched shape's
    points are projected back into the camera (9). The residual is their ``(m_y, m_z)``
    minus the points': zero when the points and the normal agree with the shape. A square
    seen under a wrong wall angle is foreshortened wrongly: this is what tells the normal's
    yaw on a small target, which the motion alone hardly does.

    Parameters
    ----------
    normal : array_like, shape (..., 3)
        Unit plane normal in the camera's frame (n* for F*), per frame.
    m : array_like, shape (..., N, 3)
        Normalised image points.
    shapes : sequence of (indices, plane coordinates of shape (K, 2)), K >= 3

    Returns
    -------
    ndarray, shape (..., 2 * sum of K)
    """
    normal = np.asarray(normal, dtype=float)
    m = np.asarray(m, dtype=float)
    normal = np.broadcast_to(normal, m.shape[:-2] + (3,))
    e1 = np.cross(normal, [0.0, 0.0, 1.0])
    e1 = e1 / np.linalg.norm(e1, axis=-1, keepdims=True)
    e2 = np.cross(normal, e1)
    residuals = []
    for indices, layout in shapes:
        points = m[..., list(indices), :]
        with np.errstate(divide="ignore", invalid="ignore"):
            on_plane = points / np.einsum("...k,...nk->...n", normal, points)[..., None]
        q = np.stack([np.einsum("...k,...nk->...n", e1, on_plane), np.einsum("...k,...nk->...n", e2, on_plane)], axis=-1)
        layout = np.asarray(layout, dtype=float)
        q_mean = q.mean(axis=-2, keepdims=True)
        lc = layout - layout.mean(axis=0)
        qc = np.nan_to_num(q - q_mean)
        rotation, singular_sum = procrustes_2d(np.einsum("ki,...kj->...ij", lc, qc))
        scale = singular_sum / max(float(np.sum(lc * lc)), 1e-300)
        fitted = q_mean + scale[..., None, None] * np.einsum("ki,...ij->...kj", lc, rotation)
        world = normal[..., None, :] + fitted[..., :1] * e1[..., None, :] + fitted[..., 1:] * e2[..., None, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            projected = world / world[..., :1]
        residuals.append((projected[..., 1:] - points[..., 1:]).reshape(m.shape[:-2] + (-1,)))
    return np.concatenate(residuals, axis=-1) if residuals else np.zeros(m.shape[:-2] + (0,))


def procrustes_2d(M: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The orthogonal polar factor ``U V^T`` of 2x2 matrices and their singular values' sum.

    In closed form (a batched SVD of many 2x2 matrices cost a third of
    :func:`shape_residuals`): with ``M = [[a, b], [c, d]]``, ``E = |(a + d, c - b)|`` and
    ``F = |(a - d, b + c)|``, the singular values are ``(E + F) / 2`` and ``|E - F| / 2``
    (so they sum to ``max(E, F)``), and ``E^2 - F^2 = 4 det M``: a rotation by
    ``atan2(c - b, a + d)`` when ``E >= F``, else a reflection.

    Parameters
    ----------
    M : ndarray, shape (..., 2, 2)

    Returns
    -------
    factor : ndarray, shape (..., 2, 2)
    singular_sum : ndarray, shape (...)
    """
    a, b, c, d = M[..., 0, 0], M[..., 0, 1], M[..., 1, 0], M[..., 1, 1]
    E, F = np.hypot(a + d, c - b), np.hypot(a - d, b + c)
    proper = E >= F
    with np.errstate(divide="ignore", invalid="ignore"):
        cos = np.where(proper, (a + d) / E, (a - d) / F)
        sin = np.where(proper, (c - b) / E, (b + c) / F)
    # Rotation [[cos, -sin], [sin, cos]] or reflection [[cos, sin], [sin, -cos]].
    sign = np.where(proper, 1.0, -1.0)
    factor = np.stack([np.stack([cos, -sign * sin], axis=-1), np.stack([sin, sign * cos], axis=-1)], axis=-2)
    return factor, np.maximum(E, F)


def refine_plane_and_reference(
    m: ArrayLike, reference_index: int, normal: ArrayLike, valid: ArrayLike | None = None,
    shapes: Sequence[KnownShape] = (),
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Refine the plane normal n* and the reference points m*_i over a whole sequence.

    Variable projection: for trial values of n* (two angles about ``normal``) and of the
    reference points (their y and z), :class:`KnownNormalSolver` gives every frame its best
    (theta, x_h); the trial values minimise the sum of every frame's squared reprojection
    error, plus the reference frame's own: F* is where the reference frame was taken, so
    its motion is pinned at identity (this fixes the gauge).

    Both parts matter. With the reference points held at their noisy measurement, the
    normal bends to absorb their error (the cost is lower at the wrong normal); averaging
    per-frame SVD normals is biased too.

    Parameters
    ----------
    m : array_like, shape (F, N, 3)
        Normalised points of the sequence (``m[reference_index]`` is the reference frame).
    reference_index : int
    normal : array_like, shape (3,)
        Starting normal (its branch already chosen).
    valid : array_like of bool, shape (F,), optional
        Frames to use besides the reference frame.
    shapes : sequence of KnownShape, optional
        Parts of the target whose shape is known up to a similarity (a marker's square):
        :func:`shape_residuals` joins the cost. With a single 0.4 m marker 3-6 m away the
        motion barely tells the normal's yaw; the square's foreshortening does.

    Returns
    -------
    normal : ndarray, shape (3,)
    m_ref : ndarray, shape (N, 3)
    """
    from scipy.optimize import least_squares  # lazy: scipy.optimize adds to every command's start-up

    m = np.asarray(m, dtype=float)
    measured_ref = validate_reference_points(m[reference_index])
    others = np.ones(m.shape[0], dtype=bool) if valid is None else np.asarray(valid, dtype=bool).copy()
    others[reference_index] = False
    frames = m[others]
    if frames.shape[0] > REFINEMENT_FRAMES:
        frames = frames[np.linspace(0, frames.shape[0] - 1, REFINEMENT_FRAMES).astype(int)]
    start = np.asarray(normal, dtype=float) / np.linalg.norm(normal)
    u = np.cross(start, [0.0, 0.0, 1.0])
    u = u / np.linalg.norm(u) if np.linalg.norm(u) > 1e-6 else np.array([0.0, 1.0, 0.0])
    v = np.cross(start, u)
    n_points = measured_ref.shape[0]

    def unpack(p: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        trial_normal = start + p[0] * u + p[1] * v
        trial_ref = measured_ref.copy()
        trial_ref[:, 1:] += p[2:].reshape(n_points, 2)
        return trial_normal / np.linalg.norm(trial_normal), trial_ref

    def residuals(p: NDArray[np.float64]) -> NDArray[np.float64]:
        trial_normal, trial_ref = unpack(p)
        solver = KnownNormalSolver(trial_ref, trial_normal)
        motion = solver.solve(frames)
        reprojection = np.nan_to_num(solver.reprojection_residuals(motion, frames)).ravel()
        if not shapes:
            return np.concatenate([reprojection, (trial_ref[:, 1:] - measured_ref[:, 1:]).ravel()])
        # Every frame sees the shape too, under its own normal Rz(theta) n*.
        c, s = np.cos(motion.theta), np.sin(motion.theta)
        normals = np.stack([c * trial_normal[0] - s * trial_normal[1], s * trial_normal[0] + c * trial_normal[1],
                            np.full_like(c, trial_normal[2])], axis=-1)
        shape = np.concatenate([shape_residuals(trial_normal, trial_ref, shapes), shape_residuals(normals, frames, shapes).ravel()])
        return np.concatenate([reprojection, (trial_ref[:, 1:] - measured_ref[:, 1:]).ravel(), np.nan_to_num(shape)])

    if frames.shape[0] == 0:
        return start, measured_ref
    try:
        solution = least_squares(residuals, np.zeros(2 + 2 * n_points), x_scale=1e-3, max_nfev=100)
    except GeometryError:
        return start, measured_ref
    refined_normal, refined_ref = unpack(solution.x)
    if np.any(refined_ref @ refined_normal <= 0.0):
        return start, measured_ref
    return refined_normal, refined_ref
