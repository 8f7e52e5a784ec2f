"""Functions the core shares instead of copying: one point Jacobian, typed statuses, one
projection, one frame interval, one depth check."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from hbvs_cli.core.camera import DEFAULT_CAMERA, normalized_to_pixels, pixels_to_normalized, pixels_to_normalized_floats
from hbvs_cli.core.depth import check_depth
from hbvs_cli.core.desired import DEFAULT_FRAME_INTERVAL, taught_frame_interval
from hbvs_cli.core.estimation import Observation, ObservationStatus, dropped
from hbvs_cli.core.known_normal import KnownNormalSolver, point_jacobian
from hbvs_cli.core.state_filter import FilterOutcome, measurement_information
from hbvs_cli.sim.world import default_world
from hbvs_cli.errors import InvalidValueError

from oracles import ground_truth


def _predicted(m_ref, normal, state):
    """m_y, m_z of every reference point under (theta, x_h1, x_h2), from H = Rz + x_h n*^T."""
    theta, x1, x2 = state
    H = np.array([[math.cos(theta), -math.sin(theta), 0.0], [math.sin(theta), math.cos(theta), 0.0], [0.0, 0.0, 1.0]])
    H = H + np.outer([x1, x2, 0.0], normal)
    q = m_ref @ H.T
    return np.concatenate([q[:, 1] / q[:, 0], q[:, 2] / q[:, 0]])


def test_the_point_jacobian_is_the_derivative_of_the_projection():
    world = default_world("dots", dots=5)
    m_ref, normal, _ = world.reference_geometry(np.array([0.0, 0.1, 0.05]))
    state = np.array([0.1, -0.2, 0.15])
    g = m_ref @ normal
    c, s = math.cos(state[0]), math.sin(state[0])
    q0, q1, inv, jy_t, jy_1, jy_2, jz_t, jz_1 = point_jacobian(c, s, m_ref[:, 1], m_ref[:, 2], g, state[1], state[2])
    analytic = np.column_stack([np.concatenate([jy_t, jz_t]), np.concatenate([jy_1, jz_1]), np.concatenate([jy_2, 0 * jz_1])])
    step = 1e-7
    numeric = np.column_stack([
        (_predicted(m_ref, normal, state + step * e) - _predicted(m_ref, normal, state - step * e)) / (2 * step)
        for e in np.eye(3)
    ])
    np.testing.assert_allclose(analytic, numeric, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(np.concatenate([q1 * inv, m_ref[:, 2] * inv]), _predicted(m_ref, normal, state), rtol=1e-12)
    # The state filter's information is J^T J of the same Jacobian; the float path agrees to the bit.
    np.testing.assert_array_equal(measurement_information(m_ref, normal, state), analytic.T @ analytic)
    for k in range(m_ref.shape[0]):
        one = point_jacobian(c, s, float(m_ref[k, 1]), float(m_ref[k, 2]), float(g[k]), float(state[1]), float(state[2]))
        assert one[3] == jy_t[k] and one[7] == jz_1[k]


def test_the_solver_batch_and_single_frame_paths_agree(rng):
    world = default_world("dots", dots=4)
    reference = np.array([0.0, 0.0, 0.0])
    m_ref, normal, _ = world.reference_geometry(reference)
    solver = KnownNormalSolver(m_ref, normal)
    poses = np.column_stack([rng.uniform(0.5, 2.0, 20), rng.uniform(-0.3, 0.3, 20), rng.uniform(-0.2, 0.2, 20)])
    m = np.array([world.normalized_points(p) for p in poses]) + rng.normal(0, 2e-4, (20, 4, 3)) * [0, 1, 1]
    batch = solver.solve(m)
    for k in range(20):
        theta, x1, x2, residual = solver.solve_one(m[k, :, 1].tolist(), m[k, :, 2].tolist())
        assert theta == pytest.approx(batch.theta[k], abs=1e-12) and residual == pytest.approx(batch.residual[k], rel=1e-9)
        assert (x1, x2) == pytest.approx(tuple(batch.x_h[k]), abs=1e-12)
    truth_theta, truth_xh = ground_truth(world, poses, reference)
    assert np.max(np.abs(batch.theta - truth_theta)) < 5e-3  # 3.3e-3 rad measured at 0.1 px


def test_statuses_and_filter_outcomes_are_enums_that_write_the_same_words():
    assert [s.value for s in ObservationStatus] == ["ok", "dropped", "missing", "invalid", "outlier", "occluded"]
    assert [o.value for o in FilterOutcome] == ["fused", "gated", "started", "predicted"]
    assert dropped().status is ObservationStatus.DROPPED and not dropped().lost
    lost = Observation(None, status=ObservationStatus.OCCLUDED)
    assert lost.lost and f"target lost ({lost.status})" == "target lost (occluded)"
    assert json.dumps({"lost_reason": lost.status, "filter": FilterOutcome.GATED}) == '{"lost_reason": "occluded", "filter": "gated"}'


def test_one_projection_one_frame_interval_one_depth_check():
    world = default_world("dots", dots=3)
    pose = np.array([0.5, 0.2, 0.1])
    pixels = world.pixels(pose)
    np.testing.assert_allclose(pixels_to_normalized(DEFAULT_CAMERA, pixels), world.normalized_points(pose), atol=1e-12)
    np.testing.assert_array_equal(pixels, normalized_to_pixels(DEFAULT_CAMERA, world.points_in_camera(pose)))
    m_y, m_z = pixels_to_normalized_floats(DEFAULT_CAMERA, pixels)
    np.testing.assert_array_equal(np.column_stack([m_y, m_z]), pixels_to_normalized(DEFAULT_CAMERA, pixels)[:, 1:])
    assert taught_frame_interval(np.arange(10) / 15.0) == pytest.approx(1 / 15)
    assert taught_frame_interval(np.array([0.0]), 0.05) == 0.05
    assert taught_frame_interval(None, None) == DEFAULT_FRAME_INTERVAL == 1 / 30
    assert check_depth(2.5, "d") == 2.5
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(InvalidValueError, match="d must be a positive depth in metres"):
            check_depth(bad, "d")
