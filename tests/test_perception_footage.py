"""Perception on footage hbvs did not render (issue 12): the table of the issue, row by row.

Each video comes from ``tests/footage.py`` (its own warp, distortion, blur, noise,
vignetting, exposure drift and MJPG compression; no hbvs code), with a ROS camera_info YAML
and the true poses. Every row goes through hbvs's command line (in this process, through
``conftest.call_hbvs``; the bare wall without a target as separate processes, as a user
runs them, where the one-line error is checked):
``hbvs teach --video ... --calibration ...`` then ``hbvs fit ...`` with ``--target auto``;
the fitted (theta_d, x_hd) and n* are compared with the truth.
"""

from __future__ import annotations

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest

from hbvs_cli.core.desired import AMBIGUOUS_NORMAL_MARGIN
from hbvs_cli.io.fit_file import read_fit_file
from hbvs_cli.io.teach_file import TeachReader
from hbvs_cli.perception.autodetect import find_dots

import footage
from conftest import SUITE_OR_CAMPAIGN, call_hbvs, campaign_extent, run_hbvs

#: A short drive (60 frames at 5 Hz): 5.8 m to about 3 m from the wall (a 2x change of scale),
#: heading weaving by about +-15 deg.
DRIVE = footage.Drive(duration=12.0, fps=5.0, speed=0.24, period=9.0)

#: The issue's bounds for dot targets seen from 2-6 m. Measured (frames stored in colour; the
#: same to 1e-4 deg as from the gray frames stored before): light dots 0.016 deg, 1.1e-4, n*
#: 0.09 deg; red dots 0.049 deg, 8.6e-5, 0.21 deg; red dots on a grey of the same luminance
#: (seen in colour only) 0.080 deg, 2.5e-4, 0.22 deg; black dots with distortion and motion
#: blur 0.071 deg, 1.8e-4, 0.27 deg.
DOT_BOUNDS = {"theta_deg": 0.1, "x_hd1": 2e-3, "normal_deg": 0.5}


def _teach_and_fit(folder, name, *fit_args):
    made = footage.make_footage(name, folder, DRIVE)
    teach = folder / "teach.mcap"
    result = call_hbvs("teach", "--video", str(made["video"]), "--calibration", str(made["calibration"]), "-o", str(teach), "-q")
    assert result.returncode == 0, result.stderr.decode()
    fit = folder / "fit.mcap"
    result = call_hbvs("fit", str(teach), "-o", str(fit), *fit_args)
    return made, teach, fit, result


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """Every row of the table, taught and fitted once (footage shared by the tests below)."""
    cache = {}

    def get(name):
        if name not in cache:
            folder = tmp_path_factory.mktemp(name)
            made, teach, fit, result = _teach_and_fit(folder, name)
            assert result.returncode == 0, result.stderr.decode()
            model = read_fit_file(fit).model
            cache[name] = {"truth": made, "teach": teach, "fit": fit, "model": model, "stderr": result.stderr.decode(),
                           "errors": footage.errors_against_truth(model, made)}
        return cache[name]

    return get




#: Black dots under 20 gray levels of sensor noise (low light at high gain), beyond the
#: issue's rows: before the detector smoothed noisy windows, --target auto picked texture
#: and the target was missing from 57 % of the frames. Measured: theta_d 0.149 deg,
#: x_hd1 2.4e-4, n* 0.66 deg.
NOISY_DOT_BOUNDS = {"theta_deg": 0.2, "x_hd1": 2e-3, "normal_deg": 1.0}


@pytest.mark.parametrize("name", ["bright_dots", "red_dots", "red_on_grey", "black_dots_distorted", "noisy_dots"])
def test_dot_targets_fit_within_the_issue_bounds(fitted, name, capsys):
    row = fitted(name)
    with capsys.disabled():
        print(f"\n{name}: {row['errors']}")
    assert row["model"].target_kind == "dots"
    assert "--target auto picked dots" in row["stderr"]
    # Only the dots that gray cannot see are measured in colour (and decoded in colour).
    seen_in_colour = name == "red_on_grey"
    assert (row["model"].detector.contrast == "colour") == seen_in_colour
    assert ("in colour, on their brightest channel" in row["stderr"]) == seen_in_colour
    for key, bound in (NOISY_DOT_BOUNDS if name == "noisy_dots" else DOT_BOUNDS).items():
        assert row["errors"][key] <= bound, (name, key, row["errors"][key])


def test_red_dots_on_grey_of_the_same_luminance_are_seen_in_colour_only(fitted):
    """The red_on_grey row's wall: its dots vanish in gray, and its teach file keeps colour."""
    grey, red = footage.RED_ON_GREY
    assert abs(footage.luma601(grey) - footage.luma601(red)) <= 3.0 and len(set(grey)) == 1
    row = fitted("red_on_grey")
    frames = [frame.stored_image().data for frame, _ in zip(TeachReader(row["teach"]).frames(), range(5))]
    stored = [cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED) for data in frames]
    assert all(image.ndim == 3 for image in stored)  # the colour video is stored in colour
    assert find_dots([cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) for image in stored]) is None
    found = find_dots(stored)
    assert found is not None and found.details == {"polarity": "light", "n_points": 5, "contrast": "colour"}


#: The issue's bounds for a single marker of 0.4 m, here 3-5.8 m away (about 35 to 70 px
#: wide). Measured with each marker's square joining the estimate of n* (core/plane.py) and
#: the corners' edge refinement iterated until it settles (perception/aruco.py), frames
#: stored in colour: ArUco 6x6 theta_d 0.108 deg RMS, x_hd1 2.4e-4, n* 0.07 deg; AprilTag
#: 36h11 0.103 deg, 2.6e-4, n* 0.11 deg. Before that iteration the AprilTag gave 1.28 deg, 2.0e-3, n* 1.24 deg: OpenCV's
#: corners were up to 1.6 px off, one refinement pass from there left F*'s corners 0.10 px
#: RMS off, and moves over 1.5 px were refused (the ArUco, 0.28 deg, 4.5e-4, n* 0.29 deg).
MARKER_BOUNDS = {"aruco_6x6": {"theta_deg": 0.35, "x_hd1": 5e-3, "normal_deg": 0.5},
                 "apriltag_36h11": {"theta_deg": 0.35, "x_hd1": 5e-3, "normal_deg": 0.5}}


@pytest.mark.parametrize("dictionary, marker_id", [("DICT_6X6_250", 23), ("DICT_APRILTAG_36h11", 5)])
def test_footage_maker_draws_the_marker_as_opencv_defines_it(dictionary, marker_id):
    """The marker walls' bits, border, quiet zone and corner points, read back cell by cell
    against OpenCV's dictionary (not through any detector): the truth the rows above are
    judged against is where the footage says it is."""
    wall = footage.marker_wall(dictionary, marker_id)
    cv_dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    bits = cv2.aruco.Dictionary.getBitsFromByteList(cv_dictionary.bytesList[marker_id:marker_id + 1], cv_dictionary.markerSize)
    cells = cv_dictionary.markerSize + 2  # the code and its one-cell black border
    expected = np.zeros((cells + 2, cells + 2), int)  # ... and a white quiet zone around it
    expected[0, :] = expected[-1, :] = expected[:, 0] = expected[:, -1] = 1
    expected[2:-2, 2:-2] = bits
    top_left, bottom_right = wall.points[0], wall.points[2]
    assert np.allclose(wall.points[1], [bottom_right[0], top_left[1]]) and np.allclose(wall.points[3], [top_left[0], bottom_right[1]])
    side = bottom_right[0] - top_left[0]  # px, pixel edges (the points are at -0.5)
    assert side == pytest.approx(bottom_right[1] - top_left[1]) and side == pytest.approx(round(0.4 / footage.WALL_MPP))
    cell = side / cells
    gray = cv2.cvtColor(wall.image, cv2.COLOR_BGR2GRAY)
    # Cell centres (wall pixels) from the quiet zone's cell before the border to the one after.
    centres = top_left[None, :] + (np.arange(cells + 2)[:, None] - 0.5) * cell
    read = np.array([[gray[int(round(y)), int(round(x))] for x in centres[:, 0]] for y in centres[:, 1]])
    assert np.array_equal((read > 100).astype(int), expected), read
    # The corners are the ink's edges: the pixel just inside each is black, just outside is paper.
    for (x, y), (dx, dy) in zip(wall.points, ((1, 1), (-1, 1), (-1, -1), (1, -1))):
        inside = gray[int(round(y + 0.5 * dy)), int(round(x + 0.5 * dx))]
        outside = gray[int(round(y - 0.5 * dy)), int(round(x - 0.5 * dx))]
        assert inside < 60 and outside > 150, ((x, y), inside, outside)


@pytest.mark.parametrize("name, dictionary, marker_id", [("aruco_6x6", "DICT_6X6_50", 23), ("apriltag_36h11", "DICT_APRILTAG_36h11", 5)])
def test_markers_auto_finds_dictionary_and_id(fitted, name, dictionary, marker_id, capsys):
    row = fitted(name)
    with capsys.disabled():
        print(f"\n{name}: {row['errors']}")
    detector = row["model"].detector
    assert row["model"].target_kind == "aruco"
    assert detector.marker_dict == dictionary and detector.marker_ids == (marker_id,)
    assert f"--target auto picked aruco: markers: {dictionary} id {marker_id}" in row["stderr"]
    for key, bound in MARKER_BOUNDS[name].items():
        assert row["errors"][key] <= bound, (name, key, row["errors"][key])


def test_marker_options_pin_the_dictionary_and_id(fitted, tmp_path):
    row = fitted("aruco_6x6")
    fit = tmp_path / "pinned.mcap"
    result = call_hbvs("fit", str(row["teach"]), "-o", str(fit), "--marker-dict", "DICT_6X6_250", "--marker-id", "23", "-q")
    assert result.returncode == 0, result.stderr.decode()
    detector = read_fit_file(fit).model.detector
    assert detector.marker_dict == "DICT_6X6_250" and detector.marker_id == 23
    # A dictionary that is not on the wall: one line, no file.
    result = call_hbvs("fit", str(row["teach"]), "-o", str(tmp_path / "no.mcap"), "--marker-dict", "DICT_4X4_50")
    lines = result.stderr.decode().strip().splitlines()
    assert result.returncode != 0 and "DICT_4X4_50" in lines[-1] and "Traceback" not in result.stderr.decode()
    assert not (tmp_path / "no.mcap").exists()
    result = call_hbvs("fit", str(row["teach"]), "-o", str(tmp_path / "no.mcap"), "--marker-dict", "DICT_9X9")
    assert result.returncode == 2 and "unknown marker dictionary" in result.stderr.decode()


#: The issue's bounds for a photograph at least 1 m wide seen from 2-6 m. Measured on this
#: footage (a 1.8 m photograph, 3-5.8 m away): theta_d 0.046 deg RMS, x_hd1 7.4e-5, n* 0.09
#: deg off (0.045 deg, 7.1e-5, 0.09 deg when every frame was aligned twice; before the
#: texture alignment was smoothed before the cut, at matched resolution and with the lens's
#: vignetting modelled: 0.28 deg, 7.6e-4, 0.89 deg). Other footage of the same kind, not
#: asserted: coffee with noise seeds 1 and 2, 0.048 and 0.033 deg; skimage astronaut 0.019
#: deg, chelsea 0.041 deg (n* 0.04-0.22 deg).
PHOTO_BOUNDS = {"theta_deg": 0.1, "x_hd1": 2e-3, "normal_deg": 0.5}


def test_photograph_poster_is_picked_as_texture(fitted, capsys):
    row = fitted("photo")
    with capsys.disabled():
        print(f"\nphoto: {row['errors']}")
    assert row["model"].target_kind == "texture"
    assert "--target auto picked texture" in row["stderr"] and "no markers" in row["stderr"] and "no dots" in row["stderr"]
    for key, bound in PHOTO_BOUNDS.items():
        assert row["errors"][key] <= bound, ("photo", key, row["errors"][key])
    # The weave tells the two homography branches apart (margin 0.008 measured; the true
    # points give 0.009): before, the homographies' errors hid it (margin 0.000, and fit
    # warned that it fell back to "the target faces F*").
    assert row["model"].normal_margin >= AMBIGUOUS_NORMAL_MARGIN, row["model"].normal_margin
    assert "homography branches" not in row["stderr"]


@pytest.mark.parametrize("name", ["red_dots", "photo", "red_on_grey"])
def test_replay_of_the_same_footage_agrees_with_the_fit(fitted, tmp_path, name):
    """Measured: red dots e3 (theta) RMS 0.035 deg, e1 8.9e-5; the photograph 0.014 deg,
    e1 6.9e-5 (its detector starts afresh, the vignetting unknown until the target moves);
    red_on_grey, decoded and detected in colour: 0.096 deg, e1 3.0e-4."""
    row = fitted(name)
    run = tmp_path / "replay.mcap"
    result = call_hbvs("repeat", str(row["fit"]), "--replay", str(row["teach"]), "-o", str(run), "-q")
    assert result.returncode == 0, result.stderr.decode()
    report = call_hbvs("report", str(run), "--json")
    assert report.returncode == 0, report.stderr.decode()
    errors = json.loads(report.stdout)["errors"]
    # The taught frames measured again, against the splines fitted to them: what is left is
    # the splines' smoothing of the per-frame noise, within the fit's own accuracy.
    assert errors["e3"]["rmse"] <= DOT_BOUNDS["theta_deg"], errors["e3"]
    assert errors["e1"]["rmse"] <= DOT_BOUNDS["x_hd1"], errors["e1"]
    assert json.loads(report.stdout)["target"]["lost_frames"] == 0


def test_no_target_names_the_kinds_tried(tmp_path):
    """A bare, evenly lit wall: one line naming every kind tried, no output file."""
    wall = footage.Wall(np.full((600, 1200, 3), 170, np.uint8), footage.WALL_MPP, (5.8, -0.05, 0.6), yaw=0.0)
    short = footage.Drive(duration=2.0, fps=4.0)
    made = footage.FootageMaker(wall, footage.Camera(), footage.Effects(supersample=1), seed=3).write(tmp_path, short)
    teach = tmp_path / "teach.mcap"
    assert run_hbvs("teach", "--video", str(made["video"]), "--calibration", str(made["calibration"]), "-o", str(teach), "-q").returncode == 0
    result = run_hbvs("fit", str(teach), "-o", str(tmp_path / "fit.mcap"))
    text = result.stderr.decode()
    lines = text.strip().splitlines()
    assert result.returncode == 3 and len(lines) == 1, text
    for words in ("markers", "dots", "texture", "--target", "--marker-dict"):
        assert words in lines[0]
    assert "Traceback" not in text and not (tmp_path / "fit.mcap").exists()


# --------------------------------------------------------------------------- issue 24
def _theta_against_truth_and_bound(row: dict, name: str) -> dict:
    """A fitted row's smoothed theta_d against its truth, its own reported sigma (the
    smooth topic's ``theta_d_sigma``) and the footage maker's Cramer-Rao bound at the
    point noise the fit measured."""
    from hbvs_cli.report.fit_plot import read_fit_signals

    truth, model = row["truth"], row["model"]
    smooth = read_fit_signals(row["fit"]).smooth
    keep = np.isin(np.round(truth["t"], 6), np.round(smooth["t"], 6))
    error = smooth["theta_d"] - truth["theta_d"][keep]
    sigma = smooth["theta_d_sigma"]
    wall, camera, _ = footage.case(name)
    bound = footage.cramer_rao_bound(wall, camera, truth["poses"], model.uncertainty.point_noise_px, frames=np.flatnonzero(keep))
    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))  # noqa: E731
    return {"theta_rms_deg": np.degrees(rms(error)), "bound_deg": np.degrees(rms(bound["theta_sigma"][1:])),
            "ratio_to_bound": rms(error) / rms(bound["theta_sigma"][1:]), "coverage": float(np.mean(np.abs(error) <= 1.96 * sigma)),
            "sigma_over_rms": rms(sigma) / rms(error), "normal_sigma_deg": model.uncertainty.normal_sigma_deg}


def test_small_apriltag_far_reference_reports_an_honest_uncertainty(fitted, capsys):
    """The issue's hardest marker row: a 25 cm AprilTag, about 30 px wide in F*, the
    farthest frame. No estimator pins n* well from this drive; hbvs's theta_d is near the
    bound and its reported sigma is the size of its error. Measured (noise seed 7): theta_d
    0.26 deg RMS, 0.98x the Cramer-Rao bound at the measured 0.017 px; reported sigma 0.99x
    the RMS error; 100 % of frames inside the 95 % interval; n* 0.26 deg off (sigma 0.25 deg).
    The campaign below measures the calibration over many noise draws."""
    row = fitted("small_apriltag")
    figures = _theta_against_truth_and_bound(row, "small_apriltag")
    with capsys.disabled():
        print(f"\nsmall_apriltag: {row['errors']} {figures}")
    assert row["model"].target_kind == "aruco"
    assert figures["ratio_to_bound"] <= 1.5, figures
    assert 0.5 <= figures["sigma_over_rms"] <= 2.0, figures
    assert figures["coverage"] >= 0.75, figures
    uncertainty = row["model"].uncertainty
    assert row["errors"]["normal_deg"] <= 3.0 * uncertainty.normal_sigma_deg, (row["errors"], uncertainty)


@pytest.mark.campaign
@pytest.mark.parametrize("name", ["small_apriltag", "red_dots", "dots_sizes_3x"])
def test_rendered_footage_calibration_campaign(request, tmp_path, name, capsys):
    """Over 12 noise draws of the same rendered scene: theta_d within 1.5x of the bound, the
    95 % interval covering at least 90 % of frames, and sigma within 2x of the RMS error
    (figures in bench/CALIBRATION.md). Runs with ``-m campaign`` only."""
    from hbvs_cli.report.fit_plot import read_fit_signals

    campaign_extent(request, "campaign")

    errors, sigmas, bounds = [], [], []
    for seed in range(12):
        folder = tmp_path / f"seed{seed}"
        made = footage.FootageMaker(*footage.case(name), seed=seed).write(folder, DRIVE)
        teach, fit = folder / "teach.mcap", folder / "fit.mcap"
        assert call_hbvs("teach", "--video", str(made["video"]), "--calibration", str(made["calibration"]), "-o", str(teach), "-q").returncode == 0
        assert call_hbvs("fit", str(teach), "-o", str(fit), "-q").returncode == 0
        model = read_fit_file(fit).model
        smooth = read_fit_signals(fit).smooth
        keep = np.isin(np.round(made["t"], 6), np.round(smooth["t"], 6))
        errors.append(smooth["theta_d"] - made["theta_d"][keep])
        sigmas.append(smooth["theta_d_sigma"])
        wall, camera, _ = footage.case(name)
        bounds.append(footage.cramer_rao_bound(wall, camera, made["poses"], model.uncertainty.point_noise_px, frames=np.flatnonzero(keep))["theta_sigma"][1:])
    error, sigma, bound = (np.concatenate(x) for x in (errors, sigmas, bounds))
    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))  # noqa: E731
    figures = {"theta_rms_deg": np.degrees(rms(error)), "ratio_to_bound": rms(error) / rms(bound),
               "coverage": float(np.mean(np.abs(error) <= 1.96 * sigma)), "sigma_over_rms": rms(sigma) / rms(error)}
    with capsys.disabled():
        print(f"\n{name} rendered, 12 draws: {figures}")
    assert figures["ratio_to_bound"] <= 1.5 and figures["coverage"] >= 0.9 and 0.5 <= figures["sigma_over_rms"] <= 2.0, figures


def _write_bag_of(directory, frames, fps: float, camera: footage.Camera) -> None:
    """The frames as a ROS 2 bag (MCAP storage, PNG CompressedImage, the footage's own
    CameraInfo), written by the independent rosbags library, stamped at ``fps``."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from test_io_sources import TYPES, CameraInfo, CompressedImage, RegionOfInterest, _header

    with Writer(directory, version=8, storage_plugin=StoragePlugin.MCAP) as writer:
        images = writer.add_connection("/cam/image/compressed", CompressedImage.__msgtype__, typestore=TYPES)
        infos = writer.add_connection("/cam/camera_info", CameraInfo.__msgtype__, typestore=TYPES)
        for k, frame in enumerate(frames):
            stamp_ns = 1_700_000_000_000_000_000 + int(round(k * 1e9 / fps))
            if k == 0:
                info = CameraInfo(
                    header=_header(stamp_ns), height=camera.height, width=camera.width, distortion_model="plumb_bob",
                    d=np.array(camera.distortion, float), k=camera.K.ravel(), r=np.eye(3).ravel(),
                    p=np.array([camera.fx, 0, camera.cx, 0, 0, camera.fy, camera.cy, 0, 0, 0, 1, 0], float),
                    binning_x=0, binning_y=0, roi=RegionOfInterest(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))
                writer.write(infos, stamp_ns, TYPES.serialize_cdr(info, CameraInfo.__msgtype__))
            data = cv2.imencode(".png", frame, [cv2.IMWRITE_PNG_COMPRESSION, 1])[1].ravel()
            writer.write(images, stamp_ns, TYPES.serialize_cdr(CompressedImage(header=_header(stamp_ns), format="png", data=data),
                                                               CompressedImage.__msgtype__))


@SUITE_OR_CAMPAIGN
def test_the_same_frames_as_video_images_and_bag_give_the_same_fit(fitted, tmp_path, capsys, request, extent):
    """The issue's last row: the LED footage (three bright dots) as its MJPG video, as a ROS
    2 bag of the video's decoded frames (PNG) and (the campaign) as a folder of them. n* and
    theta_d agree within the fits' reported uncertainty. Measured: the bag and the folder
    agree with each other exactly, and with the video (whose frames teach stores as JPEG
    again) to n* 0.16 deg (combined sigma 0.17 deg) and theta_d 0.036 deg at most."""
    from hbvs_cli.report.fit_plot import read_fit_signals

    campaign = campaign_extent(request, extent)  # before the frames are decoded and written
    row = fitted("bright_dots")
    capture = cv2.VideoCapture(str(row["truth"]["video"]))
    frames = []
    while True:
        ok, frame = capture.read()
        if not ok:
            break
        frames.append(frame)
    capture.release()
    _write_bag_of(tmp_path / "bag", frames, DRIVE.fps, footage.case("bright_dots")[1])
    sources = {"bag": ("--bag", str(tmp_path / "bag"))}
    if campaign:
        folder = tmp_path / "frames"
        folder.mkdir()
        for k, frame in enumerate(frames):
            cv2.imwrite(str(folder / f"frame{k:03d}.png"), frame)
        sources["images"] = ("--images", str(folder), "--fps", str(DRIVE.fps), "--calibration", str(row["truth"]["calibration"]))
    fits = {"video": row["fit"]}
    for name, source in sources.items():
        teach, fit = tmp_path / f"{name}.mcap", tmp_path / f"{name}-fit.mcap"
        result = call_hbvs("teach", *source, "-o", str(teach), "-q")
        assert result.returncode == 0, result.stderr.decode()
        result = call_hbvs("fit", str(teach), "-o", str(fit), "-q")
        assert result.returncode == 0, result.stderr.decode()
        fits[name] = fit
    models = {name: read_fit_file(fit).model for name, fit in fits.items()}
    smooth = {name: read_fit_signals(fit).smooth for name, fit in fits.items()}
    video = models["video"]
    for name in sources:
        model = models[name]
        assert model.target_kind == "dots" and model.frames.used == video.frames.used
        apart = np.degrees(np.arccos(np.clip(model.normal @ video.normal, -1.0, 1.0)))
        sigma = np.hypot(model.uncertainty.normal_sigma_deg, video.uncertainty.normal_sigma_deg)
        theta_apart = np.degrees(np.max(np.abs(smooth[name]["theta_d"] - smooth["video"]["theta_d"])))
        with capsys.disabled():
            print(f"\n{name} vs video: n* {apart:.4f} deg apart (combined sigma {sigma:.3f}), theta_d {theta_apart:.4f} deg at most")
        assert apart <= 2.0 * sigma
        assert np.all(np.abs(smooth[name]["theta_d"] - smooth["video"]["theta_d"])
                      <= 2.0 * np.hypot(smooth[name]["theta_d_sigma"], smooth["video"]["theta_d_sigma"]))


def test_footage_maker_pole_hides_the_wall_only_while_it_passes():
    """The pole of the ``dots_pole`` row: outside its passage the frame is the plain maker's,
    byte for byte; halfway through, its colour fills a band of its width at mid-frame."""
    wall, camera, effects, pole = footage.any_case("dots_pole")
    quiet = replace(effects, noise=0.0)
    at_start = lambda t: np.array(DRIVE.start)  # noqa: E731
    with_pole, plain = footage.PoleMaker(wall, camera, quiet, 1, pole), footage.FootageMaker(wall, camera, quiet, 1)
    assert np.array_equal(with_pole.render(at_start, pole.start_s - 0.1), plain.render(at_start, pole.start_s - 0.1))
    frame = with_pole.render(at_start, (pole.start_s + pole.end_s) / 2)
    band = frame[:, camera.width // 2 - 10:camera.width // 2 + 10].reshape(-1, 3).astype(float)
    gain_free = band / band.mean(axis=1, keepdims=True) * np.mean(pole.colour)
    assert np.allclose(np.median(gain_free, axis=0), pole.colour, atol=4.0)
    assert not np.array_equal(frame, plain.render(at_start, (pole.start_s + pole.end_s) / 2))
