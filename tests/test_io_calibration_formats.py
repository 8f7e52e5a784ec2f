"""Calibration formats of issue 14: Kalibr camchains, fisheye models through cv2.fisheye, a
4-coefficient file without a model, and the image size taken from the images."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import yaml

from conftest import call_hbvs

from hbvs_cli.core.camera import CameraIntrinsics, distort_pixels, undistort_pixels
from hbvs_cli.errors import CalibrationError
from hbvs_cli.io.calibration import load_calibration, save_calibration_ros
from hbvs_cli.io.teach_file import TeachReader

FISHEYE_D = (-0.013, 0.021, -0.012, 0.0031)


def _camchain(path, distortion_model, coefficients, resolution=(752, 480)):
    cam0 = {
        "camera_model": "pinhole", "intrinsics": [461.6, 460.3, 363.0, 248.1],
        "distortion_model": distortion_model, "distortion_coeffs": list(coefficients),
        "T_cam_imu": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
        "cam_overlaps": [], "rostopic": "/cam0/image_raw",
    }
    if resolution is not None:
        cam0["resolution"] = list(resolution)
    path.write_text(yaml.safe_dump({"cam0": cam0}))
    return path


def test_kalibr_camchain_radtan_and_equidistant(tmp_path):
    radtan = load_calibration(_camchain(tmp_path / "radtan.yaml", "radtan", (-0.28, 0.07, 0.0002, 0.00002)))
    assert (radtan.fx, radtan.fy, radtan.cx, radtan.cy, radtan.width, radtan.height) == (461.6, 460.3, 363.0, 248.1, 752, 480)
    assert radtan.distortion_model == "plumb_bob" and radtan.distortion == (-0.28, 0.07, 0.0002, 0.00002, 0.0)
    fisheye = load_calibration(_camchain(tmp_path / "equi.yaml", "equidistant", FISHEYE_D))
    assert fisheye.distortion_model == "equidistant" and fisheye.distortion == FISHEYE_D
    # No resolution in the file: the images' size stands in, and without images it is refused.
    sizeless = _camchain(tmp_path / "sizeless.yaml", "equidistant", FISHEYE_D, resolution=None)
    assert load_calibration(sizeless, image_size=(640, 480)).width == 640
    with pytest.raises(CalibrationError, match="cam0: no resolution"):
        load_calibration(sizeless)
    with pytest.raises(CalibrationError, match="distortion_model 'fov' is not supported"):
        load_calibration(_camchain(tmp_path / "fov.yaml", "fov", (0.9,)))


@pytest.mark.parametrize("model", ["equidistant", "kannala_brandt", "fisheye"])
def test_fisheye_model_names_and_ros_round_trip(tmp_path, model):
    path = tmp_path / "fisheye.yaml"
    path.write_text(yaml.safe_dump({
        "image_width": 640, "image_height": 480, "camera_matrix": {"rows": 3, "cols": 3, "data": [300, 0, 320, 0, 300, 240, 0, 0, 1]},
        "distortion_model": model, "distortion_coefficients": {"rows": 1, "cols": 4, "data": list(FISHEYE_D)},
    }))
    camera = load_calibration(path)
    assert camera.distortion_model == "equidistant" and camera.distortion == FISHEYE_D
    assert load_calibration(save_calibration_ros(camera, tmp_path / "again.yaml")) == camera


def test_fisheye_undistortion_inverts_opencv_fisheye_projection():
    """Pixels projected by cv2.fisheye (the lens) come back to the pinhole pixels of K."""
    camera = CameraIntrinsics(fx=300.0, fy=301.0, cx=320.0, cy=240.0, width=640, height=480,
                              distortion_model="equidistant", distortion=FISHEYE_D)
    rng = np.random.default_rng(5)
    points = np.column_stack([rng.uniform(-1.2, 1.2, 50), rng.uniform(-0.9, 0.9, 50), np.ones(50)])
    lens, _ = cv2.fisheye.projectPoints(points.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), camera.K, np.array(FISHEYE_D))
    pinhole = (camera.K @ points.T).T[:, :2]
    np.testing.assert_allclose(undistort_pixels(camera, lens.reshape(-1, 2)), pinhole, atol=1e-6)
    np.testing.assert_allclose(distort_pixels(camera, pinhole), lens.reshape(-1, 2), atol=1e-9)


def _opencv_file(path, coefficients, with_size=True, model=None):
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    storage.write("camera_matrix", np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]))
    storage.write("distortion_coefficients", np.array([coefficients], dtype=float))
    if with_size:
        storage.write("image_width", 640)
        storage.write("image_height", 480)
    if model is not None:
        storage.write("distortion_model", model)
    storage.release()
    return path


def test_four_coefficient_opencv_file_is_read_as_plumb_bob_with_a_note(tmp_path):
    notes: list[str] = []
    camera = load_calibration(_opencv_file(tmp_path / "four.yaml", FISHEYE_D), notes=notes)
    assert camera.distortion_model == "plumb_bob" and camera.distortion == (*FISHEYE_D, 0.0)
    assert len(notes) == 1 and "4 distortion coefficients" in notes[0] and "distortion_model: equidistant" in notes[0]
    fisheye = load_calibration(_opencv_file(tmp_path / "fisheye.yaml", FISHEYE_D, model="equidistant"), notes=notes)
    assert fisheye.distortion_model == "equidistant" and len(notes) == 1


def test_teach_takes_the_image_size_from_the_video_and_warns_about_four_coefficients(tmp_path):
    video = tmp_path / "drive.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (640, 480))
    for k in range(4):
        writer.write(np.full((480, 640, 3), 40 * k, np.uint8))
    writer.release()
    calibration = _opencv_file(tmp_path / "nosize.yaml", FISHEYE_D, with_size=False)
    output = tmp_path / "teach.mcap"
    result = call_hbvs("teach", "--video", str(video), "--calibration", str(calibration), "-o", str(output))
    assert result.returncode == 0, result.stderr
    warnings = [line for line in result.stderr.decode().splitlines() if "4 distortion coefficients" in line]
    assert len(warnings) == 1
    reader = TeachReader(output)
    assert len(list(reader.frames())) == 4
    assert (reader.camera.width, reader.camera.height) == (640, 480)


def test_a_bag_camera_info_with_a_fisheye_model_is_used(tmp_path):
    from rosbags.rosbag2 import StoragePlugin, Writer
    from test_io_rosbag_layouts import STAMP0, TYPES, CameraInfo, CompressedImage, _camera_info, _header

    from hbvs_cli.io.sources import BagSource

    bag = tmp_path / "fisheye_bag"
    with Writer(bag, version=8, storage_plugin=StoragePlugin.SQLITE3) as writer:
        info = writer.add_connection("/cam/camera_info", CameraInfo.__msgtype__, typestore=TYPES)
        image = writer.add_connection("/cam/image/compressed", CompressedImage.__msgtype__, typestore=TYPES)
        writer.write(info, STAMP0, TYPES.serialize_cdr(_camera_info(STAMP0, "equidistant", FISHEYE_D), CameraInfo.__msgtype__))
        png = cv2.imencode(".png", np.zeros((480, 640), np.uint8))[1].ravel()
        writer.write(image, STAMP0, TYPES.serialize_cdr(CompressedImage(header=_header(STAMP0), format="png", data=png),
                                                        CompressedImage.__msgtype__))
    source = BagSource(bag)
    assert source.camera_problem is None
    assert source.camera.distortion_model == "equidistant" and source.camera.distortion == FISHEYE_D


def test_the_renderer_draws_a_fisheye_lens_as_distort_pixels_says():
    """``teach --sim --calibration fisheye.yaml`` renders through cv2.fisheye too."""
    from hbvs_cli.sim.render import _inverse_distortion_map

    camera = CameraIntrinsics(fx=300.0, fy=300.0, cx=160.0, cy=120.0, width=320, height=240,
                              distortion_model="equidistant", distortion=FISHEYE_D)
    ideal = _inverse_distortion_map(camera).reshape(-1, 2).astype(float)
    u, v = np.meshgrid(np.arange(320.0), np.arange(240.0))
    # The map is stored as float32: 3e-5 px resolution at these coordinates.
    assert np.abs(distort_pixels(camera, ideal) - np.column_stack([u.ravel(), v.ravel()])).max() < 1e-4
