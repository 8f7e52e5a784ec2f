"""The plane normal n* common to a sequence of homographies (docs/method.md, "Decomposition into
(theta, x_h, n*)"), its refinement with the reference points m*_i, and their derivatives."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import GeometryError, NoValidBranchError
from .decomposition import FACING_PRIOR, PURE_ROTATION_TOLERANCE, front_facing, homography_candidates, select_branch, take_branch
from .homography import validate_reference_points
from .known_normal import KnownNormalSolver, point_derivatives

#: Frames the plane estimates use at most (evenly spaced): the normal and the reference
#: points need no more, and long recordings stay fast and memory flat.
REFINEMENT_FRAMES = 1500
#: :func:`refine_plane_and_reference`'s Jacobian has at most this many entries (800 frames of
#: a marker), from at least MIN_PROJECTION_FRAMES frames: it only starts the joint estimate
#: (:mod:`.bundle`), whose end point a start from 100 frames rather than 200 moves by 1-4 %
#: of its sigma (boards of 3000 frames), and each of its steps decomposes the whole Jacobian.
PROJECTION_JACOBIAN_ENTRIES = 800 * 16 * 10
MIN_PROJECTION_FRAMES = 100


def estimate_common_normal(
    H: ArrayLike,
    m_ref: ArrayLike,
    valid: ArrayLike | None = None,
) -> tuple[NDArray[np.float64], float, NDArray[np.float64] | None]:
    """The plane normal n* shared by a sequence of homographies.

    The true normal is the same in every frame, the spurious candidate's moves with the
    robot. Each front-facing normal of the best-conditioned frames is scored by how well
    every frame agrees with it (weighted by each frame's ``sigma_1 - sigma_3``); the winner
    is refined as the weighted mean of the closest candidate of every frame.

    ``H`` (F, 3, 3), ``m_ref`` (N, 3), ``valid`` (F,): frames to use. Returns the unit normal
    in F* (3,); the ``margin``, the winner's score minus the best rival's in [0, 1] (near 0 the
    sequence does not tell the branches apart, e.g. a straight drive, and the prior decided:
    :data:`~.decomposition.FACING_PRIOR`, returned when no frame has a usable translation);
    and the best rival proposal (the other branch's normal, (3,)), or None.
    """
    m_ref = np.asarray(m_ref, dtype=float)
    H = np.asarray(H, dtype=float)
    prior = np.array(FACING_PRIOR)  # a copy: the caller may change what it is given
    mask = np.all(np.isfinite(H), axis=(-1, -2))
    if valid is not None:
        mask &= np.asarray(valid, dtype=bool)
    if not np.any(mask):
        raise NoValidBranchError("no frame has a usable homography to estimate the plane normal from")
    candidates = homography_candidates(H[mask])  # at most REFINEMENT_FRAMES: the fit's sample
    front = front_facing(candidates, m_ref)
    weight = np.where(np.any(front, axis=-1), candidates.strength, 0.0)
    if not np.any(weight > PURE_ROTATION_TOLERANCE):
        return prior, 0.0, None
    normals = np.nan_to_num(candidates.normals)
    # Proposals: the front normals of the few best-conditioned frames, and the prior.
    best_frames = np.argsort(weight)[::-1][: min(5, weight.size)]
    proposals = np.array([normals[f, c] for f in best_frames for c in range(4) if front[f, c]] + [prior])
    agreement = np.einsum("fck,pk->pfc", normals, proposals)
    agreement = np.where(front[None], agreement, -1.0)
    scores = (agreement.max(axis=-1) * weight[None]).sum(axis=-1) / weight.sum()
    scores = scores + 1e-9 * (proposals @ prior)  # prefer the prior on an exact tie
    order = np.argsort(scores)[::-1]
    best = proposals[order[0]]
    rival_indices = [i for i in order[1:] if float(proposals[i] @ best) < np.cos(np.radians(5.0))]
    margin = float(scores[order[0]] - scores[rival_indices[0]]) if rival_indices else 1.0
    rival = proposals[rival_indices[0]] if rival_indices else None
    for _ in range(3):
        index, ok = select_branch(candidates, m_ref, best)
        chosen = take_branch(normals, index)
        w = np.where(ok, weight, 0.0) ** 2
        refined = (chosen * w[:, None]).sum(axis=0)
        best = refined / np.linalg.norm(refined)
    return best, max(0.0, min(1.0, margin)), rival


#: A target shape known up to a similarity: the indices of some of its points, and their
#: coordinates in the target's plane (any unit, any origin and orientation, mirrored or not).
KnownShape = tuple[Sequence[int], ArrayLike]

#: The corners of a square marker in OpenCV's order (top-left, top-right, bottom-right,
#: bottom-left), as a :data:`KnownShape`'s plane coordinates.
UNIT_SQUARE = ((0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0))


def shape_residuals(normal: ArrayLike, m: ArrayLike, shapes: Sequence[KnownShape], derivatives: str | None = None
                    ) -> NDArray[np.float64] | tuple[NDArray[np.float64], ...]:
    """How far image points are from target shapes known up to a similarity, in image units.

    Points m_i seen from a camera lie on the plane ``n^T m_bar = d`` (7): with d = 1,
    ``P_i = m_i / (n^T m_i)``. Their coordinates in the plane are matched to each known
    shape by the best similarity (Procrustes, reflection allowed: for a given handedness the
    match is linear in the coordinates), and the matched shape's points are projected back
    into the camera (9). The residual is their ``(m_y, m_z)`` minus the points': zero when
    the points and the normal agree with the shape (a wrong wall angle foreshortens it wrongly).

    ``normal`` (..., 3): the unit plane normal in the camera's frame (n* for F*), per frame;
    ``m`` (..., N, 3): normalised image points; ``shapes``: (indices, plane coordinates (K, 2)),
    K >= 3. Returns the residuals (..., R = 2 * sum of K); with ``derivatives`` "normal" also
    by the normal's components (..., R, 3), with "points" by every point's ``(m_y, m_z)`` as
    well (..., R, N, 2); "points only" returns the residuals and the latter.
    """
    m = np.asarray(m, dtype=float)
    batch = m.shape[:-2]
    normal = np.broadcast_to(np.asarray(normal, dtype=float), batch + (3,))
    e1 = np.cross(normal, [0.0, 0.0, 1.0])
    length = np.linalg.norm(e1, axis=-1, keepdims=True)
    e1 = e1 / length
    e2 = np.cross(normal, e1)
    by_normal_too = derivatives in ("normal", "points")
    if by_normal_too:  # tangents (..., D, 3): d/d n_j in row j (then the points' rows, zero here)
        d_normal = np.broadcast_to(np.eye(3), normal.shape[:-1] + (3, 3))
        da = np.cross(d_normal, [0.0, 0.0, 1.0])
        d_e1 = (da - np.einsum("...k,...jk->...j", e1, da)[..., None] * e1[..., None, :]) / length[..., None]
        d_e2 = np.cross(d_normal, e1[..., None, :]) + np.cross(normal[..., None, :], d_e1)
    residuals, by_normal, by_points = [np.zeros(batch + (0,))], [np.zeros(batch + (0, 3))], [np.zeros(batch + (0, m.shape[-2], 2))]
    for indices, layout in shapes:
        indices = list(indices)
        points = m[..., indices, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = np.einsum("...k,...nk->...n", normal, points)
            on_plane = points / depth[..., None]
        q = np.stack([np.einsum("...k,...nk->...n", e1, on_plane), np.einsum("...k,...nk->...n", e2, on_plane)], axis=-1)
        layout = np.asarray(layout, dtype=float)
        lc = layout - layout.mean(axis=0)
        fitted, proper = _similar(q, lc)
        world = normal[..., None, :] + fitted[..., :1] * e1[..., None, :] + fitted[..., 1:] * e2[..., None, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            projected = world / world[..., :1]
        residuals.append((projected[..., 1:] - points[..., 1:]).reshape(batch + (-1,)))
        if not derivatives:
            continue
        count = len(indices)
        with np.errstate(divide="ignore", invalid="ignore"):
            if by_normal_too:
                # By the normal's components d: P = p / (n . p), so dP_k/dn_d = -P_k P_d, and
                # dq_i/dn_d = de_i/dn_d . P - q_i P_d: (..., d, K, i); the match is linear in q.
                dq = np.stack([on_plane @ d_e1.swapaxes(-1, -2), on_plane @ d_e2.swapaxes(-1, -2)], axis=-1).swapaxes(-2, -3)
                dq -= q[..., None, :, :] * on_plane.swapaxes(-1, -2)[..., None]
                d_fitted = _similar(dq, lc, proper[..., None])[0]
                # The matched points on the plane, N + fitted_0 e1 + fitted_1 e2, by d: (..., d, K, 3).
                d_world = (d_normal[..., :, None, :] + d_fitted[..., :1] * e1[..., None, None, :]
                           + fitted[..., None, :, :1] * d_e1[..., :, None, :]
                           + d_fitted[..., 1:] * e2[..., None, None, :] + fitted[..., None, :, 1:] * d_e2[..., :, None, :])
                # Their projections (world_y, world_z) / world_x by d: (..., K, 2, d).
                by_normal.append(((d_world[..., 1:] - projected[..., None, :, 1:] * d_world[..., :1]) / world[..., None, :, :1])
                                 .transpose(tuple(range(len(batch))) + (-2, -1, -3)).reshape(batch + (2 * count, 3)))
            if derivatives in ("points", "points only"):
                # The match is a fixed linear map of q for each handedness: ``match`` (..., 2K, 2K).
                basis = np.eye(2 * count).reshape(2 * count, count, 2)
                match = np.where(proper[..., None, None], _similar(basis, lc, True)[0].reshape(2 * count, -1),
                                 _similar(basis, lc, False)[0].reshape(2 * count, -1))
                # d projection / d world, (..., K, 2, 3).
                out = (np.eye(3)[1:] - projected[..., 1:, None] * np.eye(3)[0]) / world[..., :1, None]
                # By each point's own (m_y, m_z) into its q, through the match, out of every projection.
                d_own = (np.eye(3)[1:] - on_plane[..., None, :] * normal[..., None, 1:, None]) / depth[..., None, None]
                into = np.stack([np.einsum("...k,...nyk->...ny", e1, d_own), np.einsum("...k,...nyk->...ny", e2, d_own)], axis=-2)
                chain = (_block_diagonal(out @ np.stack([e1, e2], axis=-1)[..., None, :, :]) @ match.swapaxes(-1, -2)
                         @ _block_diagonal(into)) - np.eye(2 * count)
                full = np.zeros(batch + (2 * count, m.shape[-2], 2))
                full[..., indices, :] = chain.reshape(batch + (2 * count, count, 2))
                by_points.append(full)
    joined = [parts[1] if len(parts) == 2 else np.concatenate(parts, axis=axis)
              for parts, axis in ((residuals, -1), (by_normal, -2), (by_points, -3))]
    if not derivatives:
        return joined[0]
    return (joined[0], joined[2]) if derivatives == "points only" else tuple(joined[:2 if derivatives == "normal" else 3])


def _block_diagonal(blocks: NDArray[np.float64]) -> NDArray[np.float64]:
    """The (..., 2K, 2K) block-diagonal matrices of (..., K, 2, 2) blocks."""
    count = blocks.shape[-3]
    out = np.zeros(blocks.shape[:-3] + (count, 2, count, 2))
    out[..., np.arange(count), :, np.arange(count), :] = np.moveaxis(blocks, -3, 0)
    return out.reshape(blocks.shape[:-3] + (2 * count, 2 * count))


def _similar(q: NDArray[np.float64], lc: NDArray[np.float64], proper: NDArray[np.bool_] | None = None
             ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """The similarity image of the centred layout ``lc`` (K, 2) nearest to points ``q``
    (..., K, 2), a reflection allowed, and whether it is proper (..., ).

    With ``M = sum_k lc_k q_k^T = [[a, b], [c, d]]`` (q centred), the best proper match is
    ``lc_k (a + d, c - b)`` rotated, the best mirrored ``(a - d, b + c)`` reflected, over
    ``sum |lc|^2``; the larger of ``|(a + d, c - b)|`` and ``|(a - d, b + c)|`` wins
    (:func:`procrustes_2d`). Given ``proper``, the same map: linear in ``q``.
    """
    q_mean = q.mean(axis=-2, keepdims=True)
    qc = q - q_mean
    a, b = qc[..., 0] @ lc[:, 0], qc[..., 1] @ lc[:, 0]
    c, d = qc[..., 0] @ lc[:, 1], qc[..., 1] @ lc[:, 1]
    if proper is None:
        proper = np.hypot(a + d, c - b) >= np.hypot(a - d, b + c)
    alpha = np.where(proper, a + d, a - d)[..., None]
    beta = np.where(proper, c - b, b + c)[..., None]
    sign = np.where(proper, 1.0, -1.0)[..., None]
    scale = 1.0 / max(float(np.sum(lc * lc)), 1e-300)
    fitted = np.stack([lc[:, 0] * alpha + lc[:, 1] * beta, sign * (lc[:, 1] * alpha - lc[:, 0] * beta)], axis=-1)
    return q_mean + scale * fitted, proper


def procrustes_2d(M: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The orthogonal polar factor ``U V^T`` (..., 2, 2) of 2x2 matrices ``M`` (..., 2, 2) and
    their singular values' sum (...).

    In closed form: with ``M = [[a, b], [c, d]]``, ``E = |(a + d, c - b)|`` and
    ``F = |(a - d, b + c)|``, the singular values are ``(E + F) / 2`` and ``|E - F| / 2``
    (so they sum to ``max(E, F)``), and ``E^2 - F^2 = 4 det M``: a rotation by
    ``atan2(c - b, a + d)`` when ``E >= F``, else a reflection.
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


def globals_derivative(normal: NDArray[np.float64], m_ref: NDArray[np.float64], by_angles: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(g, m*_y, m*_z)`` of every reference point by the global unknowns (n*'s two angles,
    then each point's y and z offsets), shape (N, 3, 2 + 2N); ``by_angles`` (3, 2) is n* by
    its two angles."""
    count = m_ref.shape[0]
    local = np.zeros((count, 3, 2 + 2 * count))
    own = np.arange(count)
    local[:, 0, :2] = m_ref @ by_angles
    local[own, 0, 2 + 2 * own], local[own, 0, 3 + 2 * own] = normal[1], normal[2]
    local[own, 1, 2 + 2 * own] = local[own, 2, 3 + 2 * own] = 1.0
    return local


def rotated_normals(normal: NDArray[np.float64], theta: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Each frame's normal ``Rz(theta) n*`` (K, 3) and its derivative by theta (K, 3)."""
    c, s = np.cos(theta), np.sin(theta)
    normals = np.stack([c * normal[0] - s * normal[1], s * normal[0] + c * normal[1], np.full_like(c, normal[2])], axis=-1)
    return normals, np.stack([-normals[:, 1], normals[:, 0], np.zeros_like(c)], axis=-1)


@dataclass(frozen=True)
class PlaneGeometry:
    """The global unknowns of the joint estimate: n*'s two angles about the unit ``base`` (3,)
    along ``u`` (horizontal) and ``v`` (3,), and the reference points' (y, z) offsets from
    ``measured_ref`` (N, 3), as measured in F*."""

    base: NDArray[np.float64]
    u: NDArray[np.float64]
    v: NDArray[np.float64]
    measured_ref: NDArray[np.float64]

    @classmethod
    def around(cls, normal: ArrayLike, measured_ref: ArrayLike) -> "PlaneGeometry":
        base = np.asarray(normal, dtype=float) / np.linalg.norm(normal)
        u = np.cross(base, [0.0, 0.0, 1.0])
        u = u / np.linalg.norm(u) if np.linalg.norm(u) > 1e-6 else np.array([0.0, 1.0, 0.0])
        return cls(base, u, np.cross(base, u), np.asarray(measured_ref, dtype=float))

    @property
    def size(self) -> int:
        """Number of global unknowns: 2 + 2N."""
        return 2 + 2 * self.measured_ref.shape[0]

    def unpack(self, p: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(normal (3,), m_ref (N, 3)) of global unknowns ``p`` (shape (2 + 2N,))."""
        normal = self.base + p[0] * self.u + p[1] * self.v
        ref = self.measured_ref.copy()
        ref[:, 1:] += p[2:].reshape(-1, 2)
        return normal / np.linalg.norm(normal), ref

    def normal_derivative(self, p: NDArray[np.float64]) -> NDArray[np.float64]:
        """The unit normal of ``p`` by its two angles, shape (3, 2)."""
        raw = self.base + p[0] * self.u + p[1] * self.v
        length = np.linalg.norm(raw)
        normal = raw / length
        tangents = np.column_stack([self.u, self.v])
        return (tangents - np.outer(normal, normal @ tangents)) / length

    def pack(self, normal: ArrayLike, m_ref: ArrayLike) -> NDArray[np.float64]:
        """The global unknowns of ``normal`` (on the base's side) and ``m_ref``."""
        normal = np.asarray(normal, dtype=float)
        normal = normal / (normal @ self.base)
        offsets = (np.asarray(m_ref, dtype=float)[:, 1:] - self.measured_ref[:, 1:]).ravel()
        return np.concatenate([[normal @ self.u, normal @ self.v], offsets])


def frame_rows(geometry: PlaneGeometry, p: NDArray[np.float64], motion: NDArray[np.float64], m: NDArray[np.float64],
                shapes: Sequence[KnownShape], derivatives: bool | str = False) -> NDArray[np.float64] | tuple[NDArray[np.float64], ...]:
    """Each frame's residuals (K, R) at the globals ``p`` and its ``motion`` (K, 3): reprojection
    errors of its points ``m`` (K, N, 3) (12), then its known shapes' residuals; with
    ``derivatives`` also their derivatives by its own (theta, x_h1, x_h2) (K, R, 3) and by ``p``
    (K, R, G), or with "compact" only the nonzero ones of the latter: the points' rows by the
    columns :func:`point_columns` names (K, 2N, 4), the shapes' by n*'s two angles (K, R - 2N, 2)."""
    normal, m_ref = geometry.unpack(p)
    frames = m.shape[0]
    predicted, *gradient = point_derivatives(normal, m_ref, motion, order=int(bool(derivatives)))
    residuals = (predicted - m[..., 1:]).reshape(frames, -1)
    # Every frame sees the shapes under its own normal Rz(theta) n*.
    normals, by_theta = rotated_normals(normal, motion[:, 0])
    if not derivatives:
        return np.concatenate([residuals, shape_residuals(normals, m, shapes)], axis=-1)
    by_angles = geometry.normal_derivative(p)
    own = gradient[0][..., :3].reshape(frames, -1, 3)
    # (g, m*_y, m*_z) by the globals (:func:`globals_derivative`): g by the angles and the
    # point's own offsets (n*_y, n*_z), m*_y and m*_z by their own offsets.
    by_g, by_y, by_z = gradient[0][..., 3], gradient[0][..., 4], gradient[0][..., 5]
    shared = np.stack([by_g * (m_ref @ by_angles[:, 0])[:, None], by_g * (m_ref @ by_angles[:, 1])[:, None],
                       by_g * normal[1] + by_y, by_g * normal[2] + by_z], axis=-1).reshape(frames, -1, 4)
    shape, by_normal = shape_residuals(normals, m, shapes, "normal")
    shape_own = np.zeros(shape.shape + (3,))
    shape_own[..., 0] = np.einsum("krj,kj->kr", by_normal, by_theta)
    rotated = np.stack([rotated_normals(by_angles[:, a], motion[:, 0])[0] for a in range(2)], axis=-1)
    shape_shared = by_normal @ rotated
    residuals, own = np.concatenate([residuals, shape], axis=1), np.concatenate([own, shape_own], axis=1)
    if derivatives == "compact":
        return residuals, own, shared, shape_shared
    dense = np.zeros(residuals.shape + (geometry.size,))
    columns = point_columns(m.shape[1])
    dense[:, np.arange(columns.shape[0])[:, None], columns] = shared
    dense[:, columns.shape[0]:, :2] = shape_shared
    return residuals, own, dense


def point_columns(count: int) -> NDArray[np.intp]:
    """The globals each point row depends on, (2N, 4): n*'s two angles and its point's two offsets."""
    point = np.arange(count)
    return np.repeat(np.column_stack([np.zeros(count, np.intp), np.ones(count, np.intp), 2 + 2 * point, 3 + 2 * point]), 2, axis=0)


def reference_rows(geometry: PlaneGeometry, p: NDArray[np.float64], shapes: Sequence[KnownShape],
                    derivatives: bool = False) -> NDArray[np.float64]:
    """F*'s residuals at the globals ``p`` (R0,): its points' offsets (its pose is the
    identity: the gauge), then its shapes'; with ``derivatives`` their derivatives (R0, G)."""
    normal, m_ref = geometry.unpack(p)
    points = 2 * m_ref.shape[0]
    if not derivatives:
        return np.concatenate([(m_ref[:, 1:] - geometry.measured_ref[:, 1:]).ravel(), shape_residuals(normal, m_ref, shapes)])
    _, by_normal, by_points = shape_residuals(normal, m_ref, shapes, "points")
    return np.concatenate([np.eye(points, geometry.size, 2),
                           np.concatenate([by_normal @ geometry.normal_derivative(p), by_points.reshape(-1, points)], axis=1)])


def projected_residuals(geometry: PlaneGeometry, p: NDArray[np.float64], frames: NDArray[np.float64],
                        shapes: Sequence[KnownShape], derivatives: bool = False) -> NDArray[np.float64]:
    """The cost of :func:`refine_plane_and_reference` at the globals ``p`` (G = 2 + 2N,) about
    ``geometry``: its residuals (R,), or with ``derivatives`` their Jacobian by ``p`` (R, G):
    every frame's (``frames`` (K, N, 3)) reprojection errors at its best pose
    (:class:`KnownNormalSolver`), F*'s rows (:func:`reference_rows`), every frame's shapes' residuals.
    """
    normal, m_ref = geometry.unpack(p)
    motion = KnownNormalSolver(m_ref, normal).solve(frames)
    x = np.column_stack([motion.theta, motion.x_h])
    points = 2 * m_ref.shape[0]
    if not derivatives:
        rows = frame_rows(geometry, p, x, frames, shapes)
    else:
        # Variable projection: each frame's pose minimises its reprojection error, so by the
        # implicit function theorem d pose / d p = -H_xx^-1 H_xp (full Hessians).
        solved = np.all(np.isfinite(x), axis=1)
        x = np.where(solved[:, None], x, 0.0)
        _, own, rows = frame_rows(geometry, p, x, frames, shapes, derivatives=True)
        predicted, _, hessian = point_derivatives(normal, m_ref, x, order=2)
        r = (predicted - frames[..., 1:]).reshape(x.shape[0], -1)
        hessian = hessian.reshape(r.shape + (6, 6))
        local = np.repeat(globals_derivative(normal, m_ref, geometry.normal_derivative(p)), 2, axis=0)  # per row
        h_xx = np.einsum("kra,krb->kab", own[:, :points], own[:, :points]) + np.einsum("kr,krab->kab", r, hessian[..., :3, :3])
        curvature = (r[..., None, None] * hessian[..., :3, 3:]).swapaxes(1, 2).reshape(r.shape[0], 3, -1)  # (K, 3, R 3)
        h_xp = np.swapaxes(own[:, :points], 1, 2) @ rows[:, :points] + curvature @ local.reshape(-1, geometry.size)
        h_xx[~solved] = np.eye(3)
        rows = rows - own @ np.linalg.solve(h_xx, h_xp)
        rows[~solved] = 0.0
    # The solver's order: each frame's m_y errors, then its m_z errors.
    reprojection = rows[:, :points].reshape((x.shape[0], -1, 2) + rows.shape[2:]).swapaxes(1, 2)
    return np.nan_to_num(np.concatenate([reprojection.reshape((-1,) + rows.shape[2:]), reference_rows(geometry, p, shapes, derivatives),
                                         rows[:, points:].reshape((-1,) + rows.shape[2:])]), copy=False)


def refine_plane_and_reference(
    m: ArrayLike, reference_index: int, normal: ArrayLike, valid: ArrayLike | None = None,
    shapes: Sequence[KnownShape] = (),
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Refine the plane normal n* and the reference points m*_i over a whole sequence.

    Variable projection: for trial values of n* (two angles about ``normal``) and of the
    reference points (their y and z), :class:`KnownNormalSolver` gives every frame its best
    (theta, x_h); the trial values minimise the sum of every frame's squared reprojection
    error, plus F*'s own (its motion pinned at identity: the gauge).

    ``m`` (F, N, 3): the sequence's normalised points; ``normal`` (3,): the start (its branch
    chosen); ``valid`` (F,): frames to use besides F*; ``shapes``: target parts known up to a
    similarity (a marker's square), :func:`shape_residuals` joins the cost. Returns n* (3,)
    and m*_i (N, 3).
    """
    from scipy.optimize import least_squares  # lazy: scipy.optimize adds to every command's start-up

    m = np.asarray(m, dtype=float)
    measured_ref = validate_reference_points(m[reference_index])
    others = np.ones(m.shape[0], dtype=bool) if valid is None else np.asarray(valid, dtype=bool).copy()
    others[reference_index] = False
    frames = m[others]
    geometry = PlaneGeometry.around(normal, measured_ref)
    # Each step decomposes the dense Jacobian: a target of many points uses fewer frames.
    rows = 2 * m.shape[1] + 2 * sum(len(indices) for indices, _ in shapes)
    count = min(REFINEMENT_FRAMES, max(MIN_PROJECTION_FRAMES, PROJECTION_JACOBIAN_ENTRIES // (rows * geometry.size)))
    if frames.shape[0] > count:
        frames = frames[np.linspace(0, frames.shape[0] - 1, count).astype(int)]
    if frames.shape[0] == 0:
        return geometry.base, measured_ref
    try:
        solution = least_squares(lambda p: projected_residuals(geometry, p, frames, shapes), np.zeros(geometry.size),
                                 jac=lambda p: projected_residuals(geometry, p, frames, shapes, derivatives=True), x_scale=1e-3, max_nfev=100)
    except GeometryError:
        return geometry.base, measured_ref
    refined_normal, refined_ref = geometry.unpack(solution.x)
    if np.any(refined_ref @ refined_normal <= 0.0):
        return geometry.base, measured_ref
    return refined_normal, refined_ref
