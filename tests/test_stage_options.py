"""Options and cases of teach, fit and repeat not covered elsewhere."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from hbvs_cli.core.path import PRESETS, preset_profile
from hbvs_cli.sim.world import TARGET_KINDS, default_world
from hbvs_cli.errors import InputError, UsageError
from hbvs_cli.io.fit_file import read_fit_file
from hbvs_cli.io.mcap import McapStream
from hbvs_cli.io.run_file import read_run

from conftest import call_hbvs, fit_errors, make_fit, make_run, make_teach
from oracles import ground_truth


@pytest.mark.parametrize("kind", TARGET_KINDS)
@pytest.mark.parametrize("name", sorted(PRESETS))
def test_every_preset_keeps_the_target_in_view_and_the_path_moving(kind, name):
    """Every preset keeps every target kind in view (15 px from the border) and keeps
    |x_hd1_dot| away from zero, condition (35) (measured minimum 0.023 1/s)."""
    world = default_world(kind)
    profile, start = preset_profile(name, 30.0)
    t = np.arange(0.0, profile.duration, 1.0 / 30.0)
    poses = profile.poses_at(t, start)
    assert all(world.in_view(pose, margin_px=15.0) for pose in poses)
    _, _, d_star = world.reference_geometry(poses[0])
    _, x_h = ground_truth(world, poses, poses[0])
    v, w = profile.commands_at(t)
    assert np.min(np.abs(-v / d_star + x_h[:, 1] * w)) > 0.02


def test_teach_with_a_poster_image(tmp_path):
    poster = tmp_path / "poster.png"
    rng = np.random.default_rng(3)
    image = cv2.GaussianBlur((rng.random((300, 600)) * 255).astype(np.uint8), (0, 0), 2.0)
    cv2.rectangle(image, (40, 40), (200, 160), 0, -1)
    cv2.circle(image, (420, 150), 70, 255, -1)
    cv2.imwrite(str(poster), image)
    teach = make_teach(tmp_path / "teach.mcap", target="texture", texture=poster, duration=4.0)
    make_fit(teach, tmp_path / "fit.mcap")
    model = read_fit_file(tmp_path / "fit.mcap").model
    assert model.target_kind == "texture" and model.world_description["target"]["texture"] == str(poster)
    assert model.frames.used == model.frames.total == 120
    with pytest.raises(InputError, match="not found"):
        make_teach(tmp_path / "x.mcap", target="texture", texture=tmp_path / "missing.png", duration=1.0)
    with pytest.raises(UsageError, match="--texture"):
        make_teach(tmp_path / "x.mcap", texture=poster, duration=1.0)


def test_lens_distortion_is_honoured(tmp_path):
    """A camera with plumb_bob distortion: images rendered through the lens, points
    undistorted by fit; the desired signals agree with the truth as without distortion."""
    from hbvs_cli.core.camera import CameraIntrinsics
    from hbvs_cli.io.calibration import save_calibration_ros

    calibration = tmp_path / "distorted.yaml"
    save_calibration_ros(CameraIntrinsics(
        fx=500.0, fy=500.0, cx=319.5, cy=239.5, width=640, height=480,
        distortion_model="plumb_bob", distortion=(-0.25, 0.08, 0.0005, -0.0005, 0.0),
    ), calibration)
    teach = make_teach(tmp_path / "teach.mcap", calibration=calibration)
    make_fit(teach, tmp_path / "fit.mcap")
    model = read_fit_file(tmp_path / "fit.mcap").model
    assert model.camera.has_distortion
    errors = fit_errors(model)
    # Measured 0.006 deg and 2e-5 / 4e-5, as without distortion.
    assert errors["theta_deg"] < 0.05 and errors["x_hd1"] < 1e-3 and errors["x_hd2"] < 1e-3


def test_a_given_smoothing_is_used_and_recorded(short_teach, tmp_path):
    model = make_fit(short_teach, tmp_path / "fit.mcap", smoothing="0.5").model
    assert [ch.smoothing for ch in model.trajectory.channels.values()] == [0.5, 0.5]
    rough = make_fit(short_teach, tmp_path / "rough.mcap", smoothing="0").model  # interpolates
    assert rough.trajectory.channels["theta_d"].residual_rms < 1e-9 < model.trajectory.channels["theta_d"].residual_rms


def test_too_much_missing_fails_with_a_clear_message(short_teach, tmp_path):
    from test_stage_fit import _cover_target

    half = tmp_path / "half.mcap"
    _cover_target(short_teach, half, lambda t: int(t * 30) % 2 == 1)  # every other frame, keeping frame 0
    result = call_hbvs("fit", str(half), "-o", str(tmp_path / "f.mcap"), "-q")
    assert result.returncode == 3
    assert b"missing from 50 % of the frames" in result.stderr and b"--max-lost" in result.stderr
    assert not (tmp_path / "f.mcap").exists()
    assert call_hbvs("fit", str(half), "-o", str(tmp_path / "f.mcap"), "-q", "--max-lost", "0.6").returncode == 0


def test_record_images_stores_images_with_detected_and_desired_points(default_fit, tmp_path):
    fit_path, _ = default_fit
    make_run(fit_path, tmp_path / "run.mcap", sim=True, record_images=True, speed=4.0)
    run = read_run(tmp_path / "run.mcap")
    images = [m for m in McapStream(tmp_path / "run.mcap", topics={"/camera/image", "/camera/annotations"})]
    assert sum(m.topic == "/camera/image" for m in images) == run.steps
    annotation = next(m for m in images if m.topic == "/camera/annotations").foxglove()
    assert len(annotation.circles) == 6  # 3 detected (green) + 3 desired (orange)
    from hbvs_cli.io.images import read_compressed_image

    first = next(m for m in images if m.topic == "/camera/image")
    stored = read_compressed_image(first.data)
    image = cv2.imdecode(np.frombuffer(stored.data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert stored.format == "jpeg" and image.shape == (480, 640)  # one gray channel
    # The file holds little more than its images (measured 1.04x: the state, pose and
    # command messages of each step are the rest; bench/FILE_SIZES.md).
    image_bytes = sum(len(read_compressed_image(m.data).data) for m in images if m.topic == "/camera/image")
    assert (tmp_path / "run.mcap").stat().st_size <= 1.1 * image_bytes


def test_sim_after_real_footage_needs_and_uses_an_assumed_depth(video_fit, tmp_path):
    """A teach from a video has no world: repeat --sim builds one at --depth D."""
    fit = video_fit[1]
    result = call_hbvs("repeat", str(fit), "--sim", "-o", str(tmp_path / "run.mcap"), "-q")
    assert result.returncode == 2 and b"--depth" in result.stderr and not (tmp_path / "run.mcap").exists()
    make_run(fit, tmp_path / "run.mcap", sim=True, depth=4.0, perception="points")
    run = read_run(tmp_path / "run.mcap")
    assert run.info["d_true"] == 4.0
    position = np.hypot(*(run.true_pose[:, :2] - run.desired_pose[:, :2]).T)
    assert position[-30:].mean() < 0.01 and run.lost.sum() == 0


def test_robot_sim_base_and_stamp_fault_are_parsed_in_sim():
    """robot-sim's --base and --stamp-fault texts become sim's objects (sim/stand_in.py); the stage only wires them."""
    from hbvs_cli.sim.stand_in import StampFault, parse_base

    small = parse_base("small")
    assert (small.max_v, small.max_w, small.max_accel, small.max_alpha, small.lag_s) == (0.26, 1.8, 0.6, 3.0, 0.12)
    assert parse_base("1,2,3,4,0").max_alpha == 4.0 and math.isinf(parse_base("kinematic").max_v)
    back = StampFault("back:0.5@2")
    assert (back.stamp(10.0, 1.9, 0), back.stamp(10.0, 2.0, 1)) == (10.0, 9.5)
    stall = StampFault("stall:1@2")
    assert (stall.stamp(10.0, 2.5, 0), stall.stamp(10.0, 3.0, 1)) == (None, 10.0)
    assert StampFault("max@0").stamp(1.0, 0.0, 0) == 2.0**31 - 1
    for bad, text in ((parse_base, "1,2,3,-4,0"), (StampFault, "back@1"), (StampFault, "freeze@-1")):
        with pytest.raises(UsageError):
            bad(text)
