"""Decomposing the Euclidean homography into (theta, x_h, n*), and the known-normal solver.

``H = R + x_h n*^T`` (12) has up to four decompositions (Faugeras-Lustman [15],
Zhang-Hanson [32]). The physically right one is found in two steps (equations.md,
"Decomposition into (theta, x_h, n*)"):

1. the plane must be in front of F*: ``n*^T m*_i > 0`` for every point (two candidates stay);
2. the true normal is the same in every frame of a sequence, the spurious one moves with
   the robot: keep the candidate whose normal agrees with the sequence's common normal
   (:func:`estimate_common_normal`) or with a given prior.

Once n* is known, ``H = Rz(theta) + x_h n*^T`` is *linear* in ``(cos theta, sin theta,
x_h1, x_h2)``: :func:`solve_planar_motion_known_normal` solves it by least squares from the
points directly. It has a unique answer and can never pick a wrong branch, so ``fit`` and
``repeat`` use it for every frame once n* has been estimated.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import GeometryError, NoValidBranchError, NonFiniteInputError
from .homography import depth_ratios, validate_reference_points

#: Default prior for the plane normal in F*: the target faces the reference camera.
FACING_PRIOR = np.array([1.0, 0.0, 0.0])

#: Below this spread of singular values (sigma_1 - sigma_3) the homography is a pure
#: rotation: the translation is zero and the normal is undefined.
PURE_ROTATION_TOLERANCE = 1e-9


@dataclass(frozen=True)
class HomographyCandidates:
    """The four decompositions ``H = R + t n^T`` of each homography in a batch.

    Attributes
    ----------
    rotations : ndarray, shape (..., 4, 3, 3)
    translations : ndarray, shape (..., 4, 3)
        Scaled translations ``x_h = x_f / d*`` (14).
    normals : ndarray, shape (..., 4, 3)
        Unit plane normals in F* (NaN for a pure rotation).
    strength : ndarray, shape (...)
        ``sigma_1 - sigma_3`` of the scaled H: how well the translation (and hence the
        normal) is determined; 0 for a pure rotation.
    """

    rotations: NDArray[np.float64]
    translations: NDArray[np.float64]
    normals: NDArray[np.float64]
    strength: NDArray[np.float64]


@dataclass(frozen=True)
class PlanarMotion:
    """Rotation angle and scaled translation of F* seen from F, per frame.

    Attributes
    ----------
    theta : ndarray, shape (...)
        Rotation about z, ``phi* - phi`` (rad), from ``atan2(R_21, R_11)``.
    x_h : ndarray, shape (..., 2)
        ``[x_h1, x_h2] = x_f / d*`` (14), dimensionless.
    normal : ndarray, shape (..., 3)
        Plane normal n* in F* (unit).
    valid : ndarray of bool, shape (...)
    residual : ndarray, shape (...)
        RMS residual of the equations solved (normalised units); large values flag
        outliers or a wrong normal.
    """

    theta: NDArray[np.float64]
    x_h: NDArray[np.float64]
    normal: NDArray[np.float64]
    valid: NDArray[np.bool_]
    residual: NDArray[np.float64]


def homography_candidates(H: ArrayLike) -> HomographyCandidates:
    """All four decompositions of a batch of Euclidean homographies (SVD method).

    Follows Ma, Soatto, Kosecka and Sastry, *An Invitation to 3-D Vision*, Sec. 5.3: with
    ``H^T H = V diag(s1^2, 1, s3^2) V^T`` (H scaled so that its middle singular value is 1),
    ``u_{1,2} = (sqrt(1 - s3^2) v1 +- sqrt(s1^2 - 1) v3) / sqrt(s1^2 - s3^2)`` give the
    normals ``v2 x u`` and ``R = [H v2, H u, H v2 x H u] [v2, u, v2 x u]^T``, ``t = (H - R) n``;
    the other two solutions are ``(R, -t, -n)``.

    Parameters
    ----------
    H : array_like, shape (..., 3, 3)
        Euclidean homographies (any positive scale).

    Returns
    -------
    HomographyCandidates
    """
    H = np.asarray(H, dtype=float)
    if not np.all(np.isfinite(H)):
        raise NonFiniteInputError("the homography contains NaN or infinity")
    sigma = np.linalg.svd(H, compute_uv=False)
    H = H / sigma[..., 1, None, None]
    eigenvalues, V = np.linalg.eigh(np.swapaxes(H, -1, -2) @ H)
    # eigh sorts ascending: reorder so that v1 has the largest eigenvalue.
    eigenvalues = eigenvalues[..., ::-1]
    V = V[..., :, ::-1]
    V = V * np.sign(np.linalg.det(V))[..., None, None]
    s1_sq = eigenvalues[..., 0]
    s3_sq = eigenvalues[..., 2]
    v1, v2, v3 = V[..., :, 0], V[..., :, 1], V[..., :, 2]
    spread = np.sqrt(np.maximum(s1_sq - s3_sq, 0.0))
    strength = np.sqrt(np.maximum(s1_sq, 0.0)) - np.sqrt(np.maximum(s3_sq, 0.0))
    pure_rotation = strength < PURE_ROTATION_TOLERANCE
    safe_spread = np.where(pure_rotation, 1.0, spread)[..., None]
    a = np.sqrt(np.clip(1.0 - s3_sq, 0.0, None))[..., None]
    b = np.sqrt(np.clip(s1_sq - 1.0, 0.0, None))[..., None]
    u1 = (a * v1 + b * v3) / safe_spread
    u2 = (a * v1 - b * v3) / safe_spread

    rotations = []
    translations = []
    normals = []
    for u in (u1, u2):
        U = np.stack([v2, u, np.cross(v2, u)], axis=-1)
        Hv2 = np.einsum("...ij,...j->...i", H, v2)
        Hu = np.einsum("...ij,...j->...i", H, u)
        W = np.stack([Hv2, Hu, np.cross(Hv2, Hu)], axis=-1)
        R = W @ np.swapaxes(U, -1, -2)
        n = np.cross(v2, u)
        t = np.einsum("...ij,...j->...i", H - R, n)
        rotations += [R, R]
        translations += [t, -t]
        normals += [n, -n]
    rotations_arr = np.stack(rotations, axis=-3)
    translations_arr = np.stack(translations, axis=-2)
    normals_arr = np.stack(normals, axis=-2)
    if np.any(pure_rotation):
        # No translation: R is H itself and the normal is undefined.
        rotations_arr[pure_rotation] = H[pure_rotation][:, None, :, :]
        translations_arr[pure_rotation] = 0.0
        normals_arr[pure_rotation] = np.nan
    return HomographyCandidates(
        rotations=rotations_arr, translations=translations_arr, normals=normals_arr, strength=strength
    )


def _front_mask(candidates: HomographyCandidates, m_ref: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Candidates whose plane lies in front of F*: ``n^T m*_i > 0`` for all i, (7)."""
    with np.errstate(invalid="ignore"):
        dots = np.einsum("...ck,nk->...cn", candidates.normals, m_ref)
        return np.all(dots > 0.0, axis=-1)


def select_branch(
    candidates: HomographyCandidates, m_ref: ArrayLike, reference_normal: ArrayLike
) -> tuple[NDArray[np.intp], NDArray[np.bool_]]:
    """Index of the physically right decomposition of each homography.

    Among the candidates with the plane in front of F*, the one whose normal is closest
    to ``reference_normal``. A pure rotation has no normal; its first candidate is taken.

    Parameters
    ----------
    candidates : HomographyCandidates
        Batch shape (...).
    m_ref : array_like, shape (N, 3)
    reference_normal : array_like, shape (3,) or (..., 3)

    Returns
    -------
    index : ndarray of int, shape (...)
    valid : ndarray of bool, shape (...)
        False where no candidate has the plane in front.
    """
    m_ref = np.asarray(m_ref, dtype=float)
    reference_normal = np.asarray(reference_normal, dtype=float)
    front = _front_mask(candidates, m_ref)
    agreement = np.einsum("...ck,...k->...c", np.nan_to_num(candidates.normals), reference_normal)
    agreement = np.where(front, agreement, -np.inf)
    index = np.argmax(agreement, axis=-1)
    pure_rotation = candidates.strength < PURE_ROTATION_TOLERANCE
    valid = np.any(front, axis=-1) | pure_rotation
    index = np.where(pure_rotation, 0, index)
    return index, valid


def _take(array: NDArray[np.float64], index: NDArray[np.intp]) -> NDArray[np.float64]:
    """array[..., index[...], ...] along the candidate axis (axis = index.ndim)."""
    expanded = index.reshape(index.shape + (1,) * (array.ndim - index.ndim))
    return np.take_along_axis(array, expanded, axis=index.ndim).squeeze(axis=index.ndim)


def estimate_common_normal(
    H: ArrayLike,
    m_ref: ArrayLike,
    valid: ArrayLike | None = None,
    prior: ArrayLike = FACING_PRIOR,
) -> tuple[NDArray[np.float64], float]:
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
    front = _front_mask(candidates, m_ref)
    weight = np.where(np.any(front, axis=-1), candidates.strength, 0.0)
    if not np.any(weight > PURE_ROTATION_TOLERANCE):
        return prior, 0.0
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
    rivals = [scores[i] for i in order[1:] if float(proposals_arr[i] @ best) < np.cos(np.radians(5.0))]
    margin = float(scores[order[0]] - max(rivals)) if rivals else 1.0
    for _ in range(3):
        index, ok = select_branch(candidates, m_ref, best)
        chosen = _take(normals, index)
        w = np.where(ok, weight, 0.0) ** 2
        refined = (chosen * w[:, None]).sum(axis=0)
        best = refined / np.linalg.norm(refined)
    return best, max(0.0, min(1.0, margin))


#: Frames used by :func:`refine_plane_and_reference` at most (evenly spaced): the plane
#: and the reference points need no more, and long recordings stay fast.
REFINEMENT_FRAMES = 1500


def refine_plane_and_reference(
    m: ArrayLike, reference_index: int, normal: ArrayLike, valid: ArrayLike | None = None
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

    Returns
    -------
    normal : ndarray, shape (3,)
    m_ref : ndarray, shape (N, 3)
    """
    from scipy.optimize import least_squares

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
        reprojection = np.nan_to_num(solver.reprojection_residuals(solver.solve(frames), frames)).ravel()
        return np.concatenate([reprojection, (trial_ref[:, 1:] - measured_ref[:, 1:]).ravel()])

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


def decompose_homography(
    H: ArrayLike, m_ref: ArrayLike, reference_normal: ArrayLike = FACING_PRIOR
) -> PlanarMotion:
    """(theta, x_h, n*) of each homography, the branch chosen by a reference normal.

    Parameters
    ----------
    H : array_like, shape (..., 3, 3)
        Euclidean homographies in the paper's axes.
    m_ref : array_like, shape (N, 3)
        Reference points, for the plane-in-front test.
    reference_normal : array_like, shape (3,) or (..., 3)
        The sequence's common normal (:func:`estimate_common_normal`), the previous
        frame's, or a prior; the closest front-facing candidate is returned.

    Returns
    -------
    PlanarMotion
        ``valid`` is False where no candidate puts the plane in front of F*.
    """
    m_ref = np.asarray(m_ref, dtype=float)
    candidates = homography_candidates(H)
    index, valid = select_branch(candidates, m_ref, reference_normal)
    R = _take(candidates.rotations, index)
    t = _take(candidates.translations, index)
    n = _take(candidates.normals, index)
    pure_rotation = candidates.strength < PURE_ROTATION_TOLERANCE
    n = np.where(pure_rotation[..., None], np.broadcast_to(reference_normal, n.shape), n)
    theta = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    planarity = np.abs(t[..., 2]) + np.abs(1.0 - R[..., 2, 2])
    return PlanarMotion(theta=theta, x_h=t[..., :2], normal=n, valid=valid, residual=planarity)


def decompose_homography_single(
    H: ArrayLike, m_ref: ArrayLike, reference_normal: ArrayLike = FACING_PRIOR
) -> PlanarMotion:
    """One homography; raises :class:`NoValidBranchError` when no branch is physical."""
    motion = decompose_homography(H, m_ref, reference_normal)
    if not bool(motion.valid):
        raise NoValidBranchError(
            "no decomposition of the homography puts the target plane in front of the camera"
        )
    return motion


def known_normal_design(m_ref: ArrayLike, normal: ArrayLike) -> NDArray[np.float64]:
    """The (2N, 4) design matrix of the known-normal solver for one reference.

    Rows ``[1, -m*_iy, g_i, 0]`` and ``[m*_iy, 1, 0, g_i]`` with ``g_i = n*^T m*_i``, for the
    unknowns ``(cos theta, sin theta, x_h1, x_h2)``.
    """
    m_ref = np.asarray(m_ref, dtype=float)
    normal = np.asarray(normal, dtype=float)
    g = m_ref @ normal
    n_points = m_ref.shape[0]
    design = np.zeros((2 * n_points, 4))
    design[0::2, 0] = 1.0
    design[0::2, 1] = -m_ref[:, 1]
    design[0::2, 2] = g
    design[1::2, 0] = m_ref[:, 1]
    design[1::2, 1] = 1.0
    design[1::2, 3] = g
    return design


class KnownNormalSolver:
    """(theta, x_h) from points when the plane normal n* is known: linear least squares.

    With ``alpha_i = m_iz / m*_iz`` (18) and ``g_i = n*^T m*_i``, each point of (12) with
    ``H = Rz(theta) + x_h n*^T`` gives two equations linear in ``(c, s, x_h1, x_h2)``::

        1 / alpha_i      = c - s m*_iy + x_h1 g_i
        m_iy / alpha_i   = s + c m*_iy + x_h2 g_i

    (equations.md, "Known-normal variant"). Unique, no SVD, never a wrong branch. The design
    matrix depends only on the reference, so it is factored once here and every frame (or
    a whole batch of frames) costs one matrix product.

    The linear solution leaves ``(c, s)`` free of ``c^2 + s^2 = 1``; Gauss-Newton steps on
    the reprojection error of the points, with theta as the unknown, then give the
    maximum-likelihood estimate under equal pixel noise (half the theta error of the
    linear solution at 0.02 px). Each step is kept only where it lowers the error: plain
    Gauss-Newton can diverge at large noise. ``refine_steps=0`` keeps the linear solution.

    :meth:`solve` works on batches with numpy; :meth:`solve_one` is the same computation
    in plain floats for one frame of a few points, where numpy's per-call overhead would
    dominate (the closed loop calls it every control period).

    Parameters
    ----------
    m_ref : array_like, shape (N, 3)
        Reference normalised points, N >= 3.
    normal : array_like, shape (3,)
        Unit normal of the target plane in F* (pointing from the camera to the plane).
    refine_steps : int
        Gauss-Newton steps after the linear solution.
    """

    def __init__(self, m_ref: ArrayLike, normal: ArrayLike, refine_steps: int = 2) -> None:
        self.m_ref = validate_reference_points(m_ref, min_points=3)
        self.refine_steps = int(refine_steps)
        normal = np.asarray(normal, dtype=float)
        if normal.shape != (3,) or not np.all(np.isfinite(normal)) or np.linalg.norm(normal) < 1e-9:
            raise GeometryError("the plane normal must be a finite, non-zero 3-vector")
        self.normal = normal / np.linalg.norm(normal)
        if np.any(self.m_ref @ self.normal <= 0.0):
            raise NoValidBranchError("the given plane normal puts the target behind the reference camera")
        self.design = known_normal_design(self.m_ref, self.normal)
        self._pinv = np.linalg.pinv(self.design)
        # Plain-float copies for solve_one.
        self._y = [float(v) for v in self.m_ref[:, 1]]
        self._z = [float(v) for v in self.m_ref[:, 2]]
        self._g = [float(v) for v in self.m_ref @ self.normal]
        self._pinv_rows = [[float(v) for v in row] for row in self._pinv]

    # -- batches ----------------------------------------------------------------------------
    #: Frames solved at once: bounds the temporaries of a long recording.
    BLOCK = 4096

    def solve(self, m: ArrayLike) -> PlanarMotion:
        """Solve for points of shape (..., N, 3) in the reference's order.

        Returns
        -------
        PlanarMotion
            ``valid`` is False for frames with non-finite points or a non-positive depth
            ratio; ``residual`` is the RMS reprojection error (normalised units).
        """
        m = np.asarray(m, dtype=float)
        if m.ndim == 3 and m.shape[0] > self.BLOCK:
            parts = [self._solve_block(m[k : k + self.BLOCK]) for k in range(0, m.shape[0], self.BLOCK)]
            return PlanarMotion(
                theta=np.concatenate([p.theta for p in parts]),
                x_h=np.concatenate([p.x_h for p in parts]),
                normal=np.broadcast_to(self.normal, (m.shape[0], 3)),
                valid=np.concatenate([p.valid for p in parts]),
                residual=np.concatenate([p.residual for p in parts]),
            )
        return self._solve_block(m)

    def _solve_block(self, m: NDArray[np.float64]) -> PlanarMotion:
        m_ref = self.m_ref
        if m.shape[-2:] != m_ref.shape:
            raise GeometryError(
                f"current points have shape {m.shape[-2:]} but the reference has {m_ref.shape}"
            )
        alpha = depth_ratios(m, m_ref)
        finite = np.all(np.isfinite(m), axis=(-1, -2))
        with np.errstate(invalid="ignore"):
            valid = finite & np.all(alpha > 0.0, axis=-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv_alpha = 1.0 / alpha
            rhs = np.empty(m.shape[:-2] + (2 * m_ref.shape[0],))
            rhs[..., 0::2] = inv_alpha
            rhs[..., 1::2] = m[..., 1] * inv_alpha
        rhs = np.where(valid[..., None], rhs, 0.0)
        solution = rhs @ self._pinv.T
        theta = np.arctan2(solution[..., 1], solution[..., 0])
        x1, x2 = solution[..., 2], solution[..., 3]
        m_y = np.where(valid[..., None], m[..., 1], m_ref[:, 1])
        m_z = np.where(valid[..., None], m[..., 2], m_ref[:, 2])
        cost = self._cost(theta, x1, x2, m_y, m_z)
        for _ in range(self.refine_steps):
            theta, x1, x2, cost = self._gauss_newton_step(theta, x1, x2, cost, m_y, m_z)
        residual = np.sqrt(cost / (2 * m_ref.shape[0]))
        x_h = np.stack([x1, x2], axis=-1)
        return PlanarMotion(
            theta=np.where(valid, theta, np.nan),
            x_h=np.where(valid[..., None], x_h, np.nan),
            normal=np.broadcast_to(self.normal, m.shape[:-2] + (3,)),
            valid=valid,
            residual=np.where(valid, residual, np.nan),
        )

    def reprojection_residuals(self, motion: PlanarMotion, m: ArrayLike) -> NDArray[np.float64]:
        """Predicted minus measured ``(m_y, m_z)`` of every point, shape (..., 2N)."""
        m = np.asarray(m, dtype=float)
        q0, q1, _, _ = self._projections(motion.theta, motion.x_h[..., 0], motion.x_h[..., 1])
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.concatenate([q1 / q0 - m[..., 1], self.m_ref[:, 2] / q0 - m[..., 2]], axis=-1)

    def _projections(self, theta: NDArray[np.float64], x1: NDArray[np.float64], x2: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
        """``q = H m*_i`` for every point: its first two components, and cos, sin."""
        y, g = self.m_ref[:, 1], self.m_ref @ self.normal
        c, s = np.cos(theta)[..., None], np.sin(theta)[..., None]
        q0 = c - s * y + x1[..., None] * g
        q1 = s + c * y + x2[..., None] * g
        return q0, q1, c, s

    def _cost(self, theta: Any, x1: Any, x2: Any, m_y: Any, m_z: Any) -> NDArray[np.float64]:
        """Sum of squared reprojection errors per frame: predicted ``(q1/q0, m*_z/q0)`` vs measured."""
        q0, q1, _, _ = self._projections(theta, x1, x2)
        with np.errstate(divide="ignore", invalid="ignore"):
            r_y = q1 / q0 - m_y
            r_z = self.m_ref[:, 2] / q0 - m_z
            return np.nan_to_num(np.sum(r_y * r_y + r_z * r_z, axis=-1), nan=np.inf)

    def _gauss_newton_step(self, theta: Any, x1: Any, x2: Any, cost: Any, m_y: Any, m_z: Any) -> tuple[Any, Any, Any, Any]:
        """One safeguarded Gauss-Newton step on the reprojection error, per frame.

        The 3x3 normal equations are built from per-point sums and solved in closed form
        (Cramer's rule): no Jacobian arrays, no batched linalg calls.
        """
        y, z, g = self.m_ref[:, 1], self.m_ref[:, 2], self.m_ref @ self.normal
        q0, q1, c, s = self._projections(theta, x1, x2)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / q0
            inv2 = inv * inv
            r_y = q1 * inv - m_y
            r_z = z * inv - m_z
            dq0 = -s - c * y  # d q0 / d theta
            dq1 = c - s * y  # d q1 / d theta
            jy_t = (dq1 * q0 - q1 * dq0) * inv2
            jy_1 = -q1 * g * inv2
            jy_2 = g * inv
            jz_t = -z * dq0 * inv2
            jz_1 = -z * g * inv2
            a11 = np.sum(jy_t * jy_t + jz_t * jz_t, axis=-1)
            a12 = np.sum(jy_t * jy_1 + jz_t * jz_1, axis=-1)
            a13 = np.sum(jy_t * jy_2, axis=-1)
            a22 = np.sum(jy_1 * jy_1 + jz_1 * jz_1, axis=-1)
            a23 = np.sum(jy_1 * jy_2, axis=-1)
            a33 = np.sum(jy_2 * jy_2, axis=-1)
            b1 = np.sum(jy_t * r_y + jz_t * r_z, axis=-1)
            b2 = np.sum(jy_1 * r_y + jz_1 * r_z, axis=-1)
            b3 = np.sum(jy_2 * r_y, axis=-1)
            d1, d2, d3 = _solve_symmetric3(a11, a12, a13, a22, a23, a33, b1, b2, b3)
            new_theta, new_x1, new_x2 = theta - d1, x1 - d2, x2 - d3
            new_cost = self._cost(new_theta, new_x1, new_x2, m_y, m_z)
        better = np.isfinite(new_cost) & (new_cost < cost)
        return (
            np.where(better, new_theta, theta),
            np.where(better, new_x1, x1),
            np.where(better, new_x2, x2),
            np.where(better, new_cost, cost),
        )

    # -- one frame --------------------------------------------------------------------------
    def solve_one(self, m_y: Sequence[float], m_z: Sequence[float]) -> tuple[float, float, float, float] | None:
        """:meth:`solve` for one frame, in plain floats.

        Parameters
        ----------
        m_y, m_z : sequences of float, length N
            The current normalised points' second and third components.

        Returns
        -------
        (theta, x_h1, x_h2, residual) or None
            None when a point is not finite or a depth ratio is not positive.
        """
        y_ref, z_ref, g = self._y, self._z, self._g
        rhs = []
        for my, mz, zr in zip(m_y, m_z, z_ref):
            if not (math.isfinite(my) and math.isfinite(mz)) or mz * zr <= 0.0:
                return None
            inv_alpha = zr / mz
            rhs.append(inv_alpha)
            rhs.append(my * inv_alpha)
        c, s, x1, x2 = (sum(p * r for p, r in zip(row, rhs)) for row in self._pinv_rows)
        theta = math.atan2(s, c)
        cost = _cost_one(theta, x1, x2, m_y, m_z, y_ref, z_ref, g)
        for _ in range(self.refine_steps):
            cs, sn = math.cos(theta), math.sin(theta)
            a11 = a12 = a13 = a22 = a23 = a33 = b1 = b2 = b3 = 0.0
            for my, mz, yr, zr, gi in zip(m_y, m_z, y_ref, z_ref, g):
                q0 = cs - sn * yr + x1 * gi
                q1 = sn + cs * yr + x2 * gi
                inv = 1.0 / q0
                inv2 = inv * inv
                r_y = q1 * inv - my
                r_z = zr * inv - mz
                dq0 = -sn - cs * yr
                dq1 = cs - sn * yr
                jy_t = (dq1 * q0 - q1 * dq0) * inv2
                jy_1 = -q1 * gi * inv2
                jy_2 = gi * inv
                jz_t = -zr * dq0 * inv2
                jz_1 = -zr * gi * inv2
                a11 += jy_t * jy_t + jz_t * jz_t
                a12 += jy_t * jy_1 + jz_t * jz_1
                a13 += jy_t * jy_2
                a22 += jy_1 * jy_1 + jz_1 * jz_1
                a23 += jy_1 * jy_2
                a33 += jy_2 * jy_2
                b1 += jy_t * r_y + jz_t * r_z
                b2 += jy_1 * r_y + jz_1 * r_z
                b3 += jy_2 * r_y
            try:
                step = _solve_symmetric3(a11, a12, a13, a22, a23, a33, b1, b2, b3)
            except ZeroDivisionError:
                break
            trial = (theta - step[0], x1 - step[1], x2 - step[2])
            trial_cost = _cost_one(*trial, m_y, m_z, y_ref, z_ref, g)
            if not trial_cost < cost:
                break
            (theta, x1, x2), cost = trial, trial_cost
        return theta, x1, x2, math.sqrt(cost / (2 * len(y_ref)))


def _cost_one(theta: float, x1: float, x2: float, m_y: Sequence[float], m_z: Sequence[float],
              y_ref: Sequence[float], z_ref: Sequence[float], g: Sequence[float]) -> float:
    """Squared reprojection error of one frame (see :meth:`KnownNormalSolver._cost`)."""
    cs, sn = math.cos(theta), math.sin(theta)
    total = 0.0
    for my, mz, yr, zr, gi in zip(m_y, m_z, y_ref, z_ref, g):
        q0 = cs - sn * yr + x1 * gi
        if q0 == 0.0:
            return math.inf
        r_y = (sn + cs * yr + x2 * gi) / q0 - my
        r_z = zr / q0 - mz
        total += r_y * r_y + r_z * r_z
    return total


def _solve_symmetric3(a11: Any, a12: Any, a13: Any, a22: Any, a23: Any, a33: Any, b1: Any, b2: Any, b3: Any) -> tuple[Any, Any, Any]:
    """Solve a symmetric 3x3 system by Cramer's rule (floats or arrays alike)."""
    c11 = a22 * a33 - a23 * a23
    c12 = a13 * a23 - a12 * a33
    c13 = a12 * a23 - a13 * a22
    det = a11 * c11 + a12 * c12 + a13 * c13
    c22 = a11 * a33 - a13 * a13
    c23 = a12 * a13 - a11 * a23
    c33 = a11 * a22 - a12 * a12
    return (
        (c11 * b1 + c12 * b2 + c13 * b3) / det,
        (c12 * b1 + c22 * b2 + c23 * b3) / det,
        (c13 * b1 + c23 * b2 + c33 * b3) / det,
    )


def solve_planar_motion_known_normal(m: ArrayLike, m_ref: ArrayLike, normal: ArrayLike) -> PlanarMotion:
    """One-off use of :class:`KnownNormalSolver`: ``KnownNormalSolver(m_ref, normal).solve(m)``."""
    return KnownNormalSolver(m_ref, normal).solve(m)
