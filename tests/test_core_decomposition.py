"""Decomposition into (theta, x_h, n*) with the physically right branch."""

from __future__ import annotations

import numpy as np
import pytest

from hbvs_cli.core.camera import DEFAULT_CAMERA, pixels_to_normalized
from hbvs_cli.core.decomposition import homography_candidates
from hbvs_cli.core.known_normal import KnownNormalSolver
from hbvs_cli.core.plane import estimate_common_normal
from hbvs_cli.core.frames import rotation_z
from hbvs_cli.core.homography import estimate_euclidean_homography
from hbvs_cli.errors import GeometryError, NoValidBranchError

from conftest import random_planar_scene
from oracles import decompose_homography, ground_truth


def test_zero_wrong_branches_over_1000_poses(rng):
    """Sequence-common normal, then the front-facing branch closest to it: exact theta, x_h."""
    poses = wrong = 0
    worst_theta = worst_xh = worst_normal = 0.0
    for index in range(125):
        scene = random_planar_scene(rng, n_points=3 + index % 3, n_frames=8, tilted=index % 2 == 1)
        H = estimate_euclidean_homography(scene["m"], scene["m_ref"]).H
        normal, _, _ = estimate_common_normal(H, scene["m_ref"])
        motion = decompose_homography(H, scene["m_ref"], normal)
        err_theta = np.abs(motion.theta - scene["theta"])
        err_xh = np.max(np.abs(motion.x_h - scene["x_h"]), axis=-1)
        wrong += int(np.sum((err_theta > 1e-8) | (err_xh > 1e-8)))
        worst_theta = max(worst_theta, float(err_theta.max()))
        worst_xh = max(worst_xh, float(err_xh.max()))
        worst_normal = max(worst_normal, float(np.max(np.abs(normal - scene["normal"]))))
        poses += err_theta.size
    assert poses >= 1000
    assert wrong == 0
    assert worst_theta < 1e-8 and worst_xh < 1e-8 and worst_normal < 1e-8


def test_known_normal_solver_is_exact_and_branch_free(rng):
    worst = 0.0
    for index in range(125):
        scene = random_planar_scene(rng, n_points=3 + index % 3, n_frames=8, tilted=index % 2 == 1)
        motion = KnownNormalSolver(scene["m_ref"], scene["normal"]).solve(scene["m"])
        assert np.all(motion.valid)
        worst = max(worst, float(np.max(np.abs(motion.theta - scene["theta"]))), float(np.max(np.abs(motion.x_h - scene["x_h"]))))
        assert np.all(motion.residual < 1e-10)
    assert worst < 1e-10


def test_four_candidates_contain_the_truth_and_the_front_test_keeps_it(rng):
    scene = random_planar_scene(rng, 3, 20, tilted=False)
    candidates = homography_candidates(scene["H"])
    normals = candidates.normals  # (F, 4, 3)
    assert np.all(np.min(np.linalg.norm(normals - scene["normal"][None, None, :], axis=-1), axis=-1) < 1e-9)
    front = np.all(np.einsum("fck,nk->fcn", normals, scene["m_ref"]) > 0, axis=-1)
    # The front test keeps one of each +-n pair at most, and never drops the true normal.
    assert np.all((front.sum(axis=-1) >= 1) & (front.sum(axis=-1) <= 2))
    true_index = np.argmin(np.linalg.norm(normals - scene["normal"][None, None, :], axis=-1), axis=-1)
    assert np.all(front[np.arange(front.shape[0]), true_index])


def test_pure_rotation_and_identity():
    m_ref = np.array([[1.0, 0.1, 0.2], [1.0, -0.2, 0.1], [1.0, 0.0, -0.3]])
    for theta in (0.0, 0.3):
        motion = decompose_homography(rotation_z(theta), m_ref)
        assert bool(motion.valid) and motion.theta == pytest.approx(theta, abs=1e-12)
        np.testing.assert_allclose(motion.x_h, 0.0, atol=1e-12)


def test_no_valid_branch_raises():
    m_ref = np.array([[1.0, 0.2, 0.2], [1.0, -0.2, 0.1], [1.0, 0.05, -0.3]])
    # Not the homography of any plane in front of F*: every decomposition puts a point behind.
    H = np.array([[0.8, 0.3, -0.3], [-0.3, 0.2, 0.4], [0.4, -0.2, 1.1]])
    assert not bool(decompose_homography(H, m_ref).valid)
    with pytest.raises(GeometryError):
        KnownNormalSolver(m_ref, [0.0, 0.0, 0.0])
    with pytest.raises(NoValidBranchError):
        KnownNormalSolver(m_ref, [-1.0, 0.0, 0.0])


def test_refinement_lowers_the_error_under_noise(rng):
    scene = random_planar_scene(rng, 4, 400, tilted=False)
    noisy = scene["m"].copy()
    noisy[..., 1:] += rng.normal(0.0, 1e-3, noisy[..., 1:].shape)
    linear = KnownNormalSolver(scene["m_ref"], scene["normal"], refine_steps=0).solve(noisy)
    refined = KnownNormalSolver(scene["m_ref"], scene["normal"]).solve(noisy)
    rms = lambda motion: float(np.sqrt(np.mean((motion.theta - scene["theta"]) ** 2)))  # noqa: E731
    assert rms(refined) < rms(linear)


#: Measured with this test's seed (20031027), six dots on the default 2.0 m x 0.9 m poster:
#: RMS theta error 0.94 deg and RMS x_h error 1.2e-2 over 385 poses. Large, and physical:
#: for a nearly fronto-parallel target a yaw and a lateral shift move the image almost
#: alike, so their errors are correlated (-1.00). The bounds leave 35 % for other seeds.
NOISE_THETA_RMS_BOUND_DEG = 1.3
NOISE_XH_RMS_BOUND = 0.016


def test_theta_error_with_half_pixel_noise(rng, capsys):
    """0.5 px Gaussian noise, 640x480, f = 500 px, a 2 m dot target 3-6 m away."""
    from hbvs_cli.sim.world import default_world

    world = default_world("dots", dots=6)
    errors_theta, errors_xh = [], []
    for _ in range(400):
        reference_pose = np.array([world.wall_x - rng.uniform(3.0, 6.0), rng.uniform(-0.3, 0.3), rng.normal(0, 0.05)])
        pose = reference_pose + [rng.uniform(0.0, 1.5), rng.uniform(-0.3, 0.3), rng.normal(0, 0.08)]
        if not (world.in_view(pose) and world.in_view(reference_pose)):
            continue
        m_ref, normal, _ = world.reference_geometry(reference_pose)
        noisy_px = world.pixels(pose) + rng.normal(0.0, 0.5, (6, 2))
        motion = KnownNormalSolver(m_ref, normal).solve(pixels_to_normalized(DEFAULT_CAMERA, noisy_px))
        theta_true, x_h_true = ground_truth(world, pose, reference_pose)
        errors_theta.append(float(motion.theta - theta_true))
        errors_xh.append(np.asarray(motion.x_h) - x_h_true)
    rms_theta = float(np.degrees(np.sqrt(np.mean(np.square(errors_theta)))))
    rms_xh = float(np.sqrt(np.mean(np.square(errors_xh))))
    with capsys.disabled():
        print(f"\n0.5 px noise, 3-6 m, {len(errors_theta)} poses: RMS theta error {rms_theta:.3f} deg, RMS x_h error {rms_xh:.2e}")
    assert len(errors_theta) > 300
    assert rms_theta < NOISE_THETA_RMS_BOUND_DEG
    assert rms_xh < NOISE_XH_RMS_BOUND


def test_a_known_square_pins_the_normal_of_a_small_distant_marker():
    """One 0.6 m marker 4-5.5 m away: the square's foreshortening in every frame joins the
    motion in telling n* (core/plane.py). Measured over seeds 0-7 at 0.05 px: RMS n* error
    0.79 deg from the motion alone, 0.62 deg with the square (on the independent footage of
    tests/test_perception_footage.py, 0.4 m ArUco marker: 4.6 deg -> 0.29 deg)."""
    from hbvs_cli.core.camera import pixels_to_normalized
    from hbvs_cli.core.plane import UNIT_SQUARE, refine_plane_and_reference, shape_residuals
    from hbvs_cli.sim.world import default_world

    world = default_world("aruco", wall_x=5.5)
    t = np.linspace(0.0, 1.0, 40)
    poses = np.column_stack([1.5 * t, 0.4 * np.sin(2.5 * t), 0.25 * np.sin(3.0 * t) - 0.1])
    _, truth, _ = world.reference_geometry(poses[0])
    square = [(range(4), UNIT_SQUARE)]
    exact = world.normalized_points(poses[0])
    assert np.max(np.abs(shape_residuals(truth, exact, square))) < 1e-12
    yawed = rotation_z(np.radians(3.0)) @ truth
    assert np.max(np.abs(shape_residuals(yawed, exact, square))) * world.camera.fx > 0.05  # px
    angle = lambda n: np.degrees(np.arccos(np.clip(n @ truth, -1.0, 1.0)))  # noqa: E731
    loose, pinned = [], []
    for seed in range(8):
        noise = np.random.default_rng(seed).normal(0.0, 0.05, (40, 4, 2))
        m = pixels_to_normalized(world.camera, np.array([world.pixels(p) for p in poses]) + noise)
        loose.append(angle(refine_plane_and_reference(m, 0, np.array([1.0, 0.0, 0.0]))[0]))
        pinned.append(angle(refine_plane_and_reference(m, 0, np.array([1.0, 0.0, 0.0]), shapes=square)[0]))
    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))  # noqa: E731
    print(f"\nn* error RMS, 0.6 m marker at 5.5 m, 0.05 px: {rms(loose):.2f} deg (motion), {rms(pinned):.2f} deg (square)")
    assert rms(pinned) < 0.7 and rms(pinned) < rms(loose)
