"""(theta, x_h) from the points when the plane normal n* is known: ``H = Rz(theta) + x_h n*^T``
is linear in (cos theta, sin theta, x_h1, x_h2), a unique answer with no branch to pick."""

from __future__ import annotations

import math
from dataclasses import fields
from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import GeometryError, NoValidBranchError
from .decomposition import PlanarMotion
from .homography import ratio_rows, validate_reference_points


def point_jacobian(c: Any, s: Any, y: Any, z: Any, g: Any, x1: Any, x2: Any) -> tuple[Any, ...]:
    """A reference point's predicted image point (12) and its Jacobian in (theta, x_h1, x_h2):
    ``c, s = cos, sin theta``, ``(y, z) = (m*_iy, m*_iz)``, ``g``, ``q0`` and ``q1`` as in
    :func:`point_derivatives`. Floats or broadcasting arrays; returns ``q0, q1, 1 / q0``,
    d(m_iy)/d(theta, x_h1, x_h2) and d(m_iz)/d(theta, x_h1) (d/d x_h2 is 0)."""
    q0 = c - s * y + x1 * g
    q1 = s + c * y + x2 * g
    dq0 = -s - c * y  # d q0 / d theta
    dq1 = c - s * y  # d q1 / d theta
    inv = 1.0 / q0
    inv2 = inv * inv
    return q0, q1, inv, (dq1 * q0 - q1 * dq0) * inv2, -q1 * g * inv2, g * inv, -z * dq0 * inv2, -z * g * inv2


def point_derivatives(normal: NDArray[np.float64], m_ref: NDArray[np.float64], motion: NDArray[np.float64],
                      order: int = 1) -> tuple[NDArray[np.float64], ...]:
    """Every reference point's (``m_ref`` (N, 3)) predicted ``(m_y, m_z)`` (..., N, 2) in every frame
    (12) for n* ``normal`` (3,) and (theta, x_h1, x_h2) per frame ``motion`` (..., 3); from ``order``
    1 its gradient by ``u`` (..., N, 2, 6), from 2 its Hessian (..., N, 2, 6, 6).

    With ``u = (theta, x_h1, x_h2, g, m*_y, m*_z)``, ``g = n*^T m*_i``, ``q0 = c - s m*_y +
    x_h1 g`` and ``q1 = s + c m*_y + x_h2 g``, the point is ``(q1 / q0, m*_z / q0)``.
    """
    y, z, g = m_ref[:, 1], m_ref[:, 2], m_ref @ normal
    c, s = np.cos(motion[..., :1]), np.sin(motion[..., :1])
    x1, x2 = motion[..., 1:2], motion[..., 2:3]
    q0 = c - s * y + x1 * g
    q1 = s + c * y + x2 * g
    with np.errstate(divide="ignore", invalid="ignore"):
        predicted = np.stack([q1 / q0, np.broadcast_to(z, q0.shape) / q0], axis=-1)
    if order == 0:
        return (predicted,)
    zero = np.zeros_like(q0)
    d_q0 = np.stack(np.broadcast_arrays(-s - c * y, g, zero, x1, -s, zero), axis=-1)
    d_q1 = np.stack(np.broadcast_arrays(c - s * y, zero, g, x2, c, zero), axis=-1)
    d_numerator = np.stack([d_q1, np.broadcast_to(np.eye(6)[5], d_q1.shape)], axis=-2)
    with np.errstate(divide="ignore", invalid="ignore"):
        gradient = (d_numerator - predicted[..., None] * d_q0[..., None, :]) / q0[..., None, None]
    if order == 1:
        return predicted, gradient
    dd_q0, dd_q1 = np.zeros(q0.shape + (6, 6)), np.zeros(q0.shape + (6, 6))
    dd_q0[..., 0, 0], dd_q1[..., 0, 0] = -c + s * y, -s - c * y
    dd_q0[..., 0, 4] = dd_q0[..., 4, 0] = -c
    dd_q1[..., 0, 4] = dd_q1[..., 4, 0] = -s
    dd_q0[..., 1, 3] = dd_q0[..., 3, 1] = dd_q1[..., 2, 3] = dd_q1[..., 3, 2] = 1.0
    # (N / q0)'' = (N'' - f q0'' - f' q0'^T - q0' f'^T) / q0 with f = N / q0 (the z numerator's N'' is 0).
    cross = gradient[..., :, None] * d_q0[..., None, None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        hessian = (np.stack([dd_q1, np.zeros_like(dd_q1)], axis=-3) - predicted[..., None, None] * dd_q0[..., None, :, :]
                   - cross - np.swapaxes(cross, -1, -2)) / q0[..., None, None, None]
    return predicted, gradient, hessian


def normal_equations(c: float, s: float, y_ref: Sequence[float], z_ref: Sequence[float], g: Sequence[float],
                     x1: float, x2: float, m_y: Sequence[float] | None = None, m_z: Sequence[float] | None = None
                     ) -> tuple[tuple[float, float, float, float, float, float], tuple[float, float, float]]:
    """``J^T J`` (upper triangle) and ``J^T r`` of one frame in plain floats (faster than numpy
    for a few points): J of :func:`point_jacobian`, r predicted minus measured ``(m_y, m_z)``."""
    a11 = a12 = a13 = a22 = a23 = a33 = b1 = b2 = b3 = 0.0
    measured = zip(m_y, m_z) if m_y is not None and m_z is not None else zip(y_ref, z_ref)
    for (my, mz), yr, zr, gi in zip(measured, y_ref, z_ref, g):
        q0, q1, inv, jy_t, jy_1, jy_2, jz_t, jz_1 = point_jacobian(c, s, yr, zr, gi, x1, x2)
        r_y = q1 * inv - my
        r_z = zr * inv - mz
        a11 += jy_t * jy_t + jz_t * jz_t
        a12 += jy_t * jy_1 + jz_t * jz_1
        a13 += jy_t * jy_2
        a22 += jy_1 * jy_1 + jz_1 * jz_1
        a23 += jy_1 * jy_2
        a33 += jy_2 * jy_2
        b1 += jy_t * r_y + jz_t * r_z
        b2 += jy_1 * r_y + jz_1 * r_z
        b3 += jy_2 * r_y
    return (a11, a12, a13, a22, a23, a33), (b1, b2, b3)


#: With ``converge``, :meth:`KnownNormalSolver.solve_one`'s most Gauss-Newton steps and the
#: halvings of a step that does not lower the error. A target seen small (50-70 px across)
#: leaves the linear start far from the minimum along the ill-determined theta - x_h2
#: direction: after the default 2 steps its squared residual is 3.5-9 times the noise's, and
#: a state filter rejects a fifth of its frames as outliers (tests/test_sim_route_loop.py).
CONVERGED_STEPS, STEP_HALVINGS = 30, 12


class KnownNormalSolver:
    """The known-normal solver for reference points ``m_ref`` (N, 3) and n* ``normal`` (3,): each
    point's two equations of (12), (18) (docs/method.md) solved by one pseudo-inverse of the
    reference's design, which ignores ``c^2 + s^2 = 1``; ``refine_steps`` safeguarded
    Gauss-Newton steps on the reprojection error follow."""

    def __init__(self, m_ref: ArrayLike, normal: ArrayLike, refine_steps: int = 2, converge: bool = False) -> None:
        self.m_ref = validate_reference_points(m_ref)
        self.refine_steps = CONVERGED_STEPS if converge else int(refine_steps)
        # A step that does not lower the error is halved (converge) or ends the refinement.
        self._step_scales = tuple(0.5**k for k in range(STEP_HALVINGS)) if converge else (1.0,)
        normal = np.asarray(normal, dtype=float)
        if normal.shape != (3,) or not np.all(np.isfinite(normal)) or np.linalg.norm(normal) < 1e-9:
            raise GeometryError("the plane normal must be a finite, non-zero 3-vector")
        self.normal = normal / np.linalg.norm(normal)
        g = self.m_ref @ self.normal
        if np.any(g <= 0.0):
            raise NoValidBranchError("the given plane normal puts the target behind the reference camera")
        # Rows [1, -m*_iy, g_i, 0] and [m*_iy, 1, 0, g_i] for the unknowns (c, s, x_h1, x_h2).
        one, zero, y = np.ones_like(g), np.zeros_like(g), self.m_ref[:, 1]
        design = np.stack([np.column_stack([one, -y, g, zero]), np.column_stack([y, one, zero, g])], axis=1)
        design = design.reshape(-1, 4)
        self._pinv = np.linalg.pinv(design)
        # Plain-float copies for solve_one.
        self._y = [float(v) for v in self.m_ref[:, 1]]
        self._z = [float(v) for v in self.m_ref[:, 2]]
        self._g = g.tolist()
        self._pinv_rows = [[float(v) for v in row] for row in self._pinv]

    #: Frames solved at once: bounds the temporaries of a long recording.
    BLOCK = 4096

    def solve(self, m: ArrayLike) -> PlanarMotion:
        """Solve for points (..., N, 3); ``valid`` is False for non-finite points or a depth
        ratio <= 0, ``residual`` is the RMS reprojection error."""
        m = np.asarray(m, dtype=float)
        if m.ndim == 3 and m.shape[0] > self.BLOCK:
            parts = [self.solve(m[k : k + self.BLOCK]) for k in range(0, m.shape[0], self.BLOCK)]
            return PlanarMotion(*(np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(PlanarMotion)))
        m_ref = self.m_ref
        if m.shape[-2:] != m_ref.shape:
            raise GeometryError(
                f"current points have shape {m.shape[-2:]} but the reference has {m_ref.shape}"
            )
        valid, rhs = ratio_rows(m, m_ref)  # the homography's (12), (18): each point's two rows in turn
        rhs = np.where(valid[..., None], rhs.reshape(valid.shape + (-1,)), 0.0)
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
        return np.concatenate(self._residuals(motion.theta, *np.moveaxis(motion.x_h, -1, 0), m[..., 1], m[..., 2]), axis=-1)

    def _residuals(self, theta: Any, x1: Any, x2: Any, m_y: Any, m_z: Any) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """:func:`point_derivatives`' predicted points minus the measured ``m_y``, ``m_z``."""
        predicted = point_derivatives(self.normal, self.m_ref, np.stack([theta, x1, x2], axis=-1), order=0)[0]
        return predicted[..., 0] - m_y, predicted[..., 1] - m_z

    def _cost(self, theta: Any, x1: Any, x2: Any, m_y: Any, m_z: Any) -> NDArray[np.float64]:
        """Sum of squared reprojection errors per frame."""
        r_y, r_z = self._residuals(theta, x1, x2, m_y, m_z)
        return np.nan_to_num(np.sum(r_y * r_y + r_z * r_z, axis=-1), nan=np.inf)

    def _gauss_newton_step(self, theta: Any, x1: Any, x2: Any, cost: Any, m_y: Any, m_z: Any) -> tuple[Any, Any, Any, Any]:
        """One Gauss-Newton step per frame, kept where it lowers the cost (Cramer's rule, no batched linalg)."""
        y, z, g = self.m_ref[:, 1], self.m_ref[:, 2], self.m_ref @ self.normal
        c, s = np.cos(theta)[..., None], np.sin(theta)[..., None]
        with np.errstate(divide="ignore", invalid="ignore"):
            q0, q1, inv, jy_t, jy_1, jy_2, jz_t, jz_1 = point_jacobian(c, s, y, z, g, x1[..., None], x2[..., None])
            r_y = q1 * inv - m_y
            r_z = z * inv - m_z
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
        return tuple(np.where(better, new, old) for new, old in zip((new_theta, new_x1, new_x2, new_cost), (theta, x1, x2, cost)))

    def solve_one(self, m_y: Sequence[float], m_z: Sequence[float]) -> tuple[float, float, float, float] | None:
        """:meth:`solve` of one frame's ``m_y``, ``m_z`` (N each) in plain floats, the closed
        loop's case: ``(theta, x_h1, x_h2, residual)``, or None where :meth:`solve` is invalid."""
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
            information, gradient = normal_equations(math.cos(theta), math.sin(theta), y_ref, z_ref, g, x1, x2, m_y, m_z)
            try:
                step = _solve_symmetric3(*information, *gradient)
            except ZeroDivisionError:
                break
            for scale in self._step_scales:
                trial = (theta - scale * step[0], x1 - scale * step[1], x2 - scale * step[2])
                trial_cost = _cost_one(*trial, m_y, m_z, y_ref, z_ref, g)
                if trial_cost < cost:
                    break
            else:
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
