"""Poster rasters and rendered frames: pixel conventions, photometry, determinism (speed is bench figure 6a)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from hbvs_cli.core.camera import CameraIntrinsics, distort_pixels
from hbvs_cli.core.path import preset_profile
from hbvs_cli.sim.world import default_world
from hbvs_cli.errors import InputError, UsageError
from hbvs_cli.perception import DotDetector
from hbvs_cli.sim import PosterRaster, RenderSettings, SceneRenderer
from hbvs_cli.sim.poster import INK_BLACK, PAPER_WHITE, build_pyramid

POSE = np.array([1.0, 0.05, 0.08])


@pytest.fixture(scope="module")
def dots_world():
    return default_world("dots")


@pytest.fixture(scope="module")
def dots_raster(dots_world):
    return PosterRaster.from_target(dots_world.target)


def path_poses(count: int) -> np.ndarray:
    profile, start = preset_profile("s-curve", 30)
    return profile.poses_at(np.linspace(0.0, profile.duration, count), start)


def ink_centroid(image: np.ndarray, centre: np.ndarray, radius: float) -> np.ndarray:
    """Darkness-weighted centroid of the ink within radius + 2 px of ``centre`` (px)."""
    reach = int(np.ceil(radius + 3))
    x0, y0 = int(round(centre[0])) - reach, int(round(centre[1])) - reach
    window = image[y0 : y0 + 2 * reach + 1, x0 : x0 + 2 * reach + 1].astype(float)
    ys, xs = np.mgrid[y0 : y0 + 2 * reach + 1, x0 : x0 + 2 * reach + 1]
    inside = np.hypot(xs - centre[0], ys - centre[1]) <= radius + 2
    weights = np.clip(PAPER_WHITE - window, 0, None) * inside
    return np.array([(weights * xs).sum(), (weights * ys).sum()]) / weights.sum()


# -- poster raster ----------------------------------------------------------------------
def test_pyramid_keeps_the_documented_pixel_centres():
    # A linear ramp is reproduced exactly by the symmetric [1 3 3 1]/8 filter, so each level's
    # values reveal where its pixel centres are: level l pixel i at 2^l i + (2^l - 1) / 2.
    ramp = np.tile((2 * np.arange(128)).astype(np.uint8), (64, 1))
    levels = build_pyramid(ramp, min_size=8)
    for level in range(1, 4):
        i = np.arange(2, levels[level].shape[1] - 2)
        centre = 2**level * i + (2**level - 1) / 2
        row = levels[level].shape[0] // 2
        np.testing.assert_array_equal(levels[level][row, i], 2 * centre)


def test_dot_raster_centres_are_exact_on_every_level(dots_world, dots_raster):
    # Ink centroid at each pyramid level vs. the metre -> level map; measured < 0.002 px.
    pad = 10
    for level in range(2, 6):
        to_level = np.linalg.inv(dots_raster.level_to_poster(level))
        radius = dots_world.target.dot_radius * dots_raster.ppm / 2**level
        picture = np.pad(dots_raster.levels[level], pad, constant_values=PAPER_WHITE)
        for a, b in dots_world.target.points_poster:
            expected = (to_level @ [a, b, 1.0])[:2]
            measured = ink_centroid(picture, expected + pad, radius) - pad
            assert np.all(np.abs(measured - expected) < 0.01), (level, measured - expected)


def test_aruco_raster_puts_marker_corners_on_the_target_points():
    world = default_world("aruco")
    raster = PosterRaster.from_target(world.target)
    image = raster.image
    for a, b in world.target.points_poster:
        # Corner (a, b) is a pixel edge: columns/rows a*ppm - 1 and a*ppm straddle it.
        x, y = int(round(a * raster.ppm)), int(round(b * raster.ppm))
        sx = 1 if x < image.shape[1] / 2 else -1
        sy = 1 if y < image.shape[0] / 2 else -1
        inside = image[y if sy > 0 else y - 1, x if sx > 0 else x - 1]
        outside = image[y - 1 if sy > 0 else y, x - 1 if sx > 0 else x]
        assert inside == INK_BLACK and outside == PAPER_WHITE


def test_texture_raster_from_image_and_builtin():
    world = default_world("texture")
    builtin = PosterRaster.from_target(world.target)
    poster = world.target.poster
    assert builtin.image.shape == (round(poster.height * builtin.ppm), round(poster.width * builtin.ppm))
    assert builtin.image.std() > 40
    np.testing.assert_array_equal(builtin.image, PosterRaster.from_target(world.target).image)
    colour = np.random.default_rng(3).integers(0, 256, (90, 120, 3), dtype=np.uint8)
    given = PosterRaster.from_target(world.target, texture=colour)
    assert given.image.shape == builtin.image.shape and given.image.dtype == np.uint8
    with pytest.raises(InputError):
        PosterRaster.from_target(world.target, texture=np.zeros((0, 0), np.uint8))
    with pytest.raises(InputError):
        PosterRaster.from_target(world.target, texture=np.zeros((50, 50), np.float32))


def test_level_choice_matches_scale(dots_raster):
    assert dots_raster.level_for_scale(dots_raster.ppm) == 0
    assert dots_raster.level_for_scale(dots_raster.ppm / 8) == 3
    assert dots_raster.level_for_scale(dots_raster.ppm / 8 * 1.3) == 3
    assert dots_raster.level_for_scale(1e-6) == len(dots_raster.levels) - 1


# -- rendering --------------------------------------------------------------------------
def test_render_is_deterministic_per_seed(dots_world, dots_raster):
    renderer = SceneRenderer(dots_world, dots_raster)
    first = renderer.render(POSE, np.random.default_rng(11))
    again = renderer.render(POSE, np.random.default_rng(11))
    other = renderer.render(POSE, np.random.default_rng(12))
    assert first.dtype == np.uint8 and first.shape == (480, 640)
    assert first.tobytes() == again.tobytes()
    assert first.tobytes() != other.tobytes()


def test_noise_has_the_requested_level(dots_world, dots_raster):
    renderer = SceneRenderer(dots_world, dots_raster, RenderSettings(noise_std=3.0, background=100))
    image = renderer.render(POSE, np.random.default_rng(5)).astype(float)
    wall = image[300:, :]  # below the poster: plain wall
    assert abs(wall.mean() - 100) < 0.05
    assert abs(wall.std() - 3.0) < 0.05  # rounding to integers adds 1/12 gray level^2


def test_exposure_gain_and_offset_scale_intensities(dots_world, dots_raster):
    renderer = SceneRenderer(dots_world, dots_raster, RenderSettings(noise_std=0.0))
    rng = np.random.default_rng(0)
    nominal = renderer.render(POSE, rng).astype(float)
    half = renderer.render(POSE, rng, exposure_gain=0.5).astype(float)
    assert abs(half.mean() - 0.5 * nominal.mean()) < 0.3
    brighter = SceneRenderer(dots_world, dots_raster, RenderSettings(noise_std=0.0, exposure_offset=20.0))
    assert abs(brighter.render(POSE, rng).astype(float).mean() - nominal.mean() - 20.0) < 0.3
    with pytest.raises(UsageError):
        renderer.render(POSE, rng, exposure_gain=-1.0)


def test_blur_softens_but_keeps_the_ink(dots_world, dots_raster):
    sharp = SceneRenderer(dots_world, dots_raster, RenderSettings(noise_std=0.0))
    soft = SceneRenderer(dots_world, dots_raster, RenderSettings(noise_std=0.0, blur_sigma=4.0))
    rng = np.random.default_rng(0)
    a, b = sharp.render(POSE, rng).astype(float), soft.render(POSE, rng).astype(float)
    u, v = np.round(dots_world.pixels(POSE)[0]).astype(int)
    # Wide enough (dot radius + 4 sigma) that the blurred light stays inside the window.
    window = (slice(v - 28, v + 29), slice(u - 28, u + 29))
    assert b[window].min() > a[window].min()  # the dot's core is no longer pure ink
    assert abs(b[window].sum() - a[window].sum()) < 0.002 * a[window].sum()  # light is conserved
    gradient = lambda img: np.abs(np.diff(img[window], axis=1)).max()  # noqa: E731
    assert gradient(b) < 0.5 * gradient(a)


def test_rendered_target_lies_at_world_pixels():
    rng = np.random.default_rng(0)
    for kind in ("dots", "aruco"):
        world = default_world(kind)
        renderer = SceneRenderer(world, settings=RenderSettings(noise_std=0.0))
        for pose in path_poses(5):
            image = renderer.render(pose, rng)
            pixels = world.pixels(pose)
            centre = pixels.mean(axis=0)
            for u, v in pixels:
                if kind == "dots":
                    assert image[int(round(v)), int(round(u))] < 60
                else:
                    # 2 px inside the corner is darker than mid-grey (ink, 20), 2 px
                    # outside brighter (paper, 230): the corner is where World.pixels says.
                    inward = (centre - (u, v)) / np.linalg.norm(centre - (u, v))
                    iu, iv = np.round((u, v) + 2.0 * np.sqrt(2) * inward).astype(int)
                    ou, ov = np.round((u, v) - 2.0 * np.sqrt(2) * inward).astype(int)
                    assert image[iv, iu] < 125 < image[ov, ou]


def test_rendered_dot_centroids_are_unbiased(dots_world, dots_raster):
    # Ink centroids vs World.pixels over the default path. Measured: |mean| 0.006 px,
    # std 0.02 px; part of it is real perspective (a disc's image centroid is not the image
    # of its centre: up to 0.036 px here).
    renderer = SceneRenderer(dots_world, dots_raster, RenderSettings(noise_std=0.0))
    rng = np.random.default_rng(0)
    errors = []
    for pose in path_poses(21):
        image = renderer.render(pose, rng)
        homography = dots_world.poster_to_image_homography(pose)
        for (a, b), expected in zip(dots_world.target.points_poster, dots_world.pixels(pose)):
            radius = dots_world.target.dot_radius * homography[0, 0] / (homography @ [a, b, 1.0])[2]
            errors.append(ink_centroid(image, expected, radius) - expected)
    errors = np.array(errors)
    assert np.all(np.abs(errors.mean(axis=0)) < 0.015)
    assert np.all(errors.std(axis=0) < 0.03)


def test_lens_distortion_moves_the_target_where_distort_pixels_says(dots_world):
    camera = CameraIntrinsics(
        fx=500.0, fy=500.0, cx=319.5, cy=239.5, width=640, height=480,
        distortion_model="plumb_bob", distortion=(-0.3, 0.1, 0.001, -0.001, 0.0),
    )
    world = replace(dots_world, camera=camera)
    renderer = SceneRenderer(world, settings=RenderSettings(noise_std=0.0))
    moved = []
    for pose in ([0.0, -0.1, 0.0], [0.8, 0.3, 0.25], [1.8, 0.0, -0.1]):
        expected = distort_pixels(camera, world.pixels(pose))
        detection = DotDetector(3).detect(renderer.render(pose, np.random.default_rng(0)), expected)
        assert detection.found
        # Measured <= 0.06 px (a distorted disc's centroid is not quite the distorted centre).
        assert np.abs(detection.pixels - expected).max() < 0.1
        moved.append(np.abs(world.pixels(pose) - expected).max())
    assert max(moved) > 5.0  # the lens matters: pinhole positions are off by several px


def test_poster_behind_the_camera(dots_world, dots_raster):
    renderer = SceneRenderer(dots_world, dots_raster, RenderSettings(noise_std=0.0))
    away = renderer.render([0.0, 0.0, np.pi], np.random.default_rng(0))
    assert np.all(away == 150)
    # Next to the wall, looking along it: part of the poster is behind the camera plane.
    grazing = renderer.render([dots_world.wall_x - 0.05, 0.0, np.pi / 2], np.random.default_rng(0))
    assert grazing.shape == (480, 640) and grazing.max() == PAPER_WHITE


# -- rendering only the windows a tracked detector reads (issue 28) ------------------------
def windows_around(pixels: np.ndarray, half: int) -> list[tuple[int, int, int, int]]:
    return [(int(u) - half, int(v) - half, int(u) + half + 1, int(v) + half + 1) for u, v in pixels]


@pytest.mark.parametrize("blur, lens", [(0.0, False), (1.3, False), (0.0, True)])
def test_windows_render_the_whole_frames_scene(dots_world, blur, lens):
    # Without noise, every window equals that window of the whole frame: the same scene,
    # blur and lens (measured: at most 1 gray level on a few pixels, the sampling's rounding).
    world = dots_world
    if lens:
        camera = CameraIntrinsics(fx=500.0, fy=500.0, cx=319.5, cy=239.5, width=640, height=480,
                                  distortion_model="plumb_bob", distortion=(-0.3, 0.1, 0.001, -0.001, 0.0))
        world = replace(dots_world, camera=camera)
    renderer = SceneRenderer(world, settings=RenderSettings(noise_std=0.0, blur_sigma=blur, exposure_gain=0.9, exposure_offset=4.0))
    differing = 0
    for pose in [*path_poses(6), np.array([0.0, 0.0, np.pi]), np.array([world.wall_x - 0.05, 0.0, np.pi / 2])]:
        whole = renderer.render(pose, np.random.default_rng(0)).astype(int)
        pixels = world.pixels(pose)
        windows = [(-10, -10, 40, 30), (600, 450, 700, 520), (300, 200, 340, 260)]
        if np.all(np.isfinite(pixels)) and np.all(np.abs(pixels) < 1e4):
            windows += windows_around(pixels, 30)
        windowed = renderer.render_windows(pose, np.random.default_rng(0), windows).astype(int)
        for x0, y0, x1, y1 in windows:
            x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, 640), min(y1, 480)
            if x0 >= x1 or y0 >= y1:
                continue
            difference = np.abs(whole[y0:y1, x0:x1] - windowed[y0:y1, x0:x1])
            assert difference.max() <= 1
            differing += int(np.count_nonzero(difference))
    assert differing < 50


def test_windows_carry_the_sensors_noise(dots_world):
    # White and correlated noise: the same level, and the grain's correlation, as whole frames.
    for grain in (0.0, 2.0):
        renderer = SceneRenderer(dots_world, settings=RenderSettings(noise_std=6.0, noise_grain=grain, background=100))
        rng = np.random.default_rng(3)
        windows = [(0, 300, 120, 420), (500, 380, 640, 480)]  # plain wall, one at the image's corner
        whole = renderer.render(POSE, rng).astype(float)[300:420, 0:120]
        windowed = renderer.render_windows(POSE, rng, windows).astype(float)
        for window in (windowed[300:420, 0:120], windowed[380:480, 500:640]):
            assert abs(window.mean() - 100) < 0.6
            assert abs(window.std() - whole.std()) < 0.4
            lag = lambda x: float(np.mean((x[:, 2:] - x.mean()) * (x[:, :-2] - x.mean())) / x.var())  # noqa: E731
            assert abs(lag(window) - lag(whole)) < 0.08


def test_windowed_tracking_finds_what_the_common_box_finds(dots_world):
    # Each dot in its own window: the same dots as the detector searching their common box,
    # to within the thresholds' difference (measured: 0.0025 px RMS), reading 2 % of the
    # frame; frames rendered only there are measured as well (0.0087 px RMS against the
    # truth; the whole frames in the common box: 0.0088 px).
    from hbvs_cli.perception.dot_windows import WindowedDotDetector

    renderer = SceneRenderer(dots_world)
    profile, start = preset_profile("s-curve", 30)
    poses = profile.poses_at(8.0 + np.arange(40) / 30.0, start)
    rng = np.random.default_rng(1)
    images = [renderer.render(pose, rng) for pose in poses]
    common, windowed, partial = DotDetector(3), WindowedDotDetector(3), WindowedDotDetector(3)
    for detector in (common, windowed, partial):
        detector.detect(images[0], dots_world.pixels(poses[0]))
    gaps, errors, read = [], [], []
    for pose, image in zip(poses[1:], images[1:]):
        windows = windowed.search_windows(image.shape)
        assert windows is not None and len(windows) == 3
        read.append(sum((x1 - x0) * (y1 - y0) for x0, y0, x1, y1 in windows) / image.size)
        found = windowed.detect_in_windows(image, windows)
        reference = common.detect(image)
        assert found is not None and reference.found
        gaps.append(found.pixels - reference.pixels)
        windows = partial.search_windows(image.shape)
        seen = partial.detect_in_windows(renderer.render_windows(pose, rng, windows), windows)
        assert seen is not None
        errors.append(seen.pixels - dots_world.pixels(pose))
    assert np.sqrt(np.mean(np.square(gaps))) < 0.02
    assert np.sqrt(np.mean(np.square(errors))) < 0.02
    assert max(read) < 0.04


@pytest.mark.parametrize("noisy", [(), (0,), (0, 1, 2)])
def test_windows_skip_the_noise_median_only_where_it_cannot_change_the_blobs(dots_world, monkeypatch, noisy):
    """find_blobs_in_windows takes a window's noise median only when some window's noise may
    exceed NOISY_GROUND (its mean then decides the smoothing): quiet windows, one noisy among
    quiet ones, and all noisy find the same blobs, to the bit, as with every window's median."""
    from hbvs_cli.perception import dot_windows
    from hbvs_cli.perception.dot_windows import WindowMosaic, find_blobs_in_windows

    pose = np.array([0.5, 0.0, 0.0])
    pixels = dots_world.pixels(pose)
    windows = [(int(u) - 22, int(v) - 22, int(u) + 23, int(v) + 23) for u, v in pixels]
    image = SceneRenderer(dots_world, settings=RenderSettings(noise_std=1.0)).render(pose, np.random.default_rng(4)).astype(float)
    rng = np.random.default_rng(5)
    for k in noisy:  # the sensor's noise well above NOISY_GROUND in these windows
        x0, y0, x1, y1 = windows[k]
        image[y0:y1, x0:x1] += rng.normal(0.0, 9.0, (y1 - y0, x1 - x0))
    gray = np.clip(image, 0, 255).astype(np.uint8)
    medians = []
    own = dot_windows.ground_noise
    monkeypatch.setattr(dot_windows, "ground_noise", lambda view, floor=0.0: medians.append(floor) or own(view, floor))
    found = find_blobs_in_windows(gray, windows, WindowMosaic())
    monkeypatch.setattr(dot_windows, "ground_noise", lambda view, floor=0.0: own(view))
    every = find_blobs_in_windows(gray, windows, WindowMosaic())
    for name in ("centres", "areas", "round", "touches_edge"):
        assert np.array_equal(getattr(found, name), getattr(every, name), equal_nan=name == "centres"), name
    assert np.count_nonzero(found.round) == 3  # the three dots (the other blobs reach their window's edge)
    # Quiet windows: three counts, no median; else the quiet ones' medians are taken too.
    assert medians == [dot_windows.NOISY_GROUND] * 3 + ([0.0] * (3 - len(noisy)) if noisy else [])


def test_a_windowed_detector_searches_the_whole_frame_when_a_dot_left_its_window(dots_world):
    from hbvs_cli.perception.dot_windows import WindowedDotDetector

    renderer = SceneRenderer(dots_world)
    rng = np.random.default_rng(2)
    detector = WindowedDotDetector(3)
    first, jumped = np.array([0.5, 0.0, 0.0]), np.array([0.5, 0.15, 0.05])
    detector.detect(renderer.render(first, rng), dots_world.pixels(first))
    image = renderer.render(jumped, rng)
    windows = detector.search_windows(image.shape)
    assert detector.detect_in_windows(image, windows) is None  # nothing updated ...
    assert detector.search_windows(image.shape) == windows
    found = detector.detect(image)  # ... and the whole frame brings the dots back
    assert found.found and np.abs(found.pixels - dots_world.pixels(jumped)).max() < 0.1


def test_settings_are_validated(dots_world):
    with pytest.raises(UsageError):
        RenderSettings(noise_std=-1.0)
    with pytest.raises(UsageError):
        RenderSettings(background=300.0)
    with pytest.raises(UsageError):
        SceneRenderer(dots_world, PosterRaster.from_target(default_world("aruco").target))
