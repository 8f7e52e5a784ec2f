"""The closed loop with rendered images under the harshest image noise the detector follows
(issue 17).

The issue asks for rendered images whose blur and sensor noise put the detector's error at
1 px. With the default target (three 5 cm dots, 4 m away, 640x480) image noise cannot get
there: the dot detector keeps its points to about 0.2 px until the noise or the blur is so
strong that it loses the dots. ``test_image_noise_cannot_reach_one_pixel`` (a campaign)
measures that over white and correlated sensor noise, blur and JPEG compression. The
other tests run the loop at the harshest image noise it follows: 15 gray levels of sensor
noise correlated over 2 px (as a camera's demosaicing and denoising leave it), blur 1 px;
and the same with 1 px of noise added to the detector's points (``--pixel-noise 1`` with
images), which brings the measured points to 1.0 px.

Measured on this machine: detector error 0.19 px RMS per axis against the projected truth
(the default images: 0.012 px; the loop's windowed detector: 0.17 px), the fit's residual
0.13 px. The harsh teach's fit itself is off the true path at the end of the drive (its
x_hd1_dot 2.3 % over the last second, theta_d 0.27 deg): with exact points the robot ends
0.29 cm / 0.12 deg off the truth there, against 0.03 cm on the default teach's fit. So the
images loop is measured twice (seeds 0-9, mean final error, worst in brackets;
``pytest -s -n 0 -m campaign``):

- on the harsh teach's fit: 0.30 cm / 0.11 deg (0.36 / 0.16); with the added 1 px
  0.48 cm / 0.20 deg (1.26 / 0.62). At that fit's floor: it cannot be judged below it.
- on the default teach's fit (the taught path right), the images rendered with the same
  harsh sensor: 0.06 cm / 0.022 deg (0.13 / 0.05); with 1 px seeds 0-29 are judged, as ten
  seeds' mean is a draw from a wide spread: seeds 0-89 end 0.49 +- 0.035 cm / 0.179 +- 0.015
  deg (mean +- its standard error), the same as the code this test was written on (0.52 +-
  0.038 cm / 0.179 +- 0.016 deg), whose ten-seed means range 0.12-0.22 deg.

Before the windowed loop and the depth in the filter the harsh fit gave 0.19 cm / 0.13 deg,
below its own floor: (31) alone ended 2.5 % above d* on average (up to 4.5 %), and a dhat
3 % high cancels that fit's lag along the path. On the default teach's fit the same code
ends 0.19 cm / 0.034 deg (seeds 0-31: 0.22 cm against 0.087 cm now; docs/results.md).
"""

from __future__ import annotations

import numpy as np
import pytest

from conftest import make_fit, make_teach
from test_control_filter import closed_loop

#: The harshest image noise the loop follows: sensor noise (gray levels), its grain (px), blur (px).
HARSH = {"noise": 15.0, "noise_grain": 2.0, "blur": 1.0}
#: The same sensor as a fit records it, for ``closed_loop(..., sensor=)``.
HARSH_SENSOR = {**HARSH, "exposure": 1.0}


def detection_errors(noise: float, grain: float, blur: float, jpeg_quality: int = 100, frames: int = 120, windowed: bool = False):
    """Per-axis detection errors (px) of the tracked dot detector against the projected truth,
    on rendered frames of the taught s-curve, and the fraction of frames where it lost the dots.
    ``windowed``: each dot followed in its own window, only the windows rendered, as the
    images loop of ``repeat --sim`` does (JPEG not applied)."""
    import cv2
    from scipy.optimize import linear_sum_assignment

    from hbvs_cli.core.path import preset_profile
    from hbvs_cli.perception.dot_windows import WindowedDotDetector
    from hbvs_cli.sim.world import default_world
    from hbvs_cli.perception.dots import DotDetector
    from hbvs_cli.sim.render import make_renderer

    world = default_world()
    profile, start = preset_profile("s-curve", 30)
    renderer = make_renderer(world, noise, blur, 1.0, grain)
    rng = np.random.default_rng(7)
    detector = (WindowedDotDetector if windowed else DotDetector)(len(world.target.points_world))
    errors, lost = [], 0
    for t in np.linspace(0.0, 19.9, frames):
        pose = profile.poses_at(t, start)
        windows = detector.search_windows((world.camera.height, world.camera.width)) if windowed else None
        found = None
        if windows is not None:
            found = detector.detect_in_windows(renderer.render_windows(pose, rng, windows), windows)
        if found is None:
            image = renderer.render(pose, rng)
            if jpeg_quality < 100:
                image = cv2.imdecode(cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])[1], cv2.IMREAD_GRAYSCALE)
            found = detector.detect(image)
        if not found.found:
            lost += 1
            continue
        truth = world.pixels(pose)
        rows, columns = linear_sum_assignment(np.linalg.norm(found.pixels[:, None] - truth[None], axis=2))
        errors.append(found.pixels[rows] - truth[columns])
    return np.concatenate(errors) if errors else np.empty((0, 2)), lost / frames


@pytest.fixture(scope="module")
def harsh_fit(tmp_path_factory):
    folder = tmp_path_factory.mktemp("image-noise")
    teach = make_teach(folder / "teach.mcap", **HARSH)
    make_fit(teach, folder / "fit.mcap")
    return folder / "fit.mcap"


def test_the_harsh_setting_raises_the_detectors_error_tenfold():
    default, _ = detection_errors(2.0, 0.0, 0.0, frames=40)
    harsh, lost = detection_errors(HARSH["noise"], HARSH["noise_grain"], HARSH["blur"], frames=40)
    default_rms, harsh_rms = float(np.sqrt(np.mean(default**2))), float(np.sqrt(np.mean(harsh**2)))
    assert default_rms < 0.03 and lost == 0
    assert 0.12 < harsh_rms < 0.3 and harsh_rms > 8 * default_rms, (default_rms, harsh_rms)


def test_dots_followed_in_their_windows_are_measured_as_well_as_in_whole_frames():
    """The images loop's detector (each dot in its own window, only those rendered) against
    the fit's (the dots' common box in whole frames) under the harsh noise (measured on 300
    frames: 0.172 against 0.193 px RMS per axis; the 30-frame averages that the filter
    passes on: 0.033 against 0.036 px in the closed loop)."""
    whole, _ = detection_errors(HARSH["noise"], HARSH["noise_grain"], HARSH["blur"], frames=60)
    windowed, lost = detection_errors(HARSH["noise"], HARSH["noise_grain"], HARSH["blur"], frames=60, windowed=True)
    whole_rms, windowed_rms = float(np.sqrt(np.mean(whole**2))), float(np.sqrt(np.mean(windowed**2)))
    assert lost == 0 and windowed_rms <= whole_rms, (windowed_rms, whole_rms)


def test_the_fit_measures_the_raised_noise(harsh_fit):
    from hbvs_cli.io.fit_file import read_fit_file

    model = read_fit_file(str(harsh_fit)).model
    assert model.render.noise_grain == HARSH["noise_grain"]  # repeat renders the same sensor
    assert 0.08 < model.residual_px.rms < 0.3, model.residual_px


def test_the_harsh_teachs_fit_sets_the_floor(harsh_fit, default_fit):
    """With exact points (no noise in the loop) the robot ends where the fit of the harsh
    teach puts the taught path, 0.29 cm / 0.12 deg off the truth (the default teach's fit:
    0.03 cm / 0.004 deg); the images loop on that fit cannot be judged below it."""
    harsh = closed_loop(harsh_fit, perception="points")
    default = closed_loop(default_fit[0], perception="points")
    assert 0.2 < harsh["position_cm"] < 0.4 and 0.08 < harsh["heading_deg"] < 0.2, (harsh["position_cm"], harsh["heading_deg"])
    assert default["position_cm"] < 0.06 and default["heading_deg"] < 0.02, (default["position_cm"], default["heading_deg"])


def test_rendered_images_under_harsh_noise_converge(harsh_fit):
    run = closed_loop(harsh_fit, perception="images", seed=0)
    steps = len(run["records"])
    assert run["position_cm"] < 1.0 and run["heading_deg"] < 0.2, (run["position_cm"], run["heading_deg"])
    assert run["lost"] <= 0.01 * steps
    assert run["smoothness"]["dv_dt_rms_mps2"] < 0.5


def test_rendered_images_with_one_pixel_at_the_detector_converge(harsh_fit):
    """The issue's 1 px bounds: < 2 cm and < 0.4 deg (seed 1; all ten with -m campaign)."""
    run = closed_loop(harsh_fit, perception="images", seed=1, pixel_noise=1.0)
    assert run["position_cm"] < 2.0 and run["heading_deg"] < 0.4, (run["position_cm"], run["heading_deg"])
    assert run["lost"] <= 0.01 * len(run["records"])


def skip_unless_campaign(request):
    if "campaign" not in (request.config.option.markexpr or ""):
        pytest.skip("runs with: pytest -m campaign tests/test_control_image_noise.py")


def final_errors_over_seeds(fit_path, what: str, seeds: range = range(10), **options):
    """Final position (cm) and heading (deg) errors of ``seeds`` (0-9) with images, printed."""
    runs = [closed_loop(fit_path, perception="images", seed=seed, **options) for seed in seeds]
    position = [run["position_cm"] for run in runs]
    heading = [run["heading_deg"] for run in runs]
    print(f"\n{what}, seeds {seeds.start}-{seeds.stop - 1}: position mean {np.mean(position):.3f} max {max(position):.3f} cm, "
          f"heading mean {np.mean(heading):.3f} max {max(heading):.3f} deg, lost {[run['lost'] for run in runs]}, "
          f"RMS dv/dt {[round(run['smoothness']['dv_dt_rms_mps2'], 3) for run in runs]}")
    return np.array(position), np.array(heading)


@pytest.mark.campaign
def test_rendered_images_under_harsh_noise_ten_seeds(harsh_fit, request):
    """About 40 s."""
    skip_unless_campaign(request)
    position, heading = final_errors_over_seeds(harsh_fit, "images, harsh noise")
    assert position.mean() < 1.0 and heading.mean() < 0.2, (position, heading)
    assert position.max() < 2.0 and heading.max() < 0.4


@pytest.mark.campaign
def test_rendered_images_with_one_pixel_at_the_detector_ten_seeds(harsh_fit, request):
    """About 40 s: the issue's 1 px case with images, mean < 2 cm and < 0.4 deg."""
    skip_unless_campaign(request)
    position, heading = final_errors_over_seeds(harsh_fit, "images + 1 px at the detector", pixel_noise=1.0)
    assert position.mean() < 2.0 and heading.mean() < 0.4, (position, heading)


@pytest.mark.campaign
def test_harsh_images_along_a_right_taught_path_ten_seeds(default_fit, request):
    """About 40 s: the default teach's fit (the taught path right to 0.03 cm), the images
    rendered with the harsh sensor: what the loop itself makes of the image noise, below the
    0.19 cm the harsh fit gave before the depth in the filter. With 1 px more, seeds 0-29
    against their population's mean plus about three standard errors (module docstring)."""
    skip_unless_campaign(request)
    position, heading = final_errors_over_seeds(default_fit[0], "harsh images, the default teach's fit", sensor=HARSH_SENSOR)
    assert position.mean() < 0.15 and heading.mean() < 0.06, (position, heading)
    position, heading = final_errors_over_seeds(default_fit[0], "the same + 1 px at the detector", seeds=range(30),
                                                sensor=HARSH_SENSOR, pixel_noise=1.0)
    assert position.mean() < 0.7 and heading.mean() < 0.27, (position, heading)


#: Image noise raised every way hbvs's renderer can (gray levels, grain px, blur px, JPEG quality).
DEGRADATIONS = [(30, 0, 0, 100), (40, 0, 0, 100), (15, 2, 1, 100), (20, 2, 1, 100), (10, 4, 1, 100),
                (2, 0, 3, 5), (30, 0, 2, 5), (10, 2, 1, 10)]


@pytest.mark.campaign
def test_image_noise_cannot_reach_one_pixel(request):
    """Wherever the detector still follows the dots (lost in under 10 % of frames), its error
    stays far below 1 px: the 1 px level of issue 17 is out of image noise's reach."""
    skip_unless_campaign(request)
    followed = []
    for noise, grain, blur, quality in DEGRADATIONS:
        errors, lost = detection_errors(noise, grain, blur, quality)
        rms = float(np.sqrt(np.mean(errors**2))) if len(errors) else float("nan")
        print(f"\nnoise {noise} grain {grain} blur {blur} jpeg {quality}: lost {lost:.0%}, error {rms:.3f} px RMS per axis")
        if lost < 0.1:
            followed.append(rms)
            assert rms < 0.35, (noise, grain, blur, quality, rms)
    assert len(followed) >= 4
