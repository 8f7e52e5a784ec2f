"""The Euclidean homography (12)-(18) by the three-point method."""

from __future__ import annotations

import numpy as np
import pytest

from hbvs_cli.core.homography import depth_ratios, estimate_euclidean_homography, transfer_points
from hbvs_cli.errors import (
    CollinearPointsError,
    NonFiniteInputError,
    NotEnoughPointsError,
    PointAtCameraHeightError,
    PointBehindCameraError,
)

from conftest import random_planar_scene


def test_three_point_homography_matches_ground_truth_on_1000_poses(rng):
    """H = R + x_h n*^T and alpha_i = x*_i / x_i to 1e-10, 1000 poses of 125 random targets."""
    worst_h = worst_alpha = 0.0
    poses = 0
    for scene_index in range(125):
        scene = random_planar_scene(rng, n_points=3 + scene_index % 3, n_frames=8, tilted=scene_index % 2 == 1)
        estimate = estimate_euclidean_homography(scene["m"], scene["m_ref"])
        assert np.all(estimate.valid)
        true_alpha = scene["points_ref"][:, 0][None, :] / scene["m_bar"][..., 0]
        worst_h = max(worst_h, float(np.max(np.abs(estimate.H - scene["H"]))))
        worst_alpha = max(worst_alpha, float(np.max(np.abs(depth_ratios(scene["m"], scene["m_ref"]) - true_alpha))))
        poses += scene["theta"].size
    assert poses >= 1000
    assert worst_h < 1e-10
    assert worst_alpha < 1e-10


def test_three_point_homography_third_row_is_planar(rng):
    scene = random_planar_scene(rng, 3, 5, tilted=True)
    H = estimate_euclidean_homography(scene["m"], scene["m_ref"]).H
    np.testing.assert_array_equal(H[:, 2, :], np.tile([0.0, 0.0, 1.0], (5, 1)))


def test_least_squares_with_noise_has_small_residual_and_error(rng):
    scene = random_planar_scene(rng, 8, 50, tilted=False)
    noisy = scene["m"] + np.concatenate([np.zeros((50, 8, 1)), rng.normal(0, 1e-4, (50, 8, 2))], axis=-1)
    estimate = estimate_euclidean_homography(noisy, scene["m_ref"])
    transferred = transfer_points(estimate.H, scene["m_ref"])
    transfer_rms = np.sqrt(np.mean((transferred[..., 1:] - noisy[..., 1:]) ** 2, axis=(-1, -2)))
    assert np.all(transfer_rms < 5e-4)
    assert np.max(np.abs(estimate.H - scene["H"])) < 0.05


@pytest.mark.parametrize(
    "points, error",
    [
        (np.array([[1.0, 0.1, 0.2], [1.0, -0.1, 0.3]]), NotEnoughPointsError),
        (np.array([[1.0, 0.1, 0.2], [1.0, -0.1, 0.0], [1.0, 0.0, 0.3]]), PointAtCameraHeightError),
        (np.array([[1.0, 0.0, 0.1], [1.0, 0.1, 0.2], [1.0, 0.2, 0.3]]), CollinearPointsError),
        (np.array([[1.0, 0.1, 0.2], [1.0, np.nan, 0.1], [1.0, 0.0, 0.3]]), NonFiniteInputError),
        (np.array([[-1.0, 0.1, 0.2], [1.0, -0.1, 0.1], [1.0, 0.0, 0.3]]), PointBehindCameraError),
    ],
)
def test_degenerate_reference_raises_typed_error(points, error):
    with pytest.raises(error) as info:
        estimate_euclidean_homography(points, points)
    assert str(info.value)  # a message a user can read


def test_point_that_changed_side_of_the_horizon_is_rejected():
    m_ref = np.array([[1.0, 0.1, 0.2], [1.0, -0.1, 0.1], [1.0, 0.0, 0.3]])
    flipped = m_ref.copy()
    flipped[1, 2] = -0.1
    batch = estimate_euclidean_homography(np.stack([m_ref, flipped, np.full((3, 3), np.inf)]), m_ref)
    assert batch.valid.tolist() == [True, False, False]
    assert np.all(np.isnan(batch.H[1:]))
