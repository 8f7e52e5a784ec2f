"""The joint estimate of n*, the reference points and every frame's pose (core/bundle.py),
and the uncertainty the fit reports (core/desired.py), against an independent bound.

The geometry is the independent footage maker's (tests/footage.py: its walls, its drives,
its own pinhole projection and its own Cramer-Rao bound, no hbvs code), without rendering:
the targets' true pixels plus Gaussian noise of a known spread. That isolates the estimate
from the detectors: what is measured is how close hbvs's theta_d comes to the best any
unbiased estimator can do from those points, and whether its reported interval covers its
actual error.
"""

from __future__ import annotations

import numpy as np
import pytest

from hbvs_cli.core.bundle import estimate_plane_jointly, joint_covariance
from hbvs_cli.core.camera import CameraIntrinsics, measured_pixels_to_normalized
from hbvs_cli.core.desired import fit_desired_trajectory
from hbvs_cli.core.known_normal import KnownNormalSolver
from hbvs_cli.perception import target_kind
from hbvs_cli.core.plane import UNIT_SQUARE

import footage
from conftest import SUITE_OR_CAMPAIGN, campaign_extent

DRIVE = footage.Drive(duration=12.0, fps=5.0, speed=0.24, period=9.0)
CURVING = footage.CurvingDrive(duration=12.0, fps=5.0, start=(0.0, 0.35, -0.05), speed=0.22)


def _scene(name: str, drive: footage.Drive = DRIVE):
    wall, camera, _ = footage.case(name)
    intrinsics = CameraIntrinsics(fx=camera.fx, fy=camera.fy, cx=camera.cx, cy=camera.cy, width=camera.width, height=camera.height)
    times = drive.times()
    poses = drive.poses(times)
    shapes = [(range(k, k + 4), UNIT_SQUARE) for k in range(0, len(wall.points), 4)] if "tag" in name or "aruco" in name else []
    true_normal = np.array([np.cos(wall.yaw - poses[0, 2]), np.sin(wall.yaw - poses[0, 2]), 0.0])
    return wall, camera, intrinsics, times, poses, shapes, true_normal


def _calibration(name: str, seeds, drive: footage.Drive = DRIVE, noise_px: float = 0.1) -> dict:
    """hbvs's fit of ``seeds`` noise draws of a scene: its theta_d error against the truth,
    against the Cramer-Rao bound, and against its own reported sigma."""
    wall, camera, intrinsics, times, poses, shapes, _ = _scene(name, drive)
    ideal = footage.ideal_pixels(wall, camera, poses)
    theta_true = poses[0, 2] - poses[:, 2]
    errors, sigmas = [], []
    for seed in seeds:
        pixels = ideal + np.random.default_rng(seed).normal(0.0, noise_px, ideal.shape)
        fit = fit_desired_trajectory(times, pixels, 0, intrinsics, None, 0.3, 1.0, shapes=shapes)
        assert fit.span == slice(0, len(times))
        errors.append(fit.trajectory.evaluate(times).theta_d - theta_true)
        sigmas.append(fit.uncertainty.smooth_theta_sigma)
    errors, sigmas = np.array(errors), np.array(sigmas)
    bound = footage.cramer_rao_bound(wall, camera, poses, noise_px)["theta_sigma"]
    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))  # noqa: E731
    return {
        "theta_rms_deg": np.degrees(rms(errors)),
        "bound_deg": np.degrees(rms(bound[1:])),
        "ratio_to_bound": rms(errors) / rms(bound[1:]),
        "coverage": float(np.mean(np.abs(errors) <= 1.96 * sigmas)),
        "sigma_over_rms": rms(sigmas) / rms(errors),
    }


def test_covariance_at_the_truth_is_the_independent_cramer_rao_bound():
    """hbvs's covariance (its parameterisation, its Jacobian blocks, its Schur complement)
    evaluated at the true geometry agrees with the footage maker's own bound (the wall's
    angles, the points in its plane, the robot's poses; a dense inverse). Measured: theta_d
    sigma within 1 %, n* within 2 % (small AprilTag, 0.1 px)."""
    wall, camera, intrinsics, times, poses, _, true_normal = _scene("small_apriltag")
    m = measured_pixels_to_normalized(intrinsics, footage.ideal_pixels(wall, camera, poses))
    motion = KnownNormalSolver(m[0], true_normal).solve(m[1:])
    stacked = np.column_stack([motion.theta, motion.x_h])
    covariance = joint_covariance(m[1:], m[0], true_normal, stacked, noise=0.1 / camera.fx)
    bound = footage.cramer_rao_bound(wall, camera, poses, 0.1)
    # fx and fy differ by 0.6 %: the bound is in pixels of each axis, hbvs's in one unit.
    assert covariance.frame_sigma()[:, 0] == pytest.approx(bound["theta_sigma"][1:], rel=0.03)
    assert covariance.normal_sigma == pytest.approx(bound["normal_sigma"], rel=0.03)


def test_joint_estimate_recovers_exact_geometry_from_a_wrong_start():
    """Noise-free points, the start 3 deg off in n* and 0.5 px off in the reference points:
    the joint estimate lands on the truth."""
    wall, camera, intrinsics, times, poses, _, true_normal = _scene("red_dots", CURVING)
    m = measured_pixels_to_normalized(intrinsics, footage.ideal_pixels(wall, camera, poses))
    yaw = np.radians(3.0)
    start = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]]) @ true_normal
    shifted = m[0].copy()
    shifted[:, 1:] += 0.5 / camera.fx
    joint = estimate_plane_jointly(m[1:], shifted, start, m[0], noise=0.1 / camera.fx)
    assert np.degrees(np.arccos(min(1.0, joint.normal @ true_normal))) < 1e-3
    assert np.allclose(joint.m_ref, m[0], atol=1e-7)
    assert np.allclose(joint.motion[:, 0], poses[0, 2] - poses[1:, 2], atol=1e-7)


#: What the suite measures (red dots, 4 points, 6 noise draws of 0.1 px): theta_d 0.38 deg
#: RMS, 0.86x the bound; 100 % of frames inside the 95 % interval; sigma/RMS 1.02.
@SUITE_OR_CAMPAIGN
def test_theta_d_near_the_bound_and_the_interval_calibrated(request, extent, capsys):
    """hbvs's theta_d within 1.5x of the Cramer-Rao bound, the true value inside the
    reported 95 % interval in at least 90 % of frames, and the reported sigma within 2x of
    the actual RMS error. The campaign: 60 noise draws of each of four scenes and two
    drives (campaign figures in the report of issue 24 and bench/)."""
    scenes = [("red_dots", DRIVE)]
    seeds = range(6)
    if campaign_extent(request, extent):
        scenes = [("red_dots", DRIVE), ("bright_dots", DRIVE), ("small_apriltag", DRIVE), ("aruco_6x6", DRIVE),
                  ("red_dots", CURVING), ("small_apriltag", CURVING)]
        seeds = range(100, 160)
    for name, drive in scenes:
        figures = _calibration(name, seeds, drive)
        with capsys.disabled():
            print(f"\n{name} ({type(drive).__name__}): " + ", ".join(f"{k} {v:.3g}" for k, v in figures.items()))
        assert figures["ratio_to_bound"] <= 1.5, (name, figures)
        assert figures["coverage"] >= 0.9, (name, figures)
        assert 0.5 <= figures["sigma_over_rms"] <= 2.0, (name, figures)


def test_detector_bias_moves_the_estimate_as_the_covariance_says():
    """A bias on each point, the same over each of 4 spans of the drive (the detector's bias
    of ``bias_fraction``), moves the joint estimate's n* and every frame's theta as the
    covariance's bias columns predict (to first order, within 10 %): the exact points of a drive, then the
    same points shifted by a known draw of that bias."""
    from hbvs_cli.core.bundle import PlaneGeometry, projected_points

    rng = np.random.default_rng(3)
    normal = np.array([0.97, -0.12, 0.05])
    normal /= np.linalg.norm(normal)
    m_ref = np.column_stack([np.ones(5), rng.uniform(-0.2, 0.2, 5), rng.uniform(-0.1, 0.15, 5)])
    frames = 40
    s = np.linspace(0.0, 1.0, frames + 1)[1:]
    motion = np.column_stack([0.15 * np.sin(3 * s), 0.6 * s, 0.1 * np.sin(5 * s)])
    exact = np.concatenate([np.ones((frames, 5, 1)), projected_points(normal, m_ref, motion)], axis=-1)
    segments = np.minimum((s * 4).astype(int), 3)
    noise, size = 1e-4, 1e-6  # normalised units: the bias draw is small, so the estimate moves linearly
    covariance = joint_covariance(exact, m_ref, normal, motion, noise=noise, correlated=False, bias_fraction=1.0,
                                  bias_segments=(0, segments, segments))
    draw = rng.standard_normal((4, 5, 2))  # per span, per point, (y, z): in units of the bias's sigma
    shift = size / noise * draw
    biased = exact.copy()
    biased[..., 1:] += noise * shift[segments]
    reference = m_ref.copy()
    reference[:, 1:] += noise * shift[0]
    joint = estimate_plane_jointly(biased, reference, normal, reference, noise)
    moved = PlaneGeometry.around(normal, m_ref).pack(joint.normal, joint.m_ref)[:2]
    predicted_normal = -covariance.bias_shared[:2] @ shift.ravel()
    predicted_theta = -covariance.bias_rows(slice(None))[:, 0, :] @ shift.ravel()
    assert np.abs(moved - predicted_normal).max() < 0.1 * np.abs(predicted_normal).max()
    assert np.abs(joint.motion[:, 0] - motion[:, 0] - predicted_theta).max() < 0.1 * np.abs(predicted_theta).max()


def _sampled_drive(frames: int, seed: int):
    """A drive's exact points (``frames``, 5, 3), its poses, F*'s points and a plane's normal,
    with a sample of its frames as the fit estimates the globals from, each frame's span of
    the drive (4) and a shift as a rolling shutter's."""
    from hbvs_cli.core.bundle import projected_points

    rng = np.random.default_rng(seed)
    normal = np.array([0.97, -0.12, 0.05])
    normal /= np.linalg.norm(normal)
    m_ref = np.column_stack([np.ones(5), rng.uniform(-0.2, 0.2, 5), rng.uniform(-0.1, 0.15, 5)])
    s = np.linspace(0.0, 1.0, frames + 1)[1:]
    motion = np.column_stack([0.15 * np.sin(3 * s), 0.6 * s, 0.1 * np.sin(5 * s)])
    m = np.concatenate([np.ones((frames, 5, 1)), projected_points(normal, m_ref, motion) + rng.normal(0.0, 1e-4, (frames, 5, 2))], axis=-1)
    sample = np.unique(np.linspace(1, frames - 1, min(frames - 1, 1500)).astype(int))
    spans = np.minimum((s * 4).astype(int), 3)
    shift = rng.normal(0.0, 1e-3, (frames, 10))
    return normal, m_ref, motion, m, sample, spans, shift


def test_estimated_frames_named_by_their_rows_give_the_covariance_of_the_frames_apart():
    """The fit names which of every frame its estimated sample is (their rows), instead of
    matching each frame's points (its keys had held 8 MiB for 30 000 frames): the same
    covariance, biases and readout as with the sample given as frames of their own, and
    the globals' covariance of the sample alone."""
    normal, m_ref, motion, m, sample, spans, shift = _sampled_drive(300, 4)
    common = dict(noise=1e-4, bias_fraction=0.5)
    every = dict(frames=m, frames_motion=motion, bias_segments=(0, spans[sample], spans), shutter=(shift[0], shift[sample], shift))
    by_rows = joint_covariance(m[sample], m_ref, normal, motion[sample], estimated_rows=sample, **every, **common)
    apart = joint_covariance(m[sample], m_ref, normal, motion[sample], **every, **common)
    alone = joint_covariance(m[sample], m_ref, normal, motion[sample], bias_segments=(0, spans[sample], spans[sample]),
                             shutter=(shift[0], shift[sample], shift[sample]), **common)
    assert by_rows.readout != 0.0 and by_rows.bias_rows(slice(None)) is not None
    same = lambda a, b: np.allclose(a, b, rtol=0.0, atol=1e-9 * np.abs(b).max())  # noqa: E731  (the sums' order differs)
    for name in ("shared", "own", "sensitivity", "bias_shared"):
        assert same(getattr(by_rows, name), getattr(apart, name)), name
    assert same(by_rows.bias_rows(slice(None)), apart.bias_rows(slice(None)))
    assert by_rows.readout == pytest.approx(apart.readout, rel=1e-9)
    assert same(by_rows.shared, alone.shared) and same(by_rows.own[sample], alone.own)
    assert by_rows.readout == pytest.approx(alone.readout, rel=1e-9)


def test_a_frames_bias_is_kept_as_its_own_part_and_what_it_inherits():
    """A frame's move with the detector's biases is its own (in its span's columns only)
    plus its sensitivity to the globals times theirs: one component's rows are those of
    all three, and every column of another span is what the globals pass on."""
    normal, m_ref, motion, m, sample, spans, shift = _sampled_drive(200, 6)
    covariance = joint_covariance(m[sample], m_ref, normal, motion[sample], noise=1e-4, bias_fraction=0.5,
                                  frames=m, frames_motion=motion, estimated_rows=sample,
                                  bias_segments=(0, spans[sample], spans), shutter=(shift[0], shift[sample], shift))
    bias, width = covariance.bias_rows(slice(None)), covariance.span_bias.shape[2]
    assert bias.shape == (200, 3, 4 * width + 1)
    for component in range(3):
        assert np.allclose(covariance.bias_rows(slice(40, 90), component), bias[40:90, component], rtol=0.0, atol=1e-12 * np.abs(bias).max())
    inherited = covariance.sensitivity @ covariance.bias_shared
    other_span = np.arange(4 * width)[None, :] // width != spans[:, None]  # (frames, columns)
    assert np.array_equal(bias[:, :, :-1].transpose(0, 2, 1)[other_span], inherited[:, :, :-1].transpose(0, 2, 1)[other_span])


def test_a_bias_scaled_frame_by_frame_moves_the_estimate_by_that_much_more():
    """A detector's bias twice as large in every frame (F* too) is the same as twice the
    fraction (its effect is linear in the bias); twice as large in the last span's frames
    only moves those frames' own parts twice as far, the first span's own parts not at all,
    and the globals by less than twice."""
    normal, m_ref, motion, m, sample, spans, shift = _sampled_drive(200, 6)
    common = dict(noise=1e-4, frames=m, frames_motion=motion, estimated_rows=sample, bias_segments=(0, spans[sample], spans))
    covariance = lambda fraction, scale: joint_covariance(  # noqa: E731
        m[sample], m_ref, normal, motion[sample], bias_fraction=fraction, bias_scale=(scale[0], scale[sample], scale), **common)
    plain, doubled, twice = covariance(0.5, np.ones(200)), covariance(0.5, np.full(200, 2.0)), covariance(1.0, np.ones(200))
    assert np.allclose(doubled.bias_shared, twice.bias_shared, rtol=1e-12, atol=0.0)
    assert np.allclose(doubled.span_bias, twice.span_bias, rtol=1e-12, atol=0.0)
    last = covariance(0.5, np.where(spans == 3, 2.0, 1.0))
    assert np.allclose(last.span_bias[spans == 3], 2.0 * plain.span_bias[spans == 3], rtol=1e-12, atol=0.0)
    assert np.array_equal(last.span_bias[spans == 0], plain.span_bias[spans == 0])
    grown = np.linalg.norm(last.bias_shared) / np.linalg.norm(plain.bias_shared)
    assert 1.0 < grown < 2.0


def test_the_covariance_of_a_long_recording_takes_memory_by_the_block_not_by_the_frame():
    """Beyond the per-frame parts it returns (own, sensitivity, own bias), the covariance of
    every frame of a recording holds blocks, not copies of the frames: tracemalloc's peak
    grows by under 100 bytes a frame from 2000 to 20 000 frames. Measured: none (it had
    grown by 5.8 kB a frame, with the biases of every span for every frame, and 0.9 kB
    without). The numbers are those of the bias test above."""
    import tracemalloc

    beyond = {}
    for frames in (2000, 20000):
        normal, m_ref, motion, m, sample, spans, shift = _sampled_drive(frames, 5)
        tracemalloc.start()
        try:
            covariance = joint_covariance(m[sample], m_ref, normal, motion[sample], noise=1e-4, bias_fraction=0.5,
                                          frames=m, frames_motion=motion, estimated_rows=sample,
                                          bias_segments=(0, spans[sample], spans), shutter=(shift[0], shift[sample], shift))
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        kept = [covariance.own, covariance.sensitivity, covariance.span_bias, covariance.frame_spans, covariance.readout_bias]
        beyond[frames] = peak - sum(part.nbytes for part in kept)
    assert (beyond[20000] - beyond[2000]) / 18000 < 100


def test_a_straight_drive_with_a_known_shape_pins_n_star_without_the_branch_warning():
    """A straight drive leaves the homographies' vote between the two branches of n* open
    (margin under 1e-3), but a target of known shape (a marker's square) pins n* in the
    refinement: the fit does not claim it assumed a facing target, and n* is the true one
    within its reported sigma, whose own line says it is uncertain. Without the shape the
    same drive does warn about the branches. Measured: n* 0.29 deg off, sigma 0.69 deg
    (0.4 m ArUco 3.5-6.4 m away, 0.05 px)."""
    straight = footage.Drive(duration=12.0, fps=5.0, speed=0.24, weave=0.0, start=(0.0, 0.15, 0.12))
    wall, camera, intrinsics, times, poses, shapes, true_normal = _scene("aruco_6x6", straight)
    pixels = footage.ideal_pixels(wall, camera, poses) + np.random.default_rng(3).normal(0.0, 0.05, (len(times), len(wall.points), 2))
    said: list[str] = []
    fit = fit_desired_trajectory(times, pixels, 0, intrinsics, None, 0.3, 1.0, warn=said.append, shapes=shapes)
    assert fit.normal_margin < 1e-3
    assert not any("branches apart" in line for line in said), said
    assert any("plane normal n* uncertain" in line for line in said), said
    error = np.degrees(np.arccos(np.clip(abs(fit.normal @ true_normal), -1.0, 1.0)))
    assert error < 0.6 * fit.uncertainty.normal_sigma_deg, (error, fit.uncertainty.normal_sigma_deg)
    unshaped: list[str] = []
    fit_desired_trajectory(times, pixels, 0, intrinsics, None, 0.3, 1.0, warn=unshaped.append)
    assert any("branches apart" in line for line in unshaped)


def _fit_spying_the_readout(monkeypatch, times, pixels, intrinsics):
    """The fit, and the rolling shutter's readout (s per normalised row) it estimated (0: none)."""
    import hbvs_cli.core.desired as desired

    found = []
    original = desired._without_rolling_shutter

    def spy(*args):
        result = original(*args)
        found.append(result[3])
        return result

    monkeypatch.setattr(desired, "_without_rolling_shutter", spy)
    fit = fit_desired_trajectory(times, pixels, 0, intrinsics, None, 0.3, 1.0)
    monkeypatch.setattr(desired, "_without_rolling_shutter", original)
    return fit, found[0]


def test_a_rolling_shutter_readout_is_estimated_and_its_skew_taken_out_of_n_star(monkeypatch):
    """Each point seen at its row's time (rolling_shutter_shift's model: a 30 ms readout per
    normalised row, 0.05 px of noise, the photograph's drive): the readout is found within
    10 % (0.0288), n*'s error is less than half of the unmodelled shutter's (0.45 against
    1.17 deg; 0.21 without a shutter) and inside its reported 95 % interval (sigma 0.34 deg).
    Without a shutter the fit is the same, bit for bit, as with the readout never estimated
    (READOUT_CHI2 infinite)."""
    import hbvs_cli.core.desired as desired

    wall, camera, intrinsics, times, poses, _, true_normal = _scene("photo")
    ideal = footage.ideal_pixels(wall, camera, poses)
    readout = 0.03
    row = measured_pixels_to_normalized(intrinsics, ideal)[..., 2]  # m_z, as rolling_shutter_shift reads rows
    noise = np.random.default_rng(5).normal(0.0, 0.05, ideal.shape)
    angle = lambda fit: np.degrees(np.arccos(min(1.0, abs(fit.normal @ true_normal))))  # noqa: E731
    skewed = ideal + np.gradient(ideal, times, axis=0) * (readout * row)[..., None] + noise
    shuttered, found = _fit_spying_the_readout(monkeypatch, times, skewed, intrinsics)
    plain, none_found = _fit_spying_the_readout(monkeypatch, times, ideal + noise, intrinsics)
    monkeypatch.setattr(desired, "READOUT_CHI2", np.inf)
    unmodelled = fit_desired_trajectory(times, skewed, 0, intrinsics, None, 0.3, 1.0)
    never = fit_desired_trajectory(times, ideal + noise, 0, intrinsics, None, 0.3, 1.0)
    assert found == pytest.approx(readout, rel=0.1)
    assert angle(shuttered) < angle(unmodelled) / 2.0
    assert angle(shuttered) < 1.96 * shuttered.uncertainty.normal_sigma_deg
    assert none_found == 0.0
    for name in ("normal", "m_ref", "theta", "x_h", "residual"):
        assert np.array_equal(getattr(plain, name), getattr(never, name), equal_nan=True)
    for name, value in vars(plain.uncertainty).items():
        other = getattr(never.uncertainty, name)
        if callable(value):  # error_modes: the same columns at the frames' times
            value, other = value(times), other(times)
        assert np.array_equal(value, other, equal_nan=True), name


def test_a_frame_with_a_dot_taken_for_another_does_not_bend_the_plane():
    """The 25-level dots' geometry (``low_contrast_dots``), 0.13 px of noise (the footage's),
    and in the last, closest frame one dot 90 px off (a neighbour taken for it: noise draw 4 of
    bench/CALIBRATION.md's campaign, n* 14.6 deg off). That frame fails the residual gate, and
    is left out of the plane's estimates as it was of the trajectory: n* the fit's without the
    frame (measured: to 0.001 deg on draws 0-7; 25 deg off when the frame pulled it)."""
    wall, camera, intrinsics, times, poses, _, true_normal = _scene("low_contrast_dots")
    ideal = footage.ideal_pixels(wall, camera, poses)
    for seed in range(3):
        pixels = ideal + np.random.default_rng(seed).normal(0.0, 0.13, ideal.shape)
        swapped, without = pixels.copy(), pixels.copy()
        swapped[-1, 1] += [0.0, 90.0]
        without[-1] = np.nan
        normals = [fit_desired_trajectory(times, p, 0, intrinsics, None, 0.3, 1.0, errors=target_kind("dots").errors).normal for p in (swapped, without)]
        apart = np.degrees(np.arccos(min(1.0, abs(normals[0] @ normals[1]))))
        assert apart < 0.01, (seed, apart)
