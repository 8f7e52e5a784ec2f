"""Calibration files: ROS camera_info YAML, OpenCV FileStorage, JSON, Foxglove messages."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hbvs_cli.core.camera import DEFAULT_CAMERA, CameraIntrinsics
from hbvs_cli.errors import CalibrationError, InputError
from hbvs_cli.io.calibration import (
    MAX_CALIBRATION_BYTES,
    calibration_from_foxglove,
    calibration_to_foxglove,
    intrinsics_from_values,
    load_calibration,
    save_calibration_ros,
)

PLUMB_BOB = CameraIntrinsics(
    fx=612.4375,
    fy=611.9921875,
    cx=318.25,
    cy=241.5,
    width=640,
    height=480,
    distortion_model="plumb_bob",
    distortion=(-0.2875, 0.0891, 1e-05, -0.00031, 0.0125),
)
RATIONAL = CameraIntrinsics(
    fx=1000.1,
    fy=999.7,
    cx=960.3,
    cy=540.9,
    width=1920,
    height=1080,
    distortion_model="rational_polynomial",
    distortion=(0.1, -0.02, 0.001, 0.002, 0.0003, 0.4, -0.05, 0.006),
)

# What the ROS camera calibrator writes (its own formatting, with 8-decimal numbers).
ROS_CALIBRATOR_YAML = """\
image_width: 752
image_height: 480
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [430.215550, 0.000000, 373.499964, 0.000000, 430.089380, 219.113265, 0.000000, 0.000000, 1.000000]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.337586, 0.111665, -0.000320, 0.000195, 0.000000]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1.000000, 0.000000, 0.000000, 0.000000, 1.000000, 0.000000, 0.000000, 0.000000, 1.000000]
projection_matrix:
  rows: 3
  cols: 4
  data: [377.126770, 0.000000, 373.437614, 0.000000, 0.000000, 396.904327, 218.102966, 0.000000, 0.000000, 0.000000, 1.000000, 0.000000]
"""


def _write(tmp_path, name, content):
    path = tmp_path / name
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content, encoding="utf-8")
    return path


# ----------------------------------------------------------------------------- ROS YAML
@pytest.mark.parametrize("camera", [PLUMB_BOB, RATIONAL, DEFAULT_CAMERA], ids=["plumb_bob", "rational", "none"])
def test_ros_yaml_round_trip_is_exact(tmp_path, camera):
    path = save_calibration_ros(camera, tmp_path / "camera.yaml", camera_name="front")
    loaded = load_calibration(path)
    assert loaded == camera  # dataclass equality: every float bit-identical
    text = path.read_text()
    assert "camera_name: front" in text and "projection_matrix:" in text


def test_ros_yaml_without_distortion_is_written_as_zero_plumb_bob(tmp_path):
    import yaml

    path = save_calibration_ros(DEFAULT_CAMERA, tmp_path / "camera.yaml")
    document = yaml.safe_load(path.read_text())
    assert document["distortion_model"] == "plumb_bob"
    assert document["distortion_coefficients"]["data"] == [0.0] * 5
    assert document["projection_matrix"]["data"] == [500.0, 0.0, 319.5, 0.0, 0.0, 500.0, 239.5, 0.0, 0.0, 0.0, 1.0, 0.0]
    assert document["rectification_matrix"]["data"] == [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0]


def test_ros_calibrator_output_is_read_with_plumb_bob_coefficients(tmp_path):
    camera = load_calibration(_write(tmp_path, "ost.yaml", ROS_CALIBRATOR_YAML))
    assert (camera.fx, camera.fy, camera.cx, camera.cy) == (430.21555, 430.08938, 373.499964, 219.113265)
    assert (camera.width, camera.height) == (752, 480)
    assert camera.distortion_model == "plumb_bob"
    assert camera.distortion == (-0.337586, 0.111665, -0.00032, 0.000195, 0.0)


def test_dumped_camera_info_message_with_document_separator(tmp_path):
    # `ros2 topic echo --once /camera_info > info.yaml`: flat k/d lists and a trailing "---".
    text = (
        "header:\n  stamp:\n    sec: 3\n    nanosec: 0\n  frame_id: cam\nheight: 240\nwidth: 320\n"
        "distortion_model: plumb_bob\nd:\n- 0.01\n- -0.02\n- 0.0\n- 0.0\n- 0.003\n"
        "k:\n- 300.0\n- 0.0\n- 160.0\n- 0.0\n- 301.0\n- 120.0\n- 0.0\n- 0.0\n- 1.0\n---\n"
    )
    camera = load_calibration(_write(tmp_path, "info.yaml", text))
    assert camera == CameraIntrinsics(300.0, 301.0, 160.0, 120.0, 320, 240, "plumb_bob", (0.01, -0.02, 0.0, 0.0, 0.003))


def test_yaml_exponent_without_dot_is_a_number(tmp_path):
    # PyYAML reads "1e-05" as a string (YAML 1.1); other writers emit it.
    text = ROS_CALIBRATOR_YAML.replace("0.000195", "1e-05")
    assert load_calibration(_write(tmp_path, "ost.yaml", text)).distortion[3] == 1e-05


# ----------------------------------------------------------------------------- OpenCV FileStorage
def _opencv_write(path, entries):
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in entries.items():
        storage.write(key, value)
    storage.release()
    return path


@pytest.mark.parametrize("extension", ["yaml", "yml", "json", "xml", "txt"])
def test_opencv_filestorage_files(tmp_path, extension):
    K = np.array([[505.5, 0.0, 322.25], [0.0, 506.75, 243.125], [0.0, 0.0, 1.0]])
    D = np.array([[0.125, -0.25, 0.0015, -0.0005, 0.0625]])
    # FileStorage picks its format from the extension; .txt is written as YAML and must
    # still be detected by content.
    written = _opencv_write(
        tmp_path / f"calib.{extension if extension != 'txt' else 'yaml'}",
        {"image_width": 640, "image_height": 480, "camera_matrix": K, "distortion_coefficients": D},
    )
    path = written.rename(tmp_path / f"calib.{extension}")
    camera = load_calibration(path)
    assert camera == CameraIntrinsics(505.5, 506.75, 322.25, 243.125, 640, 480, "plumb_bob",
                                      (0.125, -0.25, 0.0015, -0.0005, 0.0625))


def test_opencv_short_keys_and_padded_distortion(tmp_path):
    K = np.array([[700.0, 0.0, 400.0], [0.0, 700.0, 300.0], [0.0, 0.0, 1.0]])
    # calibrateCamera with CALIB_RATIONAL_MODEL pads to 14 coefficients with zeros.
    D = np.array([0.1, 0.01, 0.0, 0.0, 0.001, 0.2, 0.02, 0.002, 0, 0, 0, 0, 0, 0], float)
    path = _opencv_write(tmp_path / "c.yaml", {"width": 800, "height": 600, "K": K, "D": D})
    camera = load_calibration(path)
    assert camera.distortion_model == "rational_polynomial"
    assert camera.distortion == (0.1, 0.01, 0.0, 0.0, 0.001, 0.2, 0.02, 0.002)
    assert (camera.width, camera.height, camera.fx) == (800, 600, 700.0)


def test_opencv_zero_distortion_is_none(tmp_path):
    K = np.array([[700.0, 0.0, 400.0], [0.0, 700.0, 300.0], [0.0, 0.0, 1.0]])
    path = _opencv_write(tmp_path / "c.json", {"image_width": 800, "image_height": 600, "camera_matrix": K,
                                                "dist_coeffs": np.zeros((5, 1))})
    camera = load_calibration(path)
    assert camera.distortion_model == "none" and camera.distortion == ()


def test_opencv4_yaml_text(tmp_path):
    # As OpenCV 4's calibration sample writes it ("%YAML:1.0", which PyYAML cannot read).
    text = (
        "%YAML:1.0\n---\ncalibration_time: \"Mon 01 Jan 2024\"\nimage_width: 1280\nimage_height: 720\n"
        "board_width: 9\nboard_height: 6\nsquare_size: 2.5e-02\nflags: 0\n"
        "camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
        "   data: [ 9.1025e+02, 0., 6.4012e+02, 0., 9.0875e+02, 3.6050e+02, 0., 0., 1. ]\n"
        "distortion_coefficients: !!opencv-matrix\n   rows: 5\n   cols: 1\n   dt: d\n"
        "   data: [ -4.1e-01, 2.2e-01, 1.5e-03, -7.0e-04, -7.5e-02 ]\n"
        "avg_reprojection_error: 3.1e-01\n"
    )
    camera = load_calibration(_write(tmp_path, "out_camera_data.yml", text))
    assert camera == CameraIntrinsics(910.25, 908.75, 640.12, 360.5, 1280, 720, "plumb_bob",
                                      (-0.41, 0.22, 0.0015, -0.0007, -0.075))


def test_opencv_matrix_with_wrong_element_count(tmp_path):
    text = (
        "%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\ncamera_matrix: !!opencv-matrix\n"
        "   rows: 3\n   cols: 3\n   dt: d\n   data: [ 500., 0., 320., 0., 500., 240., 0., 0. ]\n"
    )
    path = _write(tmp_path, "broken_cv.yaml", text)
    with pytest.raises(CalibrationError, match="broken_cv.yaml"):
        load_calibration(path)


# ----------------------------------------------------------------------------- JSON
@pytest.mark.parametrize(
    "K",
    [
        [[450.5, 0, 300.25], [0, 451.5, 200.75], [0, 0, 1]],
        [450.5, 0, 300.25, 0, 451.5, 200.75, 0, 0, 1],
        {"rows": 3, "cols": 3, "data": [450.5, 0, 300.25, 0, 451.5, 200.75, 0, 0, 1]},
    ],
    ids=["nested", "flat", "ros-style"],
)
def test_simple_json(tmp_path, K):
    document = {"K": K, "D": [0.05, -0.01, 0.0, 0.0, 0.002], "width": 600, "height": 400}
    camera = load_calibration(_write(tmp_path, "cam.json", json.dumps(document)))
    expected = CameraIntrinsics(450.5, 451.5, 300.25, 200.75, 600, 400, "plumb_bob", (0.05, -0.01, 0.0, 0.0, 0.002))
    assert camera == expected


def test_json_without_distortion_and_yaml_extension(tmp_path):
    document = {"camera_matrix": [500, 0, 320, 0, 500, 240, 0, 0, 1], "image_width": 640, "image_height": 480}
    camera = load_calibration(_write(tmp_path, "cam.yaml", json.dumps(document)))
    assert camera == CameraIntrinsics(500.0, 500.0, 320.0, 240.0, 640, 480)


def test_four_coefficients_are_padded_to_plumb_bob(tmp_path):
    document = {"K": [500, 0, 320, 0, 500, 240, 0, 0, 1], "D": [0.1, 0.2, 0.003, 0.004], "width": 640, "height": 480}
    camera = load_calibration(_write(tmp_path, "cam.json", json.dumps(document)))
    assert camera.distortion_model == "plumb_bob" and camera.distortion == (0.1, 0.2, 0.003, 0.004, 0.0)


# ----------------------------------------------------------------------------- bad files
GOOD = {"image_width": 640, "image_height": 480,
        "camera_matrix": {"rows": 3, "cols": 3, "data": [500, 0, 320, 0, 500, 240, 0, 0, 1]}}


def _yaml_with(**changes):
    import yaml

    document = json.loads(json.dumps(GOOD))
    for key, value in changes.items():
        if value is None:
            document.pop(key, None)
        else:
            document[key] = value
    return yaml.safe_dump(document)


def _matrix(data, rows=3, cols=3):
    return {"rows": rows, "cols": cols, "data": data}


BAD_FILES = {
    "garbage": (b"\x89\xff\x00\x13binary junk\x00\xfe" * 20, "not UTF-8"),
    "nul": (b"camera_matrix: \x00\x00", "NUL"),
    "empty": (b"", "empty"),
    "whitespace": (b"  \n\n ", "empty"),
    "malformed_yaml": ("camera_matrix: [1, 2\nimage_width: 3\n", "malformed YAML"),
    "malformed_json": ('{"K": [1, 2, 3], "width": }', "malformed JSON"),
    "list_document": ("- 1\n- 2\n", "expected a mapping"),
    "no_camera_matrix": (_yaml_with(camera_matrix=None), "no camera_matrix"),
    "eight_numbers": (_yaml_with(camera_matrix=_matrix([500, 0, 320, 0, 500, 240, 0, 0], rows=2, cols=4)),
                      "camera_matrix has 8 numbers, expected 9"),
    "rows_cols_mismatch": (_yaml_with(camera_matrix=_matrix([500, 0, 320, 0, 500, 240, 0, 0, 1], 3, 4)),
                           "declares 3x4"),
    "negative_focal": (_yaml_with(camera_matrix=_matrix([-500, 0, 320, 0, 500, 240, 0, 0, 1])), "positive"),
    "zero_focal": (_yaml_with(camera_matrix=_matrix([500, 0, 320, 0, 0, 240, 0, 0, 1])), "positive"),
    "nan": (_yaml_with().replace("- 500", "- .nan", 1), "NaN or infinity"),
    "inf_json": ('{"K": [Infinity, 0, 320, 0, 500, 240, 0, 0, 1], "width": 640, "height": 480}', "NaN or infinity"),
    "nan_distortion": ('{"K": [500, 0, 320, 0, 500, 240, 0, 0, 1], "D": [NaN, 0, 0, 0, 0], '
                       '"width": 640, "height": 480}', "NaN or infinity"),
    "skew": (_yaml_with(camera_matrix=_matrix([500, 3, 320, 0, 500, 240, 0, 0, 1])), "skew"),
    "bad_last_row": (_yaml_with(camera_matrix=_matrix([500, 0, 320, 0, 500, 240, 0, 0, 2])),
                     "[fx 0 cx; 0 fy cy; 0 0 1]"),
    "principal_point_outside": (_yaml_with(camera_matrix=_matrix([500, 0, 700, 0, 500, 240, 0, 0, 1])), "outside"),
    "text_in_matrix": (_yaml_with(camera_matrix=_matrix([500, 0, "x", 0, 500, 240, 0, 0, 1])), "must hold numbers"),
    "bool_in_matrix": (_yaml_with(camera_matrix=_matrix([500, 0, True, 0, 500, 240, 0, 0, 1])), "must hold numbers"),
    "no_width": (_yaml_with(image_width=None), "no image_width"),
    "no_height": (_yaml_with(image_height=None), "no image_height"),
    "zero_width": (_yaml_with(image_width=0), "positive"),
    "fractional_height": (_yaml_with(image_height=479.5), "whole number"),
    "huge_width": (_yaml_with(image_width=10**9), "implausibly large"),
    "unsupported_model": (_yaml_with(distortion_model="double_sphere",
                                     distortion_coefficients=_matrix([0.1, 0.2, 0.3, 0.4], 1, 4)),
                          "unsupported distortion"),
    "wrong_coefficient_count": (_yaml_with(distortion_model="plumb_bob",
                                           distortion_coefficients=_matrix([0.1, 0.2, 0.3, 0.4, 0.5, 0.6], 1, 6)),
                                "expected 5"),
    "alias_bomb": ("a: &a [1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1]\n"
                   "b: &b [" + ", ".join(["*a"] * 300) + "]\n"
                   "camera_matrix: [" + ", ".join(["*b"] * 300) + "]\nimage_width: 640\nimage_height: 480\n",
                   "camera_matrix"),
    "huge_integer": (_yaml_with(image_width=10**400), "out of range"),
    "negative_deviation": (_yaml_with(std_deviations_intrinsics=[0.3, 0.3, -0.4, 0.4]), "finite non-negative standard deviations"),
    "three_deviations": (_yaml_with(std_deviations_intrinsics=[0.3, 0.3, 0.4]), "4 to 18"),
    "deep_nesting": ("k: " + "[" * 20000 + "]" * 20000 + "\n", "malformed YAML"),
}


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_bad_calibration_files_name_the_file(tmp_path, case):
    content, expected = BAD_FILES[case]
    path = _write(tmp_path, f"{case}_calib.yaml", content)
    with pytest.raises(CalibrationError) as info:
        load_calibration(path)
    message = str(info.value)
    assert f"{case}_calib.yaml" in message
    assert expected in message
    assert "\n" not in message


def test_the_intrinsics_standard_deviations_are_read_and_recorded_in_a_teach_file(tmp_path):
    """OpenCV's interactive calibration's two parts read as one sigma of (fx, fy, cx, cy,
    *distortion); not part of the camera's identity; a teach file records it
    (``hbvs.calibration``) and gives it back with the camera, which the ROS YAML keeps too."""
    from hbvs_cli.io.mcap import McapWriter
    from hbvs_cli.io.teach_file import TeachReader, TeachWriter

    storage = cv2.FileStorage(str(tmp_path / "interactive.xml"), cv2.FILE_STORAGE_WRITE)
    storage.write("cameraResolution", np.array([640, 480]))
    storage.write("cameraMatrix", PLUMB_BOB.K)
    storage.write("cameraMatrix_std_dev", np.array([[1.5], [1.25], [0.75], [0.5]]))
    storage.write("dist_coeffs", np.array([PLUMB_BOB.distortion]))
    storage.write("dist_coeffs_std_dev", np.array([[0.01], [0.02], [0.0], [0.0], [0.05]]))
    storage.release()
    camera = load_calibration(tmp_path / "interactive.xml", image_size=(640, 480))
    assert camera == PLUMB_BOB and camera.sigma == (1.5, 1.25, 0.75, 0.5, 0.01, 0.02, 0.0, 0.0, 0.05)
    assert load_calibration(save_calibration_ros(camera, tmp_path / "ros.yaml")).sigma == camera.sigma
    with open(tmp_path / "teach.mcap", "wb") as stream:
        writer = McapWriter(stream)
        teach = TeachWriter(writer, "video", {})
        teach.calibration(camera)
        teach.frame(0, cv2.imencode(".png", np.zeros((480, 640), np.uint8))[1].tobytes(), "png")
        writer.finish()
    reader = TeachReader(str(tmp_path / "teach.mcap"))
    assert len(list(reader.frames())) == 1 and reader.camera.sigma == camera.sigma


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(CalibrationError, match=r"nothere\.yaml: no such file"):
        load_calibration(tmp_path / "nothere.yaml")
    folder = tmp_path / "calib_dir"
    folder.mkdir()
    with pytest.raises(CalibrationError, match=r"calib_dir: is a directory"):
        load_calibration(folder)


def test_file_over_one_mebibyte_is_refused_unread(tmp_path, monkeypatch):
    path = tmp_path / "big.yaml"
    path.write_bytes(b"# " + b"x" * MAX_CALIBRATION_BYTES + b"\n" + ROS_CALIBRATOR_YAML.encode())

    def no_parsing(*args, **kwargs):  # the content must never reach a parser
        raise AssertionError("parsed an oversized file")

    monkeypatch.setattr("yaml.safe_load_all", no_parsing)
    with pytest.raises(CalibrationError, match=r"big\.yaml: .*too large"):
        load_calibration(path)


def test_just_under_the_cap_is_accepted(tmp_path):
    text = ROS_CALIBRATOR_YAML
    padding = MAX_CALIBRATION_BYTES - len(text.encode()) - 1
    path = _write(tmp_path, "padded.yaml", "#" + " " * (padding - 1) + "\n" + text)
    assert path.stat().st_size == MAX_CALIBRATION_BYTES
    assert load_calibration(path).fx == 430.21555


def test_errors_are_input_errors_with_exit_code_3(tmp_path):
    with pytest.raises(InputError) as info:
        load_calibration(tmp_path / "missing.json")
    assert info.value.exit_code == 3


# ----------------------------------------------------------------------------- Foxglove
def test_foxglove_message_fields():
    msg = calibration_to_foxglove(PLUMB_BOB, "camera", 12_345_678_901)
    assert (msg.timestamp.seconds, msg.timestamp.nanos) == (12, 345_678_901)
    assert msg.frame_id == "camera"
    assert (msg.width, msg.height) == (640, 480)
    assert msg.distortion_model == "plumb_bob"
    assert list(msg.D) == list(PLUMB_BOB.distortion)
    assert list(msg.K) == [612.4375, 0.0, 318.25, 0.0, 611.9921875, 241.5, 0.0, 0.0, 1.0]
    assert list(msg.R) == [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    assert list(msg.P) == [612.4375, 0.0, 318.25, 0.0, 0.0, 611.9921875, 241.5, 0.0, 0.0, 0.0, 1.0, 0.0]


def _through_bytes(msg):
    return type(msg).FromString(msg.SerializeToString())


@pytest.mark.parametrize("camera", [PLUMB_BOB, RATIONAL, DEFAULT_CAMERA], ids=["plumb_bob", "rational", "none"])
def test_foxglove_round_trip_through_protobuf(camera):
    assert calibration_from_foxglove(_through_bytes(calibration_to_foxglove(camera, "cam", 0))) == camera


@pytest.mark.parametrize(
    "change, expected",
    [
        ({"K": [500.0] * 8}, "K has 8 numbers"),
        ({"height": 0}, "positive"),
        ({"distortion_model": "double_sphere", "D": [0.1, 0.2, 0.3, 0.4]}, "unsupported distortion"),
        ({"K": [500.0, 0, 320, 0, float("nan"), 240, 0, 0, 1]}, "NaN or infinity"),
    ],
)
def test_foxglove_malformed_messages(change, expected):
    msg = calibration_to_foxglove(DEFAULT_CAMERA, "cam", 0)
    for key, value in change.items():
        if isinstance(value, list):
            del getattr(msg, key)[:]
            getattr(msg, key).extend(value)
        else:
            setattr(msg, key, value)
    with pytest.raises(InputError, match=expected):
        calibration_from_foxglove(msg, source="run.mcap /camera/calibration")


def test_foxglove_negative_timestamp():
    with pytest.raises(InputError, match="negative"):
        calibration_to_foxglove(DEFAULT_CAMERA, "cam", -1)


def test_intrinsics_from_values_accepts_arrays():
    camera = intrinsics_from_values(np.array([400.0, 0, 200, 0, 400, 150, 0, 0, 1]), 400, 300, "plumb_bob",
                                    np.zeros(5), "bag /cam/camera_info")
    assert camera == CameraIntrinsics(400.0, 400.0, 200.0, 150.0, 400, 300)
    with pytest.raises(CalibrationError, match="bag /cam/camera_info: K has 4 numbers"):
        intrinsics_from_values([1, 2, 3, 4], 400, 300, None, [], "bag /cam/camera_info")


_positive = st.floats(min_value=1.0, max_value=5000.0, allow_nan=False, allow_infinity=False)
_coefficient = st.floats(min_value=-2.0, max_value=2.0, allow_nan=False, allow_infinity=False)


@settings(max_examples=60, derandomize=True, deadline=None)
@given(
    fx=_positive,
    fy=_positive,
    u=st.floats(0.0, 1.0),
    v=st.floats(0.0, 1.0),
    width=st.integers(1, 8192),
    height=st.integers(1, 8192),
    distortion=st.one_of(
        st.just(()),
        st.tuples(*[_coefficient] * 5).filter(any),
        st.tuples(*[_coefficient] * 8).filter(lambda d: any(d[5:])),
    ),
)
def test_random_cameras_round_trip_exactly(tmp_path_factory, fx, fy, u, v, width, height, distortion):
    model = {0: "none", 5: "plumb_bob", 8: "rational_polynomial"}[len(distortion)]
    camera = CameraIntrinsics(fx, fy, u * width, v * height, width, height, model, tuple(distortion))
    path = save_calibration_ros(camera, tmp_path_factory.mktemp("rt") / "c.yaml")
    assert load_calibration(path) == camera
    assert calibration_from_foxglove(_through_bytes(calibration_to_foxglove(camera, "c", 1))) == camera
