"""``--target auto`` judged on the whole drive (issue 44; hbvs_cli/stages/auto_target.py),
on footage of the independent footage maker (tests/footage.py)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from hbvs_cli.core.camera import CameraIntrinsics
from hbvs_cli.errors import InputError
from hbvs_cli.io.fit_file import read_fit_file
from hbvs_cli.perception.autodetect import Candidates, TargetChoice
from hbvs_cli.perception.tracked import DetectorSpec
from hbvs_cli.report.fit_plot import read_fit_signals
from hbvs_cli.stages.auto_target import judge, picked

import footage
from conftest import call_hbvs, campaign_extent

#: The suite's short drive: 30 frames at 2.5 Hz.
SHORT = footage.Drive(duration=12.0, fps=2.5, speed=0.24, period=9.0)


def _rendered(name: str, drive: footage.Drive, seed: int = 3):
    """The drive's frames ``(t, BGR image)`` of footage ``name`` and hbvs's camera for it."""
    wall, camera, effects, extra = footage.any_style(name)
    maker = footage.BloomMaker(wall, camera, effects, seed, extra) if isinstance(extra, footage.Bloom) else footage.FootageMaker(wall, camera, effects, seed)
    pose_of = footage.drive_pose_function(drive)
    frames = [(float(t), maker.render(pose_of, t)) for t in drive.times()]
    intrinsics = CameraIntrinsics(camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height, "plumb_bob",
                                  tuple(camera.written_distortion))
    return frames, intrinsics


def _dots(polarity: str) -> TargetChoice:
    return TargetChoice("dots", f"3 {polarity} round dots", {"polarity": polarity, "n_points": 3}, n_points=3, spread_px=70.0)


def _spec(choice: TargetChoice) -> DetectorSpec:
    return DetectorSpec(kind="dots", n_points=choice.details["n_points"], polarity=choice.details["polarity"])


def test_a_candidate_missing_from_the_drive_is_passed_over_for_the_next():
    """Three LEDs on a dark wall, with a candidate that is not there (dark dots) ordered
    first: it is missing from every frame of the drive, so the light dots are picked, and the
    one line says both. Measured: the LEDs found in 30 of 30 frames, theta_d sigma 0.029 deg."""
    frames, camera = _rendered("bright_dots", SHORT)
    candidates = Candidates([_dots("dark"), _dots("light")], ["markers"])
    judged = judge(candidates, _spec, frames, camera, max_lost=0.3)
    assert [j.seen for j in judged] == [0, 30]
    assert judged[0].rejected == "missing from 30 of 30 frames" and not judged[1].rejected
    best, reason = picked(judged, candidates, max_lost=0.3)
    assert best.choice.details["polarity"] == "light"
    assert 0.02 < best.theta_sigma_deg < 0.2, best
    assert "vs dots missing from 30 of 30 frames (more than --max-lost 30 %)" in reason and "no markers" in reason
    with pytest.raises(InputError, match="no target kind is found over the whole drive"):
        picked(judged[:1], candidates, max_lost=0.3)


@pytest.mark.parametrize("name, kind, extent", [("red_distractor", "dots", "suite"),
                                               pytest.param("photo_small_fiducials", "texture", "campaign", marks=pytest.mark.campaign)])
def test_auto_with_defaults_fits_the_issue_styles(request, tmp_path, name, kind, extent, capsys):
    """Issue 44's styles at the suite's size (30 frames): ``hbvs fit`` with defaults picks
    the kind, names the measured figures, and fits with no frame lost after the pick."""
    campaign_extent(request, extent)
    drive = replace(footage.STYLE_DRIVES[name], fps=2.5)
    made = footage.make_style_footage(name, tmp_path, drive, seed=3)
    teach, fit = tmp_path / "teach.mcap", tmp_path / "fit.mcap"
    taught = call_hbvs("teach", "--video", str(made["video"]), "--calibration", str(made["calibration"]), "-o", str(teach), "-q")
    assert taught.returncode == 0, taught.stderr.decode()
    result = call_hbvs("fit", str(teach), "-o", str(fit))
    stderr = result.stderr.decode()
    assert result.returncode == 0, stderr
    assert f"--target auto picked {kind}" in stderr and "followed over 30 frames of the whole drive" in stderr
    assert "missing from" not in stderr.split("--target auto picked", 1)[1].split("\n", 1)[1]
    model = read_fit_file(fit).model
    smooth = read_fit_signals(fit).smooth
    error = smooth["theta_d"] - made["theta_d"][np.isin(np.round(made["t"], 6), np.round(smooth["t"], 6))]
    inside = float(np.mean(np.abs(error) <= 1.96 * smooth["theta_d_sigma"]))
    rms_deg = float(np.degrees(np.sqrt(np.mean(error**2))))
    with capsys.disabled():
        print(f"\n{name}, 30 frames, seed 3: theta_d {rms_deg:.3f} deg RMS, {100 * inside:.0f} % inside the 95 % band")
    assert model.frames.used == 30
    # The issue's bound for dots and posters, or the truth inside the reported band.
    assert rms_deg <= 0.1 or inside >= 0.9, (rms_deg, inside)
