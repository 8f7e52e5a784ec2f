"""n* (two angles), the reference points' ``(m*_iy, m*_iz)`` and every frame's planar pose at
once, by maximum likelihood on every point's reprojection error (12): the close frames pin the
n* that F* alone does not; and the estimate's covariance (docs/uncertainty.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .homography import validate_reference_points
from .known_normal import KnownNormalSolver, point_derivatives
from .plane import KnownShape, PlaneGeometry, frame_rows, point_columns, reference_rows, rotated_normals, shape_residuals

#: The robust loss's scale, in measured point noise: residuals beyond it count less.
ROBUST_SCALE = 3.0

#: Residuals beyond this many robust spreads are left out of the measured point noise.
OUTLIER_SPREADS = 4.0

#: The joint estimate stops when a step lowers the cost by less than this fraction of it
#: (far below what one noise draw changes; a flat valley along n*'s yaw otherwise takes dozens of steps).
COST_TOLERANCE = 1e-5

#: Iterations of the joint estimate at most (it starts from the variable-projection estimate).
MAX_EVALUATIONS = 60


def projected_points(normal: NDArray[np.float64], m_ref: NDArray[np.float64], motion: NDArray[np.float64]) -> NDArray[np.float64]:
    """:func:`~.known_normal.point_derivatives`' predicted ``(m_y, m_z)`` (K, N, 2) alone."""
    return point_derivatives(normal, m_ref, motion, order=0)[0]


@dataclass(frozen=True)
class JointEstimate:
    """What :func:`estimate_plane_jointly` gives: ``normal`` (3,), ``m_ref`` (N, 3), the frames'
    (theta, x_h1, x_h2) ``motion`` (K, 3), and ``cost``, half the sum of squared residuals."""

    normal: NDArray[np.float64]
    m_ref: NDArray[np.float64]
    motion: NDArray[np.float64]
    cost: float


def estimate_plane_jointly(m: ArrayLike, m_ref: ArrayLike, normal: ArrayLike, measured_ref: ArrayLike,
                           noise: float, shapes: Sequence[KnownShape] = ()) -> JointEstimate:
    """n*, the reference points and every frame's pose by maximum likelihood, jointly.

    ``m`` (K, N, 3): the frames besides F* (every point found); ``m_ref`` (N, 3) and
    ``normal`` (3,; its branch chosen): the start; ``measured_ref`` (N, 3): the reference points
    as measured in F*; ``noise``: the point noise (normalised units), :data:`ROBUST_SCALE` times
    it the robust loss's scale; ``shapes``: :func:`~.plane.shape_residuals`. Returns the start
    when the solver fails or puts the target behind F*.
    """
    from scipy.optimize import least_squares  # lazy: scipy.optimize adds to every command's start-up
    from scipy.sparse import csr_matrix

    m = np.asarray(m, dtype=float)
    measured_ref = validate_reference_points(measured_ref)
    start_ref = np.asarray(m_ref, dtype=float)
    geometry = PlaneGeometry.around(normal, measured_ref)
    solved = KnownNormalSolver(start_ref, geometry.base).solve(m)
    start_motion = np.nan_to_num(np.column_stack([solved.theta, solved.x_h]))  # 0 where not solved
    frames, n_global = m.shape[0], geometry.size
    start = JointEstimate(geometry.base, start_ref, start_motion, float("nan"))
    if frames == 0:
        return start
    p0 = geometry.pack(geometry.base, start_ref)
    per_frame = frame_rows(geometry, p0, start_motion, m, shapes).shape[1]
    reference_count = reference_rows(geometry, p0, shapes).size

    def residuals(p: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.nan_to_num(np.concatenate([frame_rows(geometry, p[:n_global], p[n_global:].reshape(frames, 3), m, shapes).ravel(),
                                             reference_rows(geometry, p[:n_global], shapes)]), nan=1.0, posinf=1.0, neginf=-1.0)

    # Block-arrow, and sparser: a frame's rows depend on its own 3 unknowns and on n*'s two
    # angles, a point's on its reference point's two offsets too; F*'s on the globals.
    points = 2 * m.shape[1]
    shape_rows = per_frame - points
    point_globals = point_columns(points // 2)
    own = np.broadcast_to((n_global + 3 * np.arange(frames)[:, None] + np.arange(3))[:, None], (frames, per_frame, 3))
    columns = np.concatenate([np.concatenate([np.concatenate([np.broadcast_to(point_globals, (frames, points, 4)), own[:, :points]], axis=2).reshape(frames, -1),
                                              np.concatenate([np.broadcast_to([0, 1], (frames, shape_rows, 2)), own[:, points:]], axis=2).reshape(frames, -1)],
                                             axis=1).ravel(), np.tile(np.arange(n_global), reference_count)])
    counts = np.concatenate([np.tile(np.repeat([7, 5], [points, shape_rows]), frames), np.full(reference_count, n_global)])
    # 32-bit indices when they fit, as scipy would make them (else it converts them at every step).
    index = np.int32 if columns.size < 2**31 else np.int64
    columns, pointers = columns.astype(index), np.concatenate([[0], np.cumsum(counts)]).astype(index)

    def jacobian(p: NDArray[np.float64]) -> csr_matrix:
        motion = p[n_global:].reshape(frames, 3)
        at, by_own, by_point_globals, by_angles = frame_rows(geometry, p[:n_global], motion, m, shapes, derivatives="compact")
        by_points = np.concatenate([by_point_globals, by_own[:, :points]], axis=2)
        by_shapes = np.concatenate([by_angles, by_own[:, points:]], axis=2)
        by_points[~np.isfinite(at[:, :points])] = 0.0  # where the residuals are replaced (nan_to_num)
        by_shapes[~np.isfinite(at[:, points:])] = 0.0
        data = np.concatenate([by_points.reshape(frames, -1), by_shapes.reshape(frames, -1)], axis=1).ravel()
        data = _finite(np.concatenate([data, reference_rows(geometry, p[:n_global], shapes, derivatives=True).ravel()]))
        return csr_matrix((data, columns, pointers), shape=(frames * per_frame + reference_count, n_global + 3 * frames))

    x0 = np.concatenate([p0, start_motion.ravel()])
    # Plain least squares first (from far off, a robust loss's steps stall), then Huber's loss.
    try:
        solution = least_squares(residuals, x0, jac=jacobian, method="trf", x_scale="jac",
                                 ftol=COST_TOLERANCE, max_nfev=MAX_EVALUATIONS)
        solution = least_squares(residuals, solution.x, jac=jacobian, method="trf", loss="huber",
                                 f_scale=ROBUST_SCALE * max(noise, 1e-9), x_scale="jac", ftol=COST_TOLERANCE, max_nfev=MAX_EVALUATIONS)
    except (ValueError, np.linalg.LinAlgError):
        return start
    solved_normal, solved_ref = geometry.unpack(solution.x[:n_global])
    if np.any(solved_ref @ solved_normal <= 0.0) or not np.all(np.isfinite(solution.x)):
        return start
    return JointEstimate(solved_normal, solved_ref, solution.x[n_global:].reshape(frames, 3), float(0.5 * np.sum(solution.fun ** 2)))


def measured_point_noise(residuals: ArrayLike) -> float:
    """The point noise (normalised units, per coordinate) that reprojection errors (K, 2N) show:
    their RMS within :data:`OUTLIER_SPREADS` robust spreads (the median absolute residual as a
    Gaussian's sigma) of zero, corrected for the 3 unknowns each frame fits to its ``2N``."""
    r = np.asarray(residuals, dtype=float)
    rows = r.shape[1]
    r = r[np.all(np.isfinite(r), axis=1)]
    if r.size == 0:
        return float("nan")
    spread = 1.4826 * float(np.median(np.abs(r)))
    inliers = r[np.abs(r) <= OUTLIER_SPREADS * spread]
    rms = float(np.sqrt(np.mean(inliers**2))) if inliers.size else spread
    return rms * float(np.sqrt(rows / max(rows - 3, 1)))


#: The longest lag (as a fraction of the frames) over which :func:`correlation_inflation`
#: sums the residuals' correlation from frame to frame.
CORRELATION_LAG_FRACTION = 1.0 / 8.0


def correlation_inflation(residuals: ArrayLike) -> float:
    """The factor (>= 1) on the point noise's variance for errors alike in neighbouring frames
    (a marker's edges sampled at a phase that changes slowly with the pose): the long-run
    variance of each residual's series over the frames (K, R), in time order (Newey and West:
    Bartlett's weights to a lag of :data:`CORRELATION_LAG_FRACTION` of the frames), over its
    plain variance."""
    r = np.asarray(residuals, dtype=float)
    r = r[np.all(np.isfinite(r), axis=1)]
    frames = r.shape[0]
    lag = int(np.floor(CORRELATION_LAG_FRACTION * frames))
    if lag < 1:
        return 1.0
    r = r - r.mean(axis=0)
    variance = float(np.mean(r * r))
    if variance <= 0.0:
        return 1.0
    weights = 1.0 - np.arange(1, lag + 1) / (lag + 1.0)
    covariances = np.array([np.sum(r[:-j] * r[j:]) / r.size for j in range(1, lag + 1)])
    return max(1.0, 1.0 + 2.0 * float(weights @ covariances) / variance)


@dataclass(frozen=True)
class JointCovariance:
    """The joint estimate's covariance, ``noise^2 (J^T J)^-1``, in parts (docs/uncertainty.md).

    ``shared`` (G, G): of the global unknowns (n*'s two angles about the solution, rad, then
    the reference points' offsets); ``own`` (K, 3, 3): of each frame's (theta, x_h1, x_h2) were
    the globals exact; ``sensitivity`` (K, 3, G): how each frame's estimate moves with an error
    of the globals (its full covariance is ``own + sensitivity shared sensitivity^T``);
    ``noise``: the point noise the residuals show (normalised units).

    ``bias_shared`` (G, C): how the globals move with each of C biases: a detector's, of one
    standard deviation on each point's coordinate in each of S spans of the drive (``S 2N``
    columns, :func:`joint_covariance`'s ``bias_fraction``), then a rolling shutter's (one
    column), then the D shifts every frame shares (its ``common_shift``); their covariances add
    ``bias bias^T``, common to the frames. A frame's move with them (:meth:`bias_rows`) is that
    inherited, ``sensitivity bias_shared``, plus its own, kept apart (a board's frame takes ``3
    2N`` numbers, not ``3 S 2N``): ``span_bias`` (K, 3, 2N), with the biases of its span
    ``frame_spans`` (K,); ``readout_bias`` (K, 3), with the shutter's; ``image_shift_bias`` (K,
    3, D), with the shared shifts' (the last D columns). Each None where there is no such bias.

    ``readout``, ``readout_sigma``: with ``shutter``, the readout (s per normalised row) the
    residuals show, and its standard deviation ``sqrt(inflation) noise / |s_perp|``, ``s_perp``
    the part of the shift the other unknowns cannot absorb (the Schur complement of ``J^T J``
    on the readout's column).
    """

    shared: NDArray[np.float64]
    own: NDArray[np.float64]
    sensitivity: NDArray[np.float64]
    noise: float
    bias_shared: NDArray[np.float64] | None = None
    span_bias: NDArray[np.float64] | None = None
    frame_spans: NDArray[np.intp] | None = None
    readout_bias: NDArray[np.float64] | None = None
    image_shift_bias: NDArray[np.float64] | None = None
    readout: float = 0.0
    readout_sigma: float = 0.0

    @property
    def normal_sigma(self) -> float:
        """The angle (rad) of n*'s error: the root of the trace of its 2x2 covariance."""
        biased = 0.0 if self.bias_shared is None else float(np.sum(self.bias_shared[:2] ** 2))
        return float(np.sqrt(max(np.trace(self.shared[:2, :2]) + biased, 0.0)))

    def bias_rows(self, rows: slice, component: int | None = None) -> NDArray[np.float64] | None:
        """How the frames ``rows`` (of K) move with each bias, shape (n, 3, C), or (n, C) for
        one ``component`` of (theta, x_h1, x_h2); None: no bias."""
        if self.bias_shared is None:
            return None
        components = slice(None) if component is None else [component]
        moved = self.sensitivity[rows][:, components] @ self.bias_shared
        if self.span_bias is not None and self.frame_spans is not None:
            width = self.span_bias.shape[2]
            columns = self.frame_spans[rows, None] * width + np.arange(width)  # (n, 2N): each frame's span
            frames, parts = np.arange(moved.shape[0])[:, None, None], np.arange(moved.shape[1])[:, None]
            moved[frames, parts, columns[:, None, :]] += self.span_bias[rows][:, components]
        shift_columns = 0 if self.image_shift_bias is None else self.image_shift_bias.shape[2]
        if self.readout_bias is not None:
            moved[:, :, -1 - shift_columns] += self.readout_bias[rows][:, components]
        if self.image_shift_bias is not None:
            moved[:, :, moved.shape[2] - shift_columns:] += self.image_shift_bias[rows][:, components]
        return moved if component is None else moved[:, 0]

    def frame_sigma(self) -> NDArray[np.float64]:
        """Each frame's standard deviation of (theta, x_h1, x_h2), shape (K, 3), formed
        :data:`BLOCK_FRAMES` frames at a time."""
        sigma = np.empty(self.own.shape[:2])
        for k in range(0, sigma.shape[0], BLOCK_FRAMES):
            rows = slice(k, k + BLOCK_FRAMES)
            inherited = np.einsum("kag,gh,kah->ka", self.sensitivity[rows], self.shared, self.sensitivity[rows])
            bias = self.bias_rows(rows)
            biased = 0.0 if bias is None else np.sum(bias**2, axis=-1)
            sigma[rows] = np.sqrt(np.maximum(np.einsum("kaa->ka", self.own[rows]) + inherited + biased, 0.0))
        return sigma


#: Frames whose Jacobian blocks are held at once: memory stays bounded for many points.
BLOCK_FRAMES = 256
#: At most these bytes in one block's Jacobian (its frames' rows by the globals): a target of
#: many points (a board's 54 corners: 95 kB a frame) is taken fewer frames at a time.
BLOCK_BYTES = 4 << 20


def joint_covariance(estimated: ArrayLike, m_ref: ArrayLike, normal: ArrayLike, motion: ArrayLike,
                     noise: float | None = None, shapes: Sequence[KnownShape] = (),
                     frames: ArrayLike | None = None, frames_motion: ArrayLike | None = None,
                     estimated_rows: ArrayLike | None = None, correlated: bool = True, bias_fraction: float = 0.0,
                     bias_segments: tuple[int, ArrayLike, ArrayLike] | None = None,
                     shutter: tuple[ArrayLike, ArrayLike, ArrayLike] | None = None,
                     readout_estimated: bool = False,
                     common_shift: Callable[[NDArray[np.float64]], NDArray[np.float64]] | None = None,
                     bias_scale: tuple[float, ArrayLike, ArrayLike] | None = None) -> JointCovariance:
    """``inflation noise^2 (J^T J)^-1`` of the joint estimate, by the Schur complement on the globals.

    ``J^T J`` is block-arrow (a 3x3 ``D_k`` per frame, the globals' ``A``, their coupling
    ``B_k``): the globals' covariance is ``noise^2 (A - sum B_k^T D_k^-1 B_k)^-1``, a frame's
    own ``noise^2 D_k^-1``, its sensitivity to the globals ``-D_k^-1 B_k``.

    ``estimated`` (K, N, 3), ``motion`` (K, 3): the frames (besides F*) the globals were
    estimated from, and their solved (theta, x_h1, x_h2); ``m_ref`` (N, 3), ``normal`` (3,): the
    solution's; ``noise``: the point noise (normalised units), by default
    :func:`measured_point_noise` of the estimated frames; ``frames`` (F, N, 3), ``frames_motion``
    (F, 3): frames to give the own covariance and sensitivity of (default: ``estimated``), e.g.
    every frame of a recording whose globals came from a sample of it; ``estimated_rows`` (K,):
    which frame of ``frames`` each estimated frame is, -1 for one that is not among them (by
    default none is; without ``frames``, each is itself); ``correlated``: grow the covariance by
    :func:`correlation_inflation` of the estimated frames' residuals (in the order given: time
    order), else the frames are independent.

    ``bias_fraction``: a detector's bias on each point's coordinates, the same over a span of the
    drive and independent between spans, as a standard deviation in point noise (0: none);
    ``bias_segments`` (int, (K,), (F,)): the span (0, 1, ...) of F*, of every estimated frame and
    of every frame of ``frames`` (without it, no bias); ``bias_scale`` (float, (K,), (F,)): the
    bias's size in each, in multiples of ``bias_fraction`` (default 1). ``shutter`` ((2N,), (K,
    2N), (F, 2N)): the same frames' points' move per unit of a rolling shutter's readout
    (:func:`rolling_shutter_shift`), fitted to the residuals and taken out of them before the
    noise is measured (counted, not modelled); ``readout_estimated``: the readout was one more
    unknown of the estimate (taken out of ``estimated`` and ``frames``), its column then the
    move by ``readout_sigma``. ``common_shift(points)``: how points (K, N, 3) move with one
    standard deviation of each of D errors every frame shares, F* too (K, 2N, D; normalised
    units, each point's ``(m_y, m_z)`` in turn): bloom's (:func:`uniform_shift`), the
    calibration's (:func:`~.camera.calibration_shifts`). The estimate's move with each of these
    is the bias (:class:`JointCovariance`; why and how: docs/uncertainty.md, "The uncertainty").
    """
    estimated = np.asarray(estimated, dtype=float)
    motion = np.asarray(motion, dtype=float)
    if frames is None:
        frames, rows = estimated, np.arange(estimated.shape[0])
    else:
        frames = np.asarray(frames, dtype=float)
        rows = np.full(estimated.shape[0], -1) if estimated_rows is None else np.array(estimated_rows, dtype=np.intp)
    frames_motion = motion if frames_motion is None else np.asarray(frames_motion, dtype=float)
    m_ref = np.asarray(m_ref, dtype=float)
    points = 2 * m_ref.shape[0]
    reference_segment, estimated_segments, frame_segments = (0, 0, 0) if bias_segments is None else bias_segments
    if bias_segments is None:
        bias_fraction = 0.0
    shifts = [_finite(np.asarray(x, dtype=float)) for x in shutter or (np.zeros(points), np.zeros((len(estimated), points)), np.zeros((len(frames), points)))]
    estimated_segments = np.broadcast_to(np.asarray(estimated_segments, np.intp), estimated.shape[:1])
    frame_segments = np.broadcast_to(np.asarray(frame_segments, np.intp), frames.shape[:1])
    count = int(max(reference_segment, estimated_segments.max(initial=0), frame_segments.max(initial=0))) + 1
    # One pass over the pool: ``frames``, then the estimated frames not among them; ``weight``
    # counts the times each is an estimated frame. A block's rows are gathered as it is reached,
    # and only what later steps need is kept per frame: a long recording's frames are not copied.
    missing = np.flatnonzero(rows < 0)
    where = rows.copy()
    where[missing] = frames.shape[0] + np.arange(missing.size)
    extra = (estimated[missing], motion[missing], shifts[1][missing])
    pool_size = frames.shape[0] + missing.size
    pooled = lambda block: [_rows_then(whole, more, block) for whole, more in zip((frames, frames_motion, shifts[2]), extra)]  # noqa: E731
    pool_segments = np.concatenate([frame_segments, estimated_segments[missing]])
    weight = np.bincount(where, minlength=pool_size).astype(float)
    reference_scale, estimated_scale, frame_scale = bias_scale or (1.0, np.ones(estimated.shape[0]), np.ones(frames.shape[0]))
    pool_scale = np.concatenate([frame_scale, np.asarray(estimated_scale)[missing]])[:, None, None]
    by_row = np.argsort(where, kind="stable")  # the estimated frames in the pool's order
    rows_in_order = where[by_row]
    geometry = PlaneGeometry.around(normal, m_ref)
    reference = reference_rows(geometry, np.zeros(geometry.size), shapes, derivatives=True)
    shared_info = reference.T @ reference
    spans = np.zeros((count, geometry.size, points))  # J^T W's Schur part on the globals, span by span
    inverse_own, coupling = np.empty((pool_size, 3, 3)), np.empty((pool_size, 3, geometry.size))
    own_rhs = np.zeros((pool_size, 3, points)) if bias_fraction > 0.0 else None
    residuals = np.empty((estimated.shape[0], points))  # the estimated frames' own, in their (time) order
    shutter_own, shutter_globals = np.zeros((pool_size, 3)), -reference[:points].T @ shifts[0]
    # The shared shifts' columns: F*'s points' move, then each frame's as its block is reached.
    reference_shift = np.zeros((points, 0)) if common_shift is None else _finite(common_shift(m_ref[None])[0])
    shared_shifts = reference_shift.shape[1]
    shift_own, shift_globals = np.zeros((pool_size, 3, shared_shifts)), -reference[:points].T @ reference_shift
    block_frames = int(np.clip(BLOCK_BYTES // max(8 * reference.shape[0] * geometry.size, 1), 16, BLOCK_FRAMES))
    for k in range(0, pool_size, block_frames):
        block = slice(k, min(k + block_frames, pool_size))
        pool, pool_motion, pool_shift = pooled(block)
        at, own, shared = frame_rows(geometry, np.zeros(geometry.size), pool_motion, pool, shapes, derivatives=True)
        own, shared = _finite(own), _finite(shared)
        coupling[block] = np.swapaxes(own, 1, 2) @ shared  # B_k = J_k^T J_kg; D_k = J_k^T J_k
        inverse_own[block] = np.linalg.pinv(np.swapaxes(own, 1, 2) @ own, rcond=1e-12, hermitian=True)
        weighted = weight[block, None, None] * shared
        # Sums over frames and rows as matrix products (BLAS): plain einsum loops over every index.
        reduced = np.swapaxes(weight[block, None, None] * coupling[block], 1, 2) @ inverse_own[block]  # B_k^T D_k^-1, weighted
        shared_info += (weighted.reshape(-1, geometry.size).T @ shared.reshape(-1, geometry.size)
                        - np.swapaxes(reduced, 0, 1).reshape(geometry.size, -1) @ coupling[block].reshape(-1, geometry.size))
        mine = by_row[slice(*np.searchsorted(rows_in_order, [block.start, block.stop]))]
        residuals[mine] = at[where[mine] - k, :points]
        # How the rows move with each point's shift, [-I; by_shapes], and X^T of it.
        biased = shutter is not None or bias_fraction > 0.0 or shared_shifts > 0
        by_shapes = _shape_bias_rows(pool, normal, pool_motion, shapes) if biased else None
        through = lambda x: np.swapaxes(x[:, points:], 1, 2) @ by_shapes - np.swapaxes(x[:, :points], 1, 2)  # noqa: E731
        if shutter is not None:  # as the bias below, for the one column of the shutter's shift
            change = np.concatenate([-pool_shift, np.einsum("krb,kb->kr", by_shapes, pool_shift)], axis=1)
            shutter_own[block] = np.einsum("kra,kr->ka", own, change)
            shutter_globals += np.einsum("krg,kr->g", weighted, change) - np.einsum("kga,ka->g", reduced, shutter_own[block])
        if shared_shifts:  # as the shutter's column, for each shift every frame shares
            moves = _finite(common_shift(pool))
            change = np.concatenate([-moves, by_shapes @ moves], axis=1)
            shift_own[block] = np.swapaxes(own, 1, 2) @ change
            shift_globals += np.einsum("krg,krd->gd", weighted, change) - np.einsum("kga,kad->gd", reduced, shift_own[block])
        if own_rhs is not None:
            # Each estimated frame's J_kg^T W_k - B_k^T D_k^-1 J_k^T W_k, summed over its span's frames.
            own_rhs[block] = through(own) * pool_scale[block]
            per_frame = through(weighted) * pool_scale[block] - reduced @ own_rhs[block]
            for span in np.unique(pool_segments[block]):
                spans[span] += per_frame[pool_segments[block] == span].sum(axis=0)
    shared_inverse = np.linalg.pinv(shared_info, rcond=1e-12, hermitian=True)
    readout = 0.0
    if shutter is not None:
        # The estimate's move per unit readout (as the bias's below), and the residuals' change
        # it leaves: the shift less what the estimated frames' poses and the globals absorb.
        moved_globals = shared_inverse @ shutter_globals
        moved = np.einsum("kab,kb->ka", inverse_own[where], shutter_own[where] - coupling[where] @ moved_globals)  # the estimated frames'
        visible = np.empty_like(residuals)
        for k in range(0, estimated.shape[0], block_frames):
            block = slice(k, k + block_frames)
            # The points' rows only (the shapes' do not move them): a shift moves them by -1.
            _, own, shared = frame_rows(geometry, np.zeros(geometry.size), motion[block], estimated[block], (), derivatives=True)
            visible[block] = -shifts[1][block] - np.einsum("kra,ka->kr", _finite(own), moved[block]) - _finite(shared) @ moved_globals
        finite = np.all(np.isfinite(residuals), axis=1)
        unabsorbed = float(np.sum(visible[finite] ** 2))
        readout = float(np.sum(residuals[finite] * visible[finite]) / max(unabsorbed, 1e-300))
        residuals = residuals - readout * visible
        unabsorbed += float(np.sum((shifts[0] + reference[:points] @ moved_globals) ** 2))  # F*'s points
    if noise is None:
        noise = measured_point_noise(residuals)
    inflation = correlation_inflation(residuals) if correlated else 1.0
    variance = inflation * noise**2
    detector_bias = bias_fraction * noise
    fitted_readout, readout_sigma = readout, float(np.sqrt(variance / unabsorbed)) if readout != 0.0 else 0.0
    if readout_estimated:
        readout = readout_sigma
    inverse_own, coupling = inverse_own[:frames.shape[0]], coupling[:frames.shape[0]]
    # A frame's move with the biases: its own, D_k^-1 (J_k^T W_k in its span's columns), plus
    # what it inherits through the globals, -D_k^-1 B_k bias_shared (JointCovariance.bias_rows).
    bias_columns, span_bias, readout_bias, image_shift_bias = [], None, None, None
    if detector_bias > 0.0 and own_rhs is not None:
        spans[reference_segment] -= reference_scale * reference[:points].T  # F*'s own points carry its span's bias
        bias_columns.append(detector_bias * shared_inverse @ np.concatenate(list(spans), axis=1))
        span_bias = own_rhs[:frames.shape[0]]  # formed in J_k^T W_k's place below
    if readout != 0.0:  # the shutter's effect on the estimate: one more column of the bias
        bias_columns.append(readout * moved_globals[:, None])
        readout_bias = readout * np.einsum("kab,kb->ka", inverse_own, shutter_own[:frames.shape[0]])
    if shared_shifts:  # the estimate's move with the shared shifts: D more columns
        bias_columns.append(shared_inverse @ shift_globals)
        image_shift_bias = inverse_own @ shift_own[:frames.shape[0]]
    bias_shared = np.column_stack(bias_columns) if bias_columns else None
    for k in range(0, frames.shape[0], BLOCK_FRAMES):  # in place: no second frame-long array
        block = slice(k, k + BLOCK_FRAMES)
        if span_bias is not None:
            span_bias[block] = detector_bias * (inverse_own[block] @ span_bias[block])
        coupling[block] = -(inverse_own[block] @ coupling[block])  # the sensitivity, -D_k^-1 B_k
    inverse_own *= variance
    return JointCovariance(
        shared=variance * shared_inverse,
        own=inverse_own,
        sensitivity=coupling,
        noise=float(noise),
        bias_shared=bias_shared,
        span_bias=span_bias,
        frame_spans=None if span_bias is None else np.array(frame_segments),
        readout_bias=readout_bias,
        image_shift_bias=image_shift_bias,
        readout=fitted_readout,
        readout_sigma=readout_sigma,
    )


def uniform_shift(size: float) -> Callable[[NDArray[np.float64]], NDArray[np.float64]]:
    """:func:`joint_covariance`'s ``common_shift`` for a shift of every point of every frame
    by the same ``size`` (normalised units, 1 sigma) along each image direction: (K, 2N, 2),
    every point's m_y, then every point's m_z."""
    def shifts(points: NDArray[np.float64]) -> NDArray[np.float64]:
        moves = np.zeros((points.shape[0], 2 * points.shape[1], 2))
        moves[:, 0::2, 0], moves[:, 1::2, 1] = size, size
        return moves
    return shifts


def rolling_shutter_shift(points: ArrayLike, t: ArrayLike) -> NDArray[np.float64]:
    """How every point ``(m_y, m_z)`` (K, N, 2) of frames at times ``t`` (K,) (s) moves per unit
    of a rolling shutter's readout (s per normalised row; rows read out one after the other,
    the middle one at the frame's time): its image velocity times its row ``m_z``, (K, 2N)."""
    points = np.asarray(points, dtype=float)
    if points.shape[0] < 2:
        return np.zeros((points.shape[0], 2 * points.shape[1]))
    return (np.gradient(points, np.asarray(t, dtype=float), axis=0) * points[..., 1:]).reshape(points.shape[0], -1)


def _shape_bias_rows(m: NDArray[np.float64], normal: ArrayLike, motion: ArrayLike, shapes: Sequence[KnownShape]) -> NDArray[np.float64]:
    """How every frame's shape residuals move with a shift of each point's (m_y, m_z), (K, R - 2N, 2N)
    (a point's own reprojection errors move by -1)."""
    normals, _ = rotated_normals(np.asarray(normal, dtype=float) / np.linalg.norm(normal), np.asarray(motion, dtype=float)[:, 0])
    return _finite(shape_residuals(normals, m, shapes, "points only")[1].reshape(m.shape[0], -1, 2 * m.shape[1]))


def _rows_then(first: NDArray[Any], then: NDArray[Any], rows: slice) -> NDArray[Any]:
    """Rows ``rows`` of ``first`` followed by ``then``, without concatenating the two whole."""
    if rows.stop <= first.shape[0]:
        return first[rows]
    if rows.start >= first.shape[0]:
        return then[rows.start - first.shape[0]:rows.stop - first.shape[0]]
    return np.concatenate([first[rows.start:], then[:rows.stop - first.shape[0]]])


def _finite(values: NDArray[np.float64]) -> NDArray[np.float64]:
    """``np.nan_to_num(values)``, and ``values`` themselves when all are finite (the usual
    case): the check is a tenth of the copy's cost, on every block of frames."""
    return values if np.isfinite(values).all() else np.nan_to_num(values)
