"""The targets labs print (issue 24), on footage hbvs did not render (tests/footage.py):
ChArUco boards, boards partly out of view, dots of 20 gray levels, the target's known
layout (--target-points) and what --target auto picks; each judged by the footage's truth.

The default suite renders a few frames of each and fits one drive (the ChArUco board that
leaves the view); the whole drives, with and without the known layout, run with
``-m campaign``.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from hbvs_cli.core.camera import CameraIntrinsics
from hbvs_cli.core.desired import fit_desired_trajectory
from hbvs_cli.core.known_points import match_layout
from hbvs_cli.errors import GeometryError, InputError
from hbvs_cli.io.fit_file import read_fit_file
from hbvs_cli.io.target_points import read_target_points
from hbvs_cli.perception.aruco import ArucoMarkerDetector
from hbvs_cli.perception.autodetect import find_dots
from hbvs_cli.perception.charuco import CharucoTargetDetector, infer_board
from hbvs_cli.perception.tracked import target_candidates

import footage
from conftest import SUITE_OR_CAMPAIGN, call_hbvs, campaign_extent

DRIVE = footage.Drive(duration=12.0, fps=5.0, speed=0.24, period=9.0)


def _frames(name: str, indices, seed: int = 3, jpeg: int | None = None):
    """Frames ``indices`` of the drive of footage ``name`` (rendered, optionally through
    JPEG as the video stores them), their true target pixels and the camera."""
    wall, camera, effects = footage.case(name)
    maker = footage.FootageMaker(wall, camera, effects, seed=seed)
    times = DRIVE.times()
    poses = DRIVE.poses(times)
    pose_of = lambda t: np.array([np.interp(t, times, poses[:, j]) for j in range(3)])  # noqa: E731
    images = [maker.render(pose_of, times[k]) for k in indices]
    if jpeg is not None:
        images = [cv2.imdecode(cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, jpeg])[1], cv2.IMREAD_COLOR) for image in images]
    return images, footage.ideal_pixels(wall, camera, poses[list(indices)]), camera


def _intrinsics(camera: footage.Camera) -> CameraIntrinsics:
    return CameraIntrinsics(camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height,
                            "plumb_bob", tuple(camera.distortion))


# --------------------------------------------------------------------------- ChArUco
def test_footage_maker_draws_the_charuco_board_as_opencv_defines_it():
    """OpenCV's own CharucoDetector on the wall's print finds every inner corner where the
    footage says it is (the truth the rows below are judged against)."""
    wall = footage.charuco_wall(square_m=0.2, marker_m=0.15)
    board = cv2.aruco.CharucoBoard((6, 4), 0.2, 0.15, cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50))
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(cv2.cvtColor(wall.image, cv2.COLOR_BGR2GRAY))
    assert ids is not None and sorted(np.ravel(ids)) == list(range(15))
    found = corners.reshape(-1, 2)[np.argsort(np.ravel(ids))]
    assert np.max(np.linalg.norm(found - wall.points, axis=1)) < 0.6  # wall pixels of 2 mm, after its blur


def test_charuco_board_inferred_and_its_corners_measured_even_partly_out_of_view():
    """The board's squares and dictionary are inferred from its markers; its 15 corners are
    measured to a tenth of a pixel, and a frame whose top row has left the view keeps the
    corners it shows. Measured: 0.05 px RMS, 0.2 px at most; the last frames 10 of 15
    corners."""
    images, truth, _ = _frames("charuco_partial", [0, 20, 40, 52])
    geometry = infer_board(images[0])
    assert geometry is not None and geometry.squares == (6, 4) and geometry.dictionary == "DICT_4X4_50"
    assert abs(geometry.marker_ratio - 0.75) < 0.08
    detector = CharucoTargetDetector(geometry.squares, geometry.dictionary)
    errors, counts = [], []
    for image, true in zip(images, truth):
        detection = detector.detect(image)
        assert detection.found
        seen = np.all(np.isfinite(detection.pixels), axis=1)
        counts.append(int(seen.sum()))
        errors.append(np.linalg.norm(detection.pixels[seen] - true[seen], axis=1))
    errors = np.concatenate(errors)
    assert np.sqrt(np.mean(errors**2)) < 0.1 and errors.max() < 0.3, errors
    assert counts[:3] == [15, 15, 15] and 6 <= counts[3] < 15, counts


# --------------------------------------------------------------------------- boards partly out of view
def test_aruco_board_partly_out_of_view_keeps_its_visible_markers():
    """The issue's 3x2 board of ArUco 4x4 markers with barrel distortion: once its top row
    has left the view, the bottom row's 12 corners are still reported (the top row's are
    NaN rows) instead of the frame being lost."""
    images, truth, camera = _frames("aruco_board_partial", [0, 57])
    detector = ArucoMarkerDetector(dictionary="DICT_4X4_50", marker_ids=range(6))
    whole = detector.detect(images[0])
    assert whole.found and np.all(np.isfinite(whole.pixels))
    detector.reset()
    partial = detector.detect(images[1])
    seen = np.all(np.isfinite(partial.pixels), axis=1)
    assert partial.found and seen.tolist() == [False] * 12 + [True] * 12
    # Measured pixels carry the lens's distortion; the truth is ideal: compare undistorted.
    from hbvs_cli.core.camera import undistort_pixels

    error = np.linalg.norm(undistort_pixels(_intrinsics(camera), partial.pixels[seen]) - truth[1][seen], axis=1)
    assert error.max() < 0.5, error


def test_fit_uses_frames_that_show_part_of_the_target():
    """Synthetic exact points: frames missing a third of the points (out of view) are used,
    their pose from the points they show; theta_d matches the truth everywhere."""
    from hbvs_cli.core.bundle import projected_points

    camera = CameraIntrinsics(500.0, 500.0, 320.0, 240.0, 640, 480)
    t = np.arange(40) / 5.0
    theta = 0.12 * np.sin(t / 3.0)
    x_h = np.column_stack([-0.05 * t, 0.02 * np.sin(t / 2.0)])
    normal = np.array([0.99, -0.12, 0.0])
    normal /= np.linalg.norm(normal)
    grid = np.array([[1.0, y, z] for z in (0.05, 0.1, 0.15) for y in (-0.1, 0.0, 0.1)])
    m = projected_points(normal, grid, np.column_stack([theta, x_h]))
    pixels = np.stack([camera.cx - camera.fx * m[..., 0], camera.cy - camera.fy * m[..., 1]], axis=-1)
    pixels[30:, 6:] = np.nan  # the top row out of view from frame 30 on
    fit = fit_desired_trajectory(t, pixels, 0, camera, None, max_lost=0.3, max_gap=1.0)
    assert fit.frames.used == 40
    assert np.max(np.abs(fit.theta - theta)) < 1e-6 and np.max(np.abs(fit.x_h - x_h)) < 1e-6


# --------------------------------------------------------------------------- low contrast
def test_dots_of_20_gray_levels_under_sensor_noise_are_found():
    """Five dots 20 gray levels below a mid-grey wall, with sensor noise, vignetting and
    JPEG: --target auto's dots test finds all five (before: 'no known target found')."""
    images, _, _ = _frames("low_contrast20_dots", range(5), jpeg=90)
    found = find_dots(images)
    assert found is not None and found.details == {"polarity": "dark", "n_points": 5}


# --------------------------------------------------------------------------- known layout
@pytest.mark.parametrize("n_points", [3, 4, 5, 10])
def test_known_layout_is_matched_in_any_order(n_points):
    rng = np.random.default_rng(n_points)
    layout = rng.uniform(0.0, 2.0, (n_points, 2))
    # A wall a little off face-on (three or four points are matched by their likeness).
    H = np.array([[0.1, 0.004, 0.3], [0.002, -0.1, 0.1], [0.01, 0.002, 1.0]])
    mapped = np.column_stack([layout, np.ones(n_points)]) @ H.T
    seen = mapped[:, :2] / mapped[:, 2:]
    order = rng.permutation(n_points)
    found = match_layout(layout, seen[order] + rng.normal(0.0, 1e-4, (n_points, 2)))
    assert np.array_equal(found, order)
    with pytest.raises(GeometryError):
        match_layout(rng.uniform(0.0, 2.0, (n_points, 2)) * [1.0, 0.1], seen)


def test_target_points_file_is_read_or_refused_in_one_line(tmp_path):
    good = tmp_path / "points.csv"
    good.write_text("x,y\n0.5,1.1\n2.45,1.15\n\n# the third\n1.4,0.85\n")
    assert read_target_points(good).tolist() == [[0.5, 1.1], [2.45, 1.15], [1.4, 0.85]]
    for text, words in (("x,y\n0,0\n1,0\n", "3 to"), ("0,0\n1,0\nzero,1\n", "line 3"), ("0,0\n1,0\n0,0\n", "same place"),
                        ("0,0,0\n1,0,0\n0,1,0\n", "two finite numbers"),
                        # Scaled by mistake (issue 46): refused here, not by repeat's --dhat0 after the fit.
                        ("0,0\n1e150,0\n0,2e150\n", "in metres"), ("0,0\n1e-150,0\n0,2e-150\n", "in metres"),
                        ("0,0\n0.0005,0\n0,0.0005\n", "apart at most")):
        bad = tmp_path / "bad.csv"
        bad.write_text(text)
        with pytest.raises(InputError, match=words):
            read_target_points(bad)


# --------------------------------------------------------------------------- what auto picks
def _candidates(images, camera):
    """What ``--target auto`` finds in the first frames, the best predicted first, by kind."""
    found = target_candidates(images, _intrinsics(camera))
    return found, {choice.kind: choice for choice in found.found}


def test_auto_picks_the_picture_over_a_small_marker_printed_in_it():
    """A photograph with a small ArUco marker printed in its corner: the whole picture is
    predicted the better (before: the tiny marker, n* off by 14 deg in the issue). Measured by
    --target KIND on the whole drive (seeds 7, 8): texture 0.031 and 0.044 deg; the marker 4.3
    deg (seed 7; lost on seed 8)."""
    images, _, camera = _frames("photo_with_tags", range(5))
    candidates, by_kind = _candidates(images, camera)
    assert candidates.found[0].kind == "texture", candidates.found
    assert by_kind["aruco"].n_points == 4  # one marker's corners
    assert 10 * by_kind["texture"].predicted_deg < by_kind["aruco"].predicted_deg


def test_auto_picks_the_texture_of_a_small_chessboard_over_its_corners():
    """The chessboard of 6 cm squares (its 35 inner corners 13 px RMS about their centre in
    F*): the alignment of the whole board predicts a better theta_d than its corners, as
    measured by --target KIND on the whole drive (seeds 7, 8): texture 0.083 and 0.070 deg,
    chessboard 0.144 and 0.131 deg."""
    images, _, camera = _frames("chessboard", range(5), jpeg=90)
    candidates, by_kind = _candidates(images, camera)
    assert candidates.found[0].kind == "texture", candidates.found
    assert by_kind["chessboard"].n_points == 35
    assert 0.05 <= by_kind["texture"].predicted_deg < by_kind["chessboard"].predicted_deg <= 0.3


# --------------------------------------------------------------------------- whole drives
def _teach_and_fit(tmp_path, name, seed: int = 7, drive: footage.Drive = DRIVE):
    made = footage.FootageMaker(*footage.case(name), seed=seed).write(tmp_path / name, drive)
    teach = tmp_path / name / "teach.mcap"
    result = call_hbvs("teach", "--video", str(made["video"]), "--calibration", str(made["calibration"]), "-o", str(teach), "-q")
    assert result.returncode == 0, result.stderr.decode()
    return made, teach


def _fit(teach, out, *args):
    result = call_hbvs("fit", str(teach), "-o", str(out), *args)
    assert result.returncode == 0, result.stderr.decode()
    model = read_fit_file(out).model
    return model, result.stderr.decode()


def _write_points(made_wall: footage.Wall, path, seed: int = 5):
    """The wall's target points in metres (y up, shuffled): what a tape measure gives."""
    points = made_wall.points * footage.WALL_MPP * [1.0, -1.0]
    points = points[np.random.default_rng(seed).permutation(len(points))]
    np.savetxt(path, points, delimiter=",", header="x,y", comments="")
    return path


#: The ChArUco board hung high, its top row leaving the view in the last 15 frames (seed 7).
#: Measured at 5 frames per second: 57 of 60 frames used (the last 3 show one row of
#: corners, collinear), theta_d 0.082 deg RMS, x_hd1 1.9e-4, n* 0.08 deg off; at 2.5 (the
#: suite's): 29 of 30. The board in full view the whole drive (the campaign's "charuco"):
#: 60 of 60, 0.020 deg, n* 0.004 deg off (its corners as saddle points; 0.55 deg with
#: cornerSubPix's alone).
CHARUCO_BOUNDS = {"theta_deg": 0.35, "x_hd1": 5e-3, "normal_deg": 0.5}


@SUITE_OR_CAMPAIGN
def test_charuco_board_leaving_the_view_is_picked_and_fitted(tmp_path, request, extent, capsys):
    campaign = campaign_extent(request, extent)
    names = ["charuco_partial"] + (["charuco"] if campaign else [])
    drive = DRIVE if campaign else footage.Drive(duration=12.0, fps=2.5, speed=0.24, period=9.0)
    for name in names:
        made, teach = _teach_and_fit(tmp_path, name, drive=drive)
        # The suite names the kind (its board still inferred): --target auto scans every
        # dictionary in 5 frames first, seconds on a board's many square candidates.
        model, stderr = _fit(teach, tmp_path / f"{name}-fit.mcap", *([] if campaign else ["--target", "charuco"]))
        errors = footage.errors_against_truth(model, made)
        with capsys.disabled():
            print(f"\n{name}: {model.frames.used}/{model.frames.total} frames, {errors}")
        picked = "--target auto picked charuco" if campaign else "charuco"
        assert model.target_kind == "charuco" and f"{picked}: ChArUco board of 6x4 squares" in stderr
        assert model.detector.board == (6, 4) and model.detector.marker_dict == "DICT_4X4_50"
        if name == "charuco_partial":
            assert model.frames.used >= model.frames.total - 3
        for key, bound in CHARUCO_BOUNDS.items():
            assert errors[key] <= bound, (key, errors)


@pytest.mark.campaign
def test_aruco_board_partly_out_of_view_loses_no_frame(tmp_path, request, capsys):
    """The issue's 3x2 ArUco board with distortion, its top row out of view in the last 16
    frames: before, those frames were lost. Measured: 59 of 60 used, theta_d 0.041 deg."""
    campaign_extent(request, "campaign")
    made, teach = _teach_and_fit(tmp_path, "aruco_board_partial")
    model, _ = _fit(teach, tmp_path / "fit.mcap", "-q")
    errors = footage.errors_against_truth(model, made)
    with capsys.disabled():
        print(f"\naruco_board_partial: {model.frames.used}/{model.frames.total} frames, {errors}")
    assert model.frames.used >= 58
    assert errors["theta_deg"] <= 0.35 and errors["x_hd1"] <= 5e-3


@pytest.mark.campaign
@pytest.mark.parametrize("name", ["low_contrast20_dots", "black_dots_distorted", "bright_dots"])
def test_known_layout_pins_the_plane_normal(tmp_path, request, name, capsys):
    """The same drive fitted without and with --target-points (the dots' positions in
    metres, shuffled). Measured (seed 7), n* and theta_d RMS error without -> with:
    20-level dots 1.10 -> 0.06 deg and 0.252 -> 0.115 deg; black dots with distortion 0.27 ->
    0.05 deg and 0.071 -> 0.027 deg; three bright dots 0.087 -> 0.014 deg and 0.016 ->
    0.020 deg. d* from the layout: 5.782, 5.782 and 5.781 m (true 5.781 m)."""
    campaign_extent(request, "campaign")
    made, teach = _teach_and_fit(tmp_path, name)
    plain, _ = _fit(teach, tmp_path / "plain.mcap", "-q")
    points = _write_points(footage.case(name)[0], tmp_path / "points.csv")
    known, _ = _fit(teach, tmp_path / "known.mcap", "-q", "--target-points", str(points))
    without, with_ = footage.errors_against_truth(plain, made), footage.errors_against_truth(known, made)
    with capsys.disabled():
        print(f"\n{name}: without {without}\n{name}: with    {with_}  d* {known.dhat0:.3f} (true {made['d_star']:.3f})")
    assert with_["normal_deg"] <= 0.2 and with_["normal_deg"] <= without["normal_deg"] + 0.05
    assert with_["theta_deg"] <= max(0.15, without["theta_deg"])
    assert known.dhat0_source != "guess" and abs(known.dhat0 / made["d_star"] - 1.0) < 0.02


def test_known_layout_gives_the_depth_in_the_suite(tmp_path, capsys):
    """The suite's short drive of the three bright dots fitted with --target-points: the layout
    pins n* and gives d* (the campaign above runs the whole drives)."""
    made, teach = _teach_and_fit(tmp_path, "bright_dots", drive=footage.Drive(duration=12.0, fps=2.5, speed=0.24, period=9.0))
    points = _write_points(footage.case("bright_dots")[0], tmp_path / "points.csv")
    known, said = _fit(teach, tmp_path / "known.mcap", "--target-points", str(points))
    errors = footage.errors_against_truth(known, made)
    with capsys.disabled():
        print(f"\nbright_dots, short drive, with --target-points: {errors}  d* {known.dhat0:.3f} (true {made['d_star']:.3f})")
    assert errors["normal_deg"] <= 0.2 and errors["theta_deg"] <= 0.1
    assert known.dhat0_source == "target-size" and abs(known.dhat0 / made["d_star"] - 1.0) < 0.02
    # The table names where d* came from, and nothing advises giving what was given (issue 46).
    assert f"d* from --target-points" in said and f"{known.dhat0:.3f} m (--target-points)" in said
    assert "target size" not in said and "--target-points FILE" not in said


@pytest.mark.campaign
@pytest.mark.parametrize("name, kind", [("low_contrast20_dots", "dots"), ("chessboard", "chessboard"), ("photo_with_tags", "texture")])
def test_auto_picks_on_whole_drives(tmp_path, request, name, kind, capsys):
    """--target auto on the whole drive, its one line and the fit against the truth.
    Measured (seed 7): 20-level dots, 60 of 60 frames, theta_d 0.25 deg (0.63x the bound;
    n* 1.1 deg off, sigma 0.69 deg, warned); the chessboard of 6 cm squares: its corners,
    judged on the whole drive (sigma 0.12 deg against its texture's 0.17: docs/targets.md);
    photograph with a marker 0.031 deg."""
    campaign_extent(request, "campaign")
    made, teach = _teach_and_fit(tmp_path, name)
    model, stderr = _fit(teach, tmp_path / "fit.mcap")
    errors = footage.errors_against_truth(model, made)
    with capsys.disabled():
        print(f"\n{name}: {model.frames.used}/{model.frames.total} frames, {errors}")
    assert model.target_kind == kind and f"--target auto picked {kind}" in stderr


def test_target_options_refused_in_one_line(tmp_path):
    """--board and --target-points are checked before any frame is read: one line, the
    usage or input exit code, no output; --target auto refuses kind options no one kind takes."""
    points = tmp_path / "points.csv"
    points.write_text("0,0\n1,0\n")
    cases = ((("--board", "6by4"), 2, "--board must be COLUMNSxROWS"), (("--board", "6x4", "--target", "dots"), 2, "--board is not for --target dots"),
             (("--board", "6x4", "--marker-id", "3"), 2, "--marker-id and --board are not for --target auto (no one kind"),
             (("--target-points", str(tmp_path / "none.csv")), 3, "no such file"), (("--target-points", str(points)), 3, "3 to"),
             (("--target-points", str(points), "--target", "texture"), 2, "texture"))
    for args, code, words in cases:
        result = call_hbvs("fit", str(tmp_path / "teach.mcap"), "-o", str(tmp_path / "fit.mcap"), *args)
        lines = result.stderr.decode().strip().splitlines()
        assert result.returncode == code and len(lines) == 1 and words in lines[0], (args, result.returncode, lines)
        assert not (tmp_path / "fit.mcap").exists()
