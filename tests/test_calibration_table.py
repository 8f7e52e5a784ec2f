"""The table of issue 24, row by row, on the independent footage maker (tests/footage.py).

Each row is rendered (its own warp, distortion, blur, rolling shutter, exposure drift, noise
and MJPG; no hbvs code), taught and fitted as a new user would (``hbvs teach --video ...
--calibration ...`` then ``hbvs fit`` with defaults: ``--target auto``, F* the first and
farthest frame), for a few noise draws. Measured per row, over the draws:

* theta_d's RMS error against the truth, and n*'s angle error;
* that error as a multiple of the footage maker's own Cramer-Rao bound at the point noise
  the fit measured (for a photograph the bound is of its four corners, a proxy: the
  texture tracker's points are its own; with a rolling shutter, the bound of the rolling
  shutter's model, its readout time unknown);
* the fraction of frames whose true theta_d lies inside the reported 95 % interval, and the
  reported sigma over the RMS error;
* the verdict: the issue's bound met (theta_d <= 0.1 deg and x_hd1 <= 2e-3 for dots and
  posters, <= 0.35 deg and 5e-3 for markers and boards), or, where the footage cannot pin
  n*, the fit's warning and the error inside the reported interval (coverage >= 90 %).

Runs with ``-m campaign`` only (a few minutes a row); the figures are in
bench/CALIBRATION.md. Setting ``HBVS_CALIBRATION_TABLE`` to a file appends every row to it
as a line of JSON.
"""

from __future__ import annotations

import json
import os
from dataclasses import replace

import numpy as np
import pytest

from hbvs_cli.io.fit_file import read_fit_file

import footage
from conftest import call_hbvs, campaign_extent

DRIVE = footage.Drive(duration=12.0, fps=5.0, speed=0.24, period=9.0)
#: The noise draws of every row (``HBVS_CALIBRATION_SEEDS``, comma-separated, overrides them).
SEEDS = tuple(int(s) for s in os.environ.get("HBVS_CALIBRATION_SEEDS", "7,8").split(","))
#: Rows whose error two draws do not measure, and their own draws (unless HBVS_CALIBRATION_SEEDS is
#: set): the red distractor's theta_d error is mostly a per-draw bias, so its sigma/RMS is 2.02
#: over seeds 7 and 8 and 0.96 over seeds 0-9 (2.4 s a draw).
ROW_SEEDS = {"red_distractor": tuple(range(10))}

#: The issue's bounds by kind of target: (theta_d deg, x_hd1).
DOT_BOUND = (0.1, 2e-3)
MARKER_BOUND = (0.35, 5e-3)

def _misses(reason: str):
    return pytest.mark.xfail(reason=reason, strict=False)


#: Every row: (the footage maker's case, the issue's row in words, its bound, fit options).
#: Rows that miss an aim are marked with what was measured (bench/CALIBRATION.md).
ROWS = [
    ("bright_dots", "three bright dots (LEDs) on a dark wall", DOT_BOUND, ()),
    ("black_dots_distorted", "five black dots of 3-8 cm, barrel distortion, blur", DOT_BOUND, ()),
    ("aruco_6x6", "one ArUco 6x6 marker, 0.4 m", MARKER_BOUND, ()),
    ("apriltag_36h11", "one AprilTag 36h11, 0.4 m", MARKER_BOUND, ()),
    ("red_on_grey", "red dots on a grey wall of the same luma", DOT_BOUND, ()),
    ("red_dots", "four red dots on a light wall", DOT_BOUND, ()),
    ("photo", "photograph, 1.8 m poster", DOT_BOUND, ()),
    ("photo_distorted_jpeg70", "photograph, distortion, heavy blur, JPEG 70", DOT_BOUND, ()),
    ("small_apriltag", "small AprilTag (25 cm, 30 px in F*)", MARKER_BOUND, ()),
    pytest.param("small_apriltag", "small AprilTag, --target texture", MARKER_BOUND, ("--target", "texture"), id="small_apriltag_texture"),
    ("aruco_board_3x2", "3x2 board of ArUco 4x4 markers, distortion", MARKER_BOUND, ()),
    ("chessboard", "printed chessboard, 7x5 inner corners of 6 cm", MARKER_BOUND, ()),
    pytest.param("chessboard", "printed chessboard, --target chessboard", MARKER_BOUND, ("--target", "chessboard"), id="chessboard_target"),
    ("charuco_board", "printed ChArUco board, 7x5 squares of 12 cm, distortion", MARKER_BOUND, ()),
    ("photo_plain_rolling", "photograph with plain areas, rolling shutter, exposure drift", DOT_BOUND, ()),
    ("photo_with_tags", "photograph with small fiducials printed in it", DOT_BOUND, ()),
    ("low_contrast_dots", "low-contrast dots (25 levels), sensor noise", DOT_BOUND, ()),
    ("low_contrast_dots_rolling", "low-contrast dots, sensor noise, rolling shutter", DOT_BOUND, ()),
    ("brick_sign", "photograph of a 1.2 m sign on a brick wall", DOT_BOUND, ()),
    ("dots_pole", "four red dots, a pole passing in front", DOT_BOUND, ()),
    # Issue 44's styles, each on a drive of its own (footage.STYLE_DRIVES).
    ("red_distractor", "four red dots and a red sign on a grey wall", DOT_BOUND, ()),
    pytest.param("red_distractor", "the same as a ROS 2 .db3 bag (JPEG, /cmd_vel)", DOT_BOUND, ("--bag",), id="red_distractor_bag"),
    pytest.param("leds_bloom", "three LEDs with bloom on a dark wall", DOT_BOUND, (), id="leds_bloom", marks=_misses(
        "seeds 0-9: warned, 100 % inside, sigma/RMS 1.29, but theta_d 2.56x the bound: bloom pulls every centroid 0.11-0.13 px "
        "(an error no unbiased estimate has; counted in the interval, not removed)")),
    ("board_barrel_k3", "3x2 ArUco 4x4 board, barrel lens beyond its two-term calibration", MARKER_BOUND, ()),
    ("photo_small_fiducials", "photograph with five small fiducials printed in it", DOT_BOUND, ()),
    ("dim_dots_rolling", "dots 20 gray levels dark, sensor noise, rolling shutter", DOT_BOUND, ()),
]
ROWS = [row if hasattr(row, "marks") else pytest.param(*row, id=row[0]) for row in ROWS]


def _teach_source(made: dict, name: str, folder, fit_options) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """``hbvs teach``'s source options for a draw (its video, or with ``--bag`` among the
    row's options a ROS 2 .db3 bag of it, its CameraInfo the calibration, as a user with only
    the bag has), and the fit options left."""
    if "--bag" not in fit_options:
        return ("--video", str(made["video"]), "--calibration", str(made["calibration"])), tuple(fit_options)
    bag = footage.write_ros2_bag(folder / "bag", made, footage.any_style(name)[1])
    return ("--bag", str(bag)), tuple(option for option in fit_options if option != "--bag")


def _row_figures(name: str, folder, fit_options=()) -> dict:
    """Teach and fit every noise draw of a row; the figures of the module docstring."""
    from hbvs_cli.report.fit_plot import read_fit_signals

    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))  # noqa: E731
    errors, x_errors, sigmas, bounds, normals, warned, kinds, failures, picks = [], [], [], [], [], [], [], [], []
    for seed in SEEDS if "HBVS_CALIBRATION_SEEDS" in os.environ else ROW_SEEDS.get(name, SEEDS):
        made = footage.make_style_footage(name, folder / f"s{seed}", None if name in footage.STYLES else DRIVE, seed=seed)
        teach, fit = folder / f"s{seed}" / "teach.mcap", folder / f"s{seed}" / "fit.mcap"
        source, options = _teach_source(made, name, folder / f"s{seed}", fit_options)
        taught = call_hbvs("teach", *source, "-o", str(teach), "-q")
        fitted = call_hbvs("fit", str(teach), "-o", str(fit), *options) if taught.returncode == 0 else taught
        if fitted.returncode != 0:
            failures.append(fitted.stderr.decode().strip().splitlines()[-1])
            continue
        model = read_fit_file(fit).model
        smooth = read_fit_signals(fit).smooth
        keep = np.isin(np.round(made["t"], 6), np.round(smooth["t"], 6))
        errors.append(smooth["theta_d"] - made["theta_d"][keep])
        x_errors.append(smooth["x_hd1"] - made["x_hd"][keep, 0])
        sigmas.append(smooth["theta_d_sigma"])
        wall, camera, _, extra = footage.any_style(name)
        shutter = extra if isinstance(extra, footage.RollingShutter) else None
        bounds.append(footage.cramer_rao_bound(wall, camera, made["poses"], model.uncertainty.point_noise_px,
                                               frames=np.flatnonzero(keep), shutter=shutter, drive=made["drive"])["theta_sigma"][1:])
        normal = np.asarray(model.normal, float)
        normals.append(np.degrees(np.arccos(np.clip(abs(normal @ made["normal"]) / np.linalg.norm(normal), -1.0, 1.0))))
        warned.append("plane normal n* uncertain" in fitted.stderr.decode())
        kinds.append(model.target_kind)
        picks.append(next((line for line in fitted.stderr.decode().splitlines() if "--target auto picked" in line), ""))
    if not errors:
        return {"name": name, "fitted": 0, "failures": failures}
    error, x_error, sigma, bound = (np.concatenate(v) for v in (errors, x_errors, sigmas, bounds))
    return {
        "name": name, "fitted": len(errors), "failures": failures, "kinds": sorted(set(kinds)),
        "theta_rms_deg": float(np.degrees(rms(error))), "x_hd1_rms": rms(x_error),
        "normal_error_deg": float(np.sqrt(np.mean(np.square(normals)))),
        "ratio_to_bound": rms(error) / rms(bound), "bound_deg": float(np.degrees(rms(bound))),
        "coverage": float(np.mean(np.abs(error) <= 1.96 * sigma)), "sigma_over_rms": rms(sigma) / rms(error),
        "warned": all(warned), "picks": picks,
    }


def verdict(figures: dict, bound: tuple[float, float]) -> str:
    """'bound met', 'warned, inside the interval', or what missed."""
    if not figures["fitted"]:
        return "no fit"
    if figures["theta_rms_deg"] <= bound[0] and figures["x_hd1_rms"] <= bound[1]:
        return "bound met"
    if figures["warned"] and figures["coverage"] >= 0.9:
        return "warned, inside the interval"
    return "missed"


@pytest.mark.campaign
@pytest.mark.parametrize("name, words, bound, fit_options", ROWS)
def test_issue_table_row(request, tmp_path, name, words, bound, fit_options, capsys):
    """Each row: the issue's bound met, or a warning and the error inside the interval;
    theta_d within 1.5x of the Cramer-Rao bound; and the reported sigma within 0.5-2x of the
    RMS error (issue 44: an uncertainty right both ways)."""
    campaign_extent(request, "campaign")
    figures = _row_figures(name, tmp_path, fit_options) | {"row": words}
    figures["verdict"] = verdict(figures, bound)
    with capsys.disabled():
        print(f"\n{json.dumps(figures)}")
    if os.environ.get("HBVS_CALIBRATION_TABLE"):
        with open(os.environ["HBVS_CALIBRATION_TABLE"], "a") as table:
            table.write(json.dumps(figures) + "\n")
    assert figures["verdict"] in ("bound met", "warned, inside the interval"), figures
    assert figures["ratio_to_bound"] <= 1.5, figures
    assert 0.5 <= figures["sigma_over_rms"] <= 2.0, figures


def test_the_rolling_shutter_bound_marginalises_the_readout():
    """The footage maker's bound with a rolling shutter: a readout of 0, known, gives the global
    shutter's bound (to 1e-9); the readout as an unknown can only raise it. Measured on
    ``photo_plain_rolling``'s drive (every frame): theta_d 0.0784 deg global, 0.0782 with the
    33 ms readout known or not (bench/CALIBRATION.md)."""
    wall, camera, _, shutter = footage.any_case("photo_plain_rolling")
    pose_of_time = footage.drive_pose_function(DRIVE)
    frames = np.arange(0, len(DRIVE.times()), 3)
    poses = np.array([pose_of_time(t) for t in DRIVE.times()])
    plain = footage.cramer_rao_bound(wall, camera, poses, 0.03, frames=frames)
    bound = lambda **shutter_model: footage.cramer_rao_bound(wall, camera, poses, 0.03, frames=frames, drive=DRIVE, **shutter_model)  # noqa: E731
    still = bound(shutter=replace(shutter, readout_s=0.0), readout_known=True)
    known = bound(shutter=shutter, readout_known=True)
    unknown = bound(shutter=shutter)
    assert still["theta_sigma"] == pytest.approx(plain["theta_sigma"], rel=1e-9)
    assert still["normal_sigma"] == pytest.approx(plain["normal_sigma"], rel=1e-9)
    assert np.all(unknown["theta_sigma"] >= known["theta_sigma"] * (1 - 1e-9))
    assert unknown["normal_sigma"] >= known["normal_sigma"] * (1 - 1e-9)
    assert known["theta_sigma"] != pytest.approx(plain["theta_sigma"], rel=1e-6)  # the shutter is modelled
