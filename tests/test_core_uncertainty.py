"""The parts of the fit's uncertainty that the footage tests do not isolate: the growth of
the covariance for point errors correlated from frame to frame (core/bundle.py), and the
heading tolerance the gain suggestion carries (core/gains.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hbvs_cli.core.bundle import correlation_inflation
from hbvs_cli.core.gains import INTERVAL_SIGMAS, heading_tolerance
from hbvs_cli.perception import target_kind


def test_independent_errors_are_not_inflated():
    """White noise over 200 frames of 8 coordinates: the factor is 1 (clamped) or barely above."""
    residuals = np.random.default_rng(3).normal(0.0, 1e-4, (200, 8))
    assert 1.0 <= correlation_inflation(residuals) < 1.15


def test_errors_correlated_over_frames_are_inflated_by_their_long_run_variance():
    """An AR(1) series with coefficient 0.8 has a long-run variance (1 + 0.8) / (1 - 0.8) = 9
    times its variance; Bartlett's weights to 1/8 of 4000 frames recover most of it."""
    rng = np.random.default_rng(5)
    noise = rng.normal(0.0, 1.0, (4000, 6))
    series = np.empty_like(noise)
    series[0] = noise[0]
    for k in range(1, len(noise)):
        series[k] = 0.8 * series[k - 1] + noise[k]
    assert 6.0 < correlation_inflation(series) < 9.5  # measured 6.9


def test_few_frames_or_no_spread_give_no_inflation():
    assert correlation_inflation(np.ones((5, 4))) == 1.0
    assert correlation_inflation(np.zeros((40, 4))) == 1.0


def test_heading_tolerance_is_the_default_or_the_interval():
    assert heading_tolerance(0.2, 0.05) == 0.2
    assert heading_tolerance(0.2, 0.5) == pytest.approx(INTERVAL_SIGMAS * 0.5)
    assert math.isnan(heading_tolerance(0.2, float("nan")))


def _uncertainty(normal_deg: float, theta_deg: float, x_h1: float):
    from hbvs_cli.core.desired import FitUncertainty

    flat = lambda value: np.full(50, value)  # noqa: E731
    return FitUncertainty(normal_sigma_deg=normal_deg, point_noise_px=0.02, theta_sigma=flat(np.radians(theta_deg)), x_h1_sigma=flat(x_h1),
                          smooth_theta_sigma=flat(np.radians(theta_deg)), smooth_x_h1_sigma=flat(x_h1))


def test_uncertain_fit_warning_is_one_line_naming_what_would_help():
    """n* uncertain by more than 0.5 deg: one line with the sigmas, naming both ways of giving
    the target's geometry, a curving drive and another reference frame."""
    from hbvs_cli.core.desired import uncertainty_warning

    line = uncertainty_warning(_uncertainty(1.234, 0.2, 1e-3))
    assert "\n" not in line and "plane normal n* uncertain by 1.2 deg" in line and "theta_d by 0.20 deg" in line
    assert "--target-size" in line and "--target-points FILE" in line and "curves" in line and "--reference last" in line


@pytest.mark.parametrize("kind, theta_deg, x_h1, warned", [
    ("aruco", 0.30, 1e-3, False),  # within a marker's 0.35 deg
    ("aruco", 0.40, 1e-3, True),
    ("chessboard", 0.30, 6e-3, True),  # x_hd1 over a board's 5e-3
    ("dots", 0.08, 1e-3, False),
    ("dots", 0.12, 1e-3, True),  # over a dot target's 0.1 deg, though n* is within 0.5 deg
    ("texture", 0.12, 1e-3, True),
    (None, 0.9, 9e-3, False),  # no kind: n*'s sigma alone decides
])
def test_uncertain_fit_warning_when_theta_d_or_x_hd1_exceeds_the_kinds_precision(kind, theta_deg, x_h1, warned):
    """With n* at 0.3 deg (under 0.5), the splines' RMS sigma against the kind's precision
    (its registered :class:`~hbvs_cli.core.desired.DetectorErrors`)."""
    from hbvs_cli.core.desired import DetectorErrors, uncertainty_warning

    line = uncertainty_warning(_uncertainty(0.3, theta_deg, x_h1), target_kind(kind).errors if kind else DetectorErrors())
    assert (line is not None) == warned
    if warned:
        assert "plane normal n* uncertain" in line and f"{kind} targets usually give" in line


def test_detector_bias_is_a_fraction_of_the_point_noise_grown_for_texture_beyond_the_view():
    """Markers half a point noise, chessboards 1.25, a texture half, dots none; only the
    texture's grows where a frame sees part of the target (no floor in pixels)."""
    from hbvs_cli.core.desired import DetectorErrors

    assert target_kind("aruco").errors.bias_fraction == 0.5 and not target_kind("aruco").errors.beyond_view
    assert target_kind("chessboard").errors.bias_fraction == 1.25
    assert target_kind("texture").errors.bias_fraction == 0.5 and target_kind("texture").errors.beyond_view
    assert target_kind("dots").errors.bias_fraction == 0.0
    assert DetectorErrors().bias_fraction == 0.0 and not DetectorErrors().beyond_view


def test_a_target_partly_out_of_view_counts_its_area_over_its_area_in_view():
    """A 100 px square wholly in a 640x480 image: 1; its left 40 px left of the image: 1/0.6;
    a trapezium (as perspective draws a poster) whose lower third hangs below the image: its
    whole area over the part above the bottom row; a frame where it was not found: 1."""
    from hbvs_cli.core.camera import DEFAULT_CAMERA
    from hbvs_cli.core.desired import area_beyond_view

    square = np.array([[100, 100], [200, 100], [200, 200], [100, 200]], float)
    trapezium = np.array([[300, 400], [400, 400], [380, 480 + 40], [320, 480 + 40]], float)
    frames = np.stack([square, square - [140, 0], trapezium, np.full((4, 2), np.nan)])
    scale = area_beyond_view(frames, DEFAULT_CAMERA)
    # The trapezium, 100 px wide at the top, 60 at the bottom, 120 high: (100 + 60) / 2 * 120 =
    # 9600 px^2; its top 80 px (100 -> 100 - 40 * 80 / 120 px wide): (100 + 73.33) / 2 * 80.
    assert scale == pytest.approx([1.0, 1.0 / 0.6, 9600.0 / 6933.333, 1.0], rel=1e-4)


def test_a_rolling_shutters_error_is_counted_once_not_as_noise():
    """Dots seen through a rolling shutter (rows read out over 33 ms: each point displaced by
    its image velocity times its row's delay, written here from the independent footage
    maker's geometry) plus 0.1 px of noise, 12 draws. The shutter biases theta_d (about
    0.3 deg on its own); its displacement, taken as point noise, made the interval 2.06x
    the error. Fitted as the shutter's readout and propagated as a bias: 95 % inside, sigma
    1.24x the error; with the readout estimated (-0.031 to -0.037 found: rows counted up), 96 %
    and 1.17x, theta_d 0.33 -> 0.29 deg RMS (the same scene without the shutter: 87 %, 0.73)."""
    import footage

    from hbvs_cli.core.camera import CameraIntrinsics
    from hbvs_cli.core.desired import fit_desired_trajectory

    drive = footage.Drive(duration=12.0, fps=5.0, speed=0.24, period=9.0)
    wall, camera, _ = footage.case("low_contrast_dots")
    intrinsics = CameraIntrinsics(fx=camera.fx, fy=camera.fy, cx=camera.cx, cy=camera.cy, width=camera.width, height=camera.height)
    times = drive.times()
    poses = drive.poses(times)
    ideal = footage.ideal_pixels(wall, camera, poses)
    shuttered = ideal + np.gradient(ideal, times, axis=0) * (0.033 * (ideal[..., 1] / camera.height - 0.5))[..., None]
    theta_true = poses[0, 2] - poses[:, 2]
    errors, sigmas = [], []
    for seed in range(12):
        pixels = shuttered + np.random.default_rng(seed).normal(0.0, 0.1, ideal.shape)
        fit = fit_desired_trajectory(times, pixels, 0, intrinsics, None, 0.3, 1.0, errors=target_kind("dots").errors)
        errors.append(fit.trajectory.evaluate(times).theta_d - theta_true)
        sigmas.append(fit.uncertainty.smooth_theta_sigma)
    errors, sigmas = np.array(errors), np.array(sigmas)
    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))  # noqa: E731
    assert np.mean(np.abs(errors) <= 1.96 * sigmas) >= 0.9
    assert 0.5 <= rms(sigmas) / rms(errors) <= 2.0


def _long_covariance(frames: int, seed: int = 7):
    """A recording's times, used frames, a covariance of theirs with biases of 2 spans and a
    rolling shutter's, the smoothed trajectory and its used span (random, not a fit)."""
    from hbvs_cli.core.bundle import JointCovariance
    from hbvs_cli.core.trajectory import fit_spline_trajectory

    rng = np.random.default_rng(seed)
    t = np.arange(frames) / 30.0
    used = rng.random(frames) > 0.02
    count, g = int(used.sum()), 6
    covariance = JointCovariance(shared=np.cov(rng.normal(size=(g, 50))) * 1e-6, own=np.abs(rng.normal(size=(count, 3, 3))) * 1e-6,
                                 sensitivity=rng.normal(size=(count, 3, g)), noise=1e-3,
                                 bias_shared=rng.normal(size=(g, 5)) * 1e-4, span_bias=rng.normal(size=(count, 3, 2)) * 1e-4,
                                 frame_spans=(np.arange(count) * 2 // count).astype(np.intp), readout_bias=rng.normal(size=(count, 3)) * 1e-4)
    trajectory = fit_spline_trajectory(t[used], 0.1 * np.sin(t[used] / 5), 0.2 * np.cos(t[used] / 7), 0.01 * t[used], 1.0)
    return t, used, covariance, trajectory, slice(int(np.flatnonzero(used)[0]), int(np.flatnonzero(used)[-1]) + 1)


@pytest.mark.parametrize("frames", [2500, 9001])
def test_the_splines_sigma_is_formed_a_block_at_a_time_with_the_same_numbers(frames, monkeypatch):
    """A long recording's probes are formed, averaged into the spline's samples and evaluated
    a block of frames at a time, and the splines formed a few columns at a time (the fit's
    peak memory stays flat; 30 000 frames had taken 90 MiB more than 3000, a board's
    biases 900 columns): the smoothed sigmas are those of the whole arrays at once (int8
    signs for the probes, drawn as the float ones were), but for the order of the sums."""
    from scipy.interpolate import make_smoothing_spline

    from hbvs_cli.core import desired

    t, used, covariance, trajectory, span = _long_covariance(frames)
    count = int(used.sum())
    monkeypatch.setattr(desired, "UNCERTAINTY_BLOCK", 1000)  # several blocks even for the shorter recording
    monkeypatch.setattr(desired, "SPLINE_COLUMNS", 16)  # and several splines
    blocked = desired._fit_uncertainty(covariance, t, used, span, trajectory, 500.0)

    # The same numbers from the whole arrays, as the fit formed them before.
    values, vectors = np.linalg.eigh(covariance.shared)
    keep = values > 1e-6 * max(float(values.max()), 1e-300)
    directions = vectors[:, keep] * np.sqrt(values[keep])
    probes = np.random.default_rng(0).choice([-1.0, 1.0], size=(count, desired.NOISE_PROBES))
    group = int(np.ceil(count / desired.MAX_SPLINE_SAMPLES))
    usable = count // group * group
    for index, channel, got in ((0, "theta_d", blocked.smooth_theta_sigma), (1, "x_hd1", blocked.smooth_x_h1_sigma)):
        inherited = np.column_stack([covariance.sensitivity[:, index, :] @ directions,
                                     covariance.bias_rows(slice(None))[:, index, :]])
        columns = np.column_stack([inherited, probes * np.sqrt(np.maximum(covariance.own[:, index, index], 0.0))[:, None]])
        binned_t, binned = t[used], columns
        if group > 1:
            binned_t = t[used][:usable].reshape(-1, group).mean(axis=1)
            binned = columns[:usable].reshape(-1, group, columns.shape[1]).mean(axis=1)
        at = make_smoothing_spline(binned_t, binned, lam=trajectory.channels[channel].smoothing)(t[span])
        whole = np.sqrt(np.sum(at[:, :inherited.shape[1]] ** 2, axis=1) + np.mean(at[:, inherited.shape[1]:] ** 2, axis=1))
        assert got.shape == whole.shape and np.allclose(got, whole, rtol=1e-12, atol=0.0)


def test_the_uncertainty_of_a_long_recording_takes_memory_by_the_block_not_by_the_frame():
    """The splines' sigma of 30 000 frames holds blocks, not frame-long columns: tracemalloc's
    peak grows by under 250 bytes a frame from 3000 frames (the same 3000 spline samples).
    Measured: 154 (the probes' int8 signs, each frame's sigmas and its outputs); it had
    been about 750."""
    import tracemalloc

    from hbvs_cli.core import desired

    peaks = {}
    for frames in (3000, 30000):
        t, used, covariance, trajectory, span = _long_covariance(frames)
        tracemalloc.start()
        try:
            desired._fit_uncertainty(covariance, t, used, span, trajectory, 500.0)
            peaks[frames] = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
    assert (peaks[30000] - peaks[3000]) / 27000 < 250


def test_a_pull_every_point_shares_is_counted_as_a_shift_of_the_image():
    """Three LEDs on the bloom style's drive (tests/footage.py ``leds_bloom``), their ideal
    pixels all pulled 0.12 px down the columns (bloom's pull measured on that footage: 0.11-0.13
    px, every dot alike) plus 0.02 px of noise, 6 draws. n* absorbs the pull (theta_d 0.29 deg
    RMS, the footage's 0.26-0.30), the residuals cannot show it: without the image shift's
    term 77 % of frames inside the 95 % interval, sigma 0.60x the error (12 draws); with
    ``image_shift_px`` 0.12, 100 % and 1.21x."""
    import footage

    from hbvs_cli.core.camera import CameraIntrinsics
    from hbvs_cli.core.desired import fit_desired_trajectory

    drive = footage.STYLE_DRIVES["leds_bloom"]
    wall, camera, _, _ = footage.style_case("leds_bloom")
    intrinsics = CameraIntrinsics(fx=camera.fx, fy=camera.fy, cx=camera.cx, cy=camera.cy, width=camera.width, height=camera.height)
    times = drive.times()
    poses = drive.poses(times)
    pulled = footage.ideal_pixels(wall, camera, poses) + [0.0, 0.12]
    theta_true = poses[0, 2] - poses[:, 2]
    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))  # noqa: E731
    figures = {}
    for shift_px in (0.0, 0.12):
        errors, sigmas = [], []
        for seed in range(6):
            pixels = pulled + np.random.default_rng(seed).normal(0.0, 0.02, pulled.shape)
            fit = fit_desired_trajectory(times, pixels, 0, intrinsics, None, 0.3, 1.0, errors=target_kind("dots").errors, image_shift_px=shift_px)
            errors.append(fit.trajectory.evaluate(times).theta_d - theta_true)
            sigmas.append(fit.uncertainty.smooth_theta_sigma)
        errors, sigmas = np.array(errors), np.array(sigmas)
        figures[shift_px] = (float(np.mean(np.abs(errors) <= 1.96 * sigmas)), rms(sigmas) / rms(errors))
    assert figures[0.0][0] < 0.9 and figures[0.0][1] < 0.7, figures  # optimistic without it
    assert figures[0.12][0] >= 0.95 and 0.8 <= figures[0.12][1] <= 2.0, figures


def test_a_calibration_not_counted_leaves_the_band_to_the_pixels_and_reports_its_part():
    """The bloom drive's three LEDs with 0.02 px of noise and bloom's 0.12 px pull counted:
    with 1 px on each of fx, fy, cx and cy not counted (a calibration that states none) every
    sigma is the one the exact intrinsics give, to rounding, while n*'s part from the
    intrinsics is the one they add when counted, in quadrature (issue 46: the image shift's
    columns stay, the calibration's go)."""
    import footage

    from hbvs_cli.core.camera import CameraIntrinsics
    from hbvs_cli.core.desired import fit_desired_trajectory

    drive = footage.STYLE_DRIVES["leds_bloom"]
    wall, camera, _, _ = footage.style_case("leds_bloom")
    intrinsics = CameraIntrinsics(fx=camera.fx, fy=camera.fy, cx=camera.cx, cy=camera.cy, width=camera.width, height=camera.height)
    times = drive.times()
    ideal = footage.ideal_pixels(wall, camera, drive.poses(times))
    pixels = ideal + np.random.default_rng(0).normal(0.0, 0.02, ideal.shape)

    def uncertainty(sigma=(), counted=True):
        return fit_desired_trajectory(times, pixels, 0, intrinsics, None, 0.3, 1.0, errors=target_kind("dots").errors,
                                      image_shift_px=0.12, calibration_sigma=sigma, calibration_counted=counted).uncertainty

    exact, counted, uncounted = uncertainty(), uncertainty((1.0,) * 4), uncertainty((1.0,) * 4, counted=False)
    assert uncounted.normal_sigma_deg == pytest.approx(exact.normal_sigma_deg, rel=1e-9)
    np.testing.assert_allclose(uncounted.smooth_theta_sigma, exact.smooth_theta_sigma, rtol=1e-9)
    np.testing.assert_allclose(uncounted.x_h1_sigma, exact.x_h1_sigma, rtol=1e-9, equal_nan=True)
    assert uncounted.calibration_normal_sigma_deg == counted.calibration_normal_sigma_deg > 2 * exact.normal_sigma_deg
    assert counted.normal_sigma_deg ** 2 == pytest.approx(exact.normal_sigma_deg ** 2 + counted.calibration_normal_sigma_deg ** 2, rel=1e-9)
    assert np.all(counted.smooth_theta_sigma > exact.smooth_theta_sigma)
