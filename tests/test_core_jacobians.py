"""The analytic Jacobians of the plane estimates (core/plane.py, core/bundle.py) against
central finite differences of the residuals they differentiate: the known shapes' residuals,
the joint estimate's frame and F* rows, the detector-bias rows, and the variable-projection
cost of the plane refinement (at its solution, where every frame's pose is its optimum)."""

from __future__ import annotations

import numpy as np
import pytest

from hbvs_cli.core.camera import CameraIntrinsics, measured_pixels_to_normalized
from hbvs_cli.core import plane
from hbvs_cli.core.decomposition import PlanarMotion
from hbvs_cli.core.known_normal import KnownNormalSolver
from hbvs_cli.core.plane import UNIT_SQUARE, PlaneGeometry, point_derivatives, projected_residuals, refine_plane_and_reference, shape_residuals

import footage
from oracles import bias_rows

STEP = 1e-6


def _differences(function, x):
    """Central differences of ``function`` (any output shape) at ``x`` (shape (D,)): (..., D)."""
    columns = []
    for j in range(x.size):
        step = np.zeros_like(x)
        step[j] = STEP
        columns.append((function(x + step) - function(x - step)) / (2 * STEP))
    return np.stack(columns, axis=-1)


def _relative(analytic, numeric):
    return float(np.max(np.abs(analytic - numeric)) / np.max(np.abs(numeric)))


def _drive(name: str, noise_px: float = 0.1, seed: int = 0):
    """Normalised points of a footage scene's drive (5 fps, 12 s) with pixel noise, its shapes."""
    wall, camera, _ = footage.case(name)
    intrinsics = CameraIntrinsics(fx=camera.fx, fy=camera.fy, cx=camera.cx, cy=camera.cy, width=camera.width, height=camera.height)
    drive = footage.Drive(duration=12.0, fps=5.0, speed=0.24, period=9.0)
    poses = drive.poses(drive.times())
    pixels = footage.ideal_pixels(wall, camera, poses) + np.random.default_rng(seed).normal(0.0, noise_px, (len(poses), len(wall.points), 2))
    shapes = [(range(k, k + 4), UNIT_SQUARE) for k in range(0, len(wall.points), 4)] if "tag" in name or "aruco" in name else []
    normal = np.array([np.cos(wall.yaw - poses[0, 2]), np.sin(wall.yaw - poses[0, 2]), 0.0])
    return measured_pixels_to_normalized(intrinsics, pixels), shapes, normal


def test_shape_residuals_derivatives():
    """By the normal and by every point's (m_y, m_z), two shapes sharing a point, one mirrored;
    "points only" gives the latter alone, the same to the bit."""
    rng = np.random.default_rng(1)
    m = np.concatenate([np.ones((5, 8, 1)), rng.uniform(-0.2, 0.2, (5, 8, 2))], axis=-1)
    normals = np.array([0.95, 0.2, 0.1]) + rng.normal(0.0, 0.05, (5, 3))
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    shapes = [(range(4), UNIT_SQUARE), ([4, 5, 6, 7, 1], rng.uniform(0.0, 1.0, (5, 2)))]
    residuals, by_normal, by_points = shape_residuals(normals, m, shapes, "points")
    alone = shape_residuals(normals, m, shapes, "points only")  # without the normal's (the bias rows')
    assert len(alone) == 2 and np.array_equal(alone[0], residuals) and np.array_equal(alone[1], by_points)
    for k in range(m.shape[0]):
        numeric = _differences(lambda n: shape_residuals(n, m[k], shapes), normals[k])
        assert _relative(by_normal[k], numeric) < 1e-6
        def moved(yz):
            points = m[k].copy()
            points[:, 1:] = yz.reshape(-1, 2)
            return shape_residuals(normals[k], points, shapes)
        assert _relative(by_points[k].reshape(by_points.shape[1], -1), _differences(moved, m[k, :, 1:].ravel())) < 1e-6


@pytest.mark.parametrize("name", ["red_dots", "small_apriltag"])
def test_joint_estimate_jacobian(name):
    """Every frame's rows by its own pose and by the globals (away from the base normal), F*'s
    rows by the globals, and the detector-bias rows by the measured points."""
    m, shapes, normal = _drive(name)
    frames, motion = m[1::6], np.column_stack([np.linspace(0.0, 0.2, m[1::6].shape[0]), np.linspace(0.0, 0.5, m[1::6].shape[0]), np.full(m[1::6].shape[0], 0.02)])
    geometry = PlaneGeometry.around(normal, m[0])
    p = np.random.default_rng(2).normal(0.0, 1e-3, geometry.size)
    residuals, by_own, by_globals = plane.frame_rows(geometry, p, motion, frames, shapes, derivatives=True)
    frame_residuals = lambda q, x: plane.frame_rows(geometry, q, x.reshape(-1, 3), frames, shapes)  # noqa: E731
    assert _relative(by_globals, _differences(lambda q: frame_residuals(q, motion.ravel()), p)) < 1e-6
    numeric_own = _differences(lambda x: frame_residuals(p, x), motion.ravel()).reshape(residuals.shape + (-1, 3))
    assert _relative(by_own, np.einsum("krkj->krj", numeric_own)) < 1e-6
    reference = lambda q: plane.reference_rows(geometry, q, shapes)  # noqa: E731
    assert _relative(plane.reference_rows(geometry, p, shapes, derivatives=True), _differences(reference, p)) < 1e-6
    def shifted(yz):
        points = frames.copy()
        points[..., 1:] = yz.reshape(frames.shape[0], -1, 2)
        return plane.frame_rows(geometry, p, motion, points, shapes)
    numeric_bias = _differences(shifted, frames[..., 1:].ravel()).reshape(residuals.shape + (frames.shape[0], -1))
    assert _relative(bias_rows(frames, geometry.unpack(p)[0], motion, shapes), np.einsum("krkb->krb", numeric_bias)) < 1e-6


class _ConvergedSolver(KnownNormalSolver):
    """The known-normal solver, then Newton's method on each frame's reprojection error to
    machine precision: the poses the variable-projection Jacobian assumes (the solver's two
    safeguarded Gauss-Newton steps stop about 1e-7 px short, which moves its derivative)."""

    def solve(self, m):
        motion = super().solve(m)
        x = np.column_stack([motion.theta, motion.x_h])
        for _ in range(6):
            predicted, gradient, hessian = point_derivatives(self.normal, self.m_ref, x, order=2)
            r = predicted - m[..., 1:]
            step = np.linalg.solve(np.einsum("knca,kncb->kab", gradient[..., :3], gradient[..., :3]) + np.einsum("knc,kncab->kab", r, hessian[..., :3, :3]),
                                   np.einsum("knca,knc->ka", gradient[..., :3], r)[..., None])[..., 0]
            x = x - step
        return PlanarMotion(x[:, 0], x[:, 1:], motion.normal, motion.valid, motion.residual)


@pytest.mark.parametrize("name", ["red_dots", "small_apriltag"])
def test_plane_refinement_jacobian(name, monkeypatch):
    """The variable-projection cost's Jacobian (poses by the implicit function theorem, full
    Hessians) near the refinement's solution, 0.1 px of noise, every pose at its optimum."""
    m, shapes, normal = _drive(name)
    solved_normal, solved_ref = refine_plane_and_reference(m, 0, normal, shapes=shapes)
    geometry = PlaneGeometry.around(normal, m[0])
    p = geometry.pack(solved_normal, solved_ref) + np.random.default_rng(3).normal(0.0, 1e-4, geometry.size)
    monkeypatch.setattr(plane, "KnownNormalSolver", _ConvergedSolver)
    analytic = projected_residuals(geometry, p, m[1:], shapes, derivatives=True)
    assert _relative(analytic, _differences(lambda q: projected_residuals(geometry, q, m[1:], shapes), p)) < 1e-6
