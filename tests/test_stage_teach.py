"""``hbvs teach``: every source, the recording's contents, bad input (issue: teach)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import jsonschema
import numpy as np
import pytest
from mcap.reader import make_reader

from hbvs_cli.io.schemas import HBVS_SCHEMAS
from hbvs_cli.io.topics import TOPICS
from hbvs_cli.io.teach_file import TeachReader

from conftest import SAMPLES, call_hbvs, make_teach, run_hbvs


def read_all(path):
    """Every message through the official mcap reader and mcap-protobuf-support's decoder:
    (topic, schema name, schema record, message: a dict for JSON, else the protobuf message)."""
    from mcap_protobuf.decoder import DecoderFactory

    out = []
    factory = DecoderFactory()
    with open(path, "rb") as handle:
        reader = make_reader(handle)
        for schema, channel, message in reader.iter_messages():
            if channel.message_encoding == "json":
                out.append((channel.topic, schema.name, schema, json.loads(message.data)))
            else:
                assert (channel.message_encoding, schema.encoding) == ("protobuf", "protobuf")
                out.append((channel.topic, schema.name, schema, factory.decoder_for(channel.message_encoding, schema)(message.data)))
        metadata = {record.name: record.metadata for record in reader.iter_metadata()}
    return out, metadata


def test_sim_teach_records_images_truth_commands_and_world(default_teach):
    messages, metadata = read_all(default_teach)
    topics = {}
    for topic, schema_name, _, _ in messages:
        topics.setdefault(topic, set()).add(schema_name)
    assert topics == {topic: {schema} for topic, schema in TOPICS["teach"].items()}
    counts = {topic: sum(1 for m in messages if m[0] == topic) for topic in topics}
    # The 3D scene: world -> base_link per frame, base_link -> camera_optical once, the target once.
    assert counts == {"/camera/image": 600, "/ground_truth/pose": 600, "/teach/cmd_vel": 600, "/camera/calibration": 1, "/tf": 601, "/scene": 1}
    assert metadata["hbvs"]["file_kind"] == "teach"
    world = json.loads(metadata["hbvs.world"]["world"])
    assert world["target"]["kind"] == "dots" and len(world["target"]["points_world_m"]) == 3
    settings = json.loads(metadata["hbvs"]["settings"])
    assert settings["seed"] == 0 and settings["path_name"] == "s-curve"
    # Images are one-channel JPEGs (the default, at the stated quality) of the camera's size.
    image_message = next(m[3] for m in messages if m[0] == "/camera/image")
    assert image_message.format == "jpeg" and image_message.frame_id == "camera_optical"
    image = cv2.imdecode(np.frombuffer(image_message.data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert image.shape == (480, 640)
    assert settings["image_format"] == "auto" and settings["jpeg_quality"] == 90


def test_every_message_validates_against_its_schema(default_teach):
    """Each JSON message validates against the hbvs JSON schema stored with it; each
    foxglove.X message is protobuf, its schema the FileDescriptorSet of Foxglove's own class
    for X (foxglove-schemas-protobuf), parsed by that class."""
    import importlib

    from mcap_protobuf.schema import build_file_descriptor_set

    messages, _ = read_all(default_teach)
    validators = {}
    for topic, schema_name, schema, message in messages:
        if schema.encoding == "protobuf":
            name = schema_name.split(".", 1)[1]
            message_class = getattr(importlib.import_module(f"foxglove_schemas_protobuf.{name}_pb2"), name)
            assert schema.data == build_file_descriptor_set(message_class).SerializeToString()
            assert type(message).DESCRIPTOR.full_name == schema_name
            continue
        assert json.loads(schema.data) == HBVS_SCHEMAS[schema_name]
        validator = validators.setdefault(schema_name, jsonschema.Draft202012Validator(HBVS_SCHEMAS[schema_name]))
        validator.validate(message)
    assert {m[1] for m in messages if m[2].encoding == "protobuf"} == {
        "foxglove.CompressedImage", "foxglove.CameraCalibration", "foxglove.PoseInFrame", "foxglove.FrameTransform",
        "foxglove.SceneUpdate",
    }


def test_log_times_are_nanoseconds_at_the_frame_rate(default_teach):
    with open(default_teach, "rb") as handle:
        times = [m.log_time for _, c, m in make_reader(handle).iter_messages() if c.topic == "/camera/image"]
    assert np.allclose(np.diff(times), 1e9 / 30, atol=1)


@pytest.mark.parametrize("kind", ["aruco", "texture"])
def test_other_target_kinds(tmp_path, kind):
    path = make_teach(tmp_path / f"{kind}.mcap", target=kind, duration=1.0)
    reader = TeachReader(path)
    frames = list(reader.frames())
    assert len(frames) == 30 and reader.world_description["target"]["kind"] == kind and all(f.pose is not None for f in frames)


def test_teach_from_a_pendant_csv_and_a_calibration_file(tmp_path):
    csv = tmp_path / "drive.csv"
    csv.write_text("t,v,w\n0,0.1,0.0\n0.5,0.1,0.05\n1.0,0.1,0.0\n")
    calibration = tmp_path / "camera.yaml"
    from hbvs_cli.core.camera import CameraIntrinsics
    from hbvs_cli.io.calibration import save_calibration_ros

    save_calibration_ros(CameraIntrinsics(fx=420.0, fy=420.0, cx=319.5, cy=239.5, width=640, height=480), calibration)
    path = make_teach(tmp_path / "csv.mcap", path=str(csv), calibration=calibration, fps=10.0)
    reader = TeachReader(path)
    frames = list(reader.frames())
    assert len(frames) == 15  # 1.5 s: the last command is held for the median interval
    assert reader.camera.fx == 420.0
    assert [f.command for f in frames[:6]] == [(0.1, 0.0)] * 5 + [(0.1, 0.05)]
    assert frames[-1].pose[0] == pytest.approx(0.1 * 1.4, abs=0.01)


def test_same_seed_same_bytes(tmp_path):
    a = make_teach(tmp_path / "a.mcap", duration=0.5, seed=4)
    b = make_teach(tmp_path / "b.mcap", duration=0.5, seed=4)
    c = make_teach(tmp_path / "c.mcap", duration=0.5, seed=5)
    assert a.read_bytes() == b.read_bytes() != c.read_bytes()


def rendered_frames(count: int = 12):
    """Frames of the default scenario, rendered as a camera would record them."""
    from hbvs_cli.core.path import preset_profile
    from hbvs_cli.sim.world import default_world
    from hbvs_cli.sim.render import make_renderer

    world = default_world()
    profile, start = preset_profile("s-curve", 30)
    renderer = make_renderer(world, 2.0, 0.0, 1.0)
    rng = np.random.default_rng(0)
    return [renderer.render(profile.poses_at(k / 30.0, start), rng) for k in range(count)]


@pytest.fixture(scope="module")
def calibration_file(tmp_path_factory):
    from hbvs_cli.core.camera import DEFAULT_CAMERA
    from hbvs_cli.io.calibration import save_calibration_ros

    path = tmp_path_factory.mktemp("cal") / "camera.yaml"
    save_calibration_ros(DEFAULT_CAMERA, path)
    return path


def test_teach_from_video(tmp_path, calibration_file):
    video = tmp_path / "drive.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (640, 480), isColor=False)
    for frame in rendered_frames():
        writer.write(frame)
    writer.release()
    path = make_teach(tmp_path / "video.mcap", video=video, calibration=calibration_file)
    reader = TeachReader(path)
    frames = list(reader.frames())
    assert len(frames) == 12 and frames[-1].t == pytest.approx(11 / 30, abs=1e-6)
    assert reader.info["source"] == "video" and frames[0].pose is None


def test_teach_from_an_image_folder(tmp_path, calibration_file):
    folder = tmp_path / "frames"
    folder.mkdir()
    for k, frame in enumerate(rendered_frames(11)):
        cv2.imwrite(str(folder / f"frame{k}.png"), frame)  # frame2 must come before frame10
    path = make_teach(tmp_path / "images.mcap", images=str(folder), calibration=calibration_file, fps=10.0)
    frames = list(TeachReader(path).frames())
    assert [round(f.t, 6) for f in frames] == [round(k / 10, 6) for k in range(11)]
    # A gray PNG is stored as it is: the same bytes.
    assert frames[10].stored_image().data == (folder / "frame10.png").read_bytes()


class FakeCapture:
    """A camera that delivers frames, then the user presses Ctrl-C."""

    def __init__(self, frames, interrupt_after):
        self.frames, self.count, self.interrupt_after = frames, 0, interrupt_after

    def isOpened(self):
        return True

    def read(self):
        if self.count == self.interrupt_after:
            raise KeyboardInterrupt
        frame = self.frames[self.count % len(self.frames)]
        self.count += 1
        return True, frame

    def get(self, prop):
        return 30.0

    def set(self, *args):
        return True

    def release(self):
        pass


def test_live_camera_ctrl_c_leaves_a_valid_finished_recording(tmp_path, calibration_file, monkeypatch):
    from hbvs_cli.io import sources
    from hbvs_cli.stages import teach

    frames = rendered_frames(4)
    ticks = iter(np.arange(0, 100, 1 / 30))
    monkeypatch.setattr(
        teach, "_open_source",
        lambda kind, options: sources.CameraSource(0, capture_factory=lambda index: FakeCapture(frames, 7), clock=lambda: next(ticks)),
    )
    path = make_teach(tmp_path / "camera.mcap", camera=0, calibration=calibration_file)
    with open(path, "rb") as handle:
        summary = make_reader(handle).get_summary()
    assert summary is not None  # finished: footer and summary written
    assert len(list(TeachReader(path).frames())) == 7
    assert not list(tmp_path.glob("camera.mcap*.partial"))


def write_bag(directory: Path, frames, *, images=True, camera_info=True, second_topic=False):
    """A ROS 2 bag in MCAP storage written by the independent rosbags library; ``frames``
    are images (stored as PNG) or JPEG bytes (stored as they are)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from test_io_sources import TYPES, CompressedImage, CameraInfo, _camera_info, _header

    from hbvs_cli.core.camera import DEFAULT_CAMERA

    with Writer(directory, version=8, storage_plugin=StoragePlugin.MCAP) as writer:
        topics = (["/cam/image/compressed"] if images else []) + (["/other/image/compressed"] if second_topic else [])
        image_connections = [writer.add_connection(topic, CompressedImage.__msgtype__, typestore=TYPES) for topic in topics]
        info_connection = writer.add_connection("/cam/camera_info", CameraInfo.__msgtype__, typestore=TYPES) if camera_info else None
        for k, frame in enumerate(frames):
            stamp_ns = 1_700_000_000_000_000_000 + k * 33_333_333
            if isinstance(frame, bytes):  # a JPEG already, as a camera driver's compressed topic
                image_format, data = "jpeg", np.frombuffer(frame, np.uint8)
            else:
                # Fastest lossless PNG: the same pixels, a third of the default level's CPU.
                image_format, data = "png", cv2.imencode(".png", frame, [cv2.IMWRITE_PNG_COMPRESSION, 1])[1].ravel()
            for connection in image_connections:
                message = CompressedImage(header=_header(stamp_ns), format=image_format, data=data)
                writer.write(connection, stamp_ns, TYPES.serialize_cdr(message, CompressedImage.__msgtype__))
            if info_connection is not None and k == 0:  # one CameraInfo is enough
                info = _camera_info(DEFAULT_CAMERA, stamp_ns)
                writer.write(info_connection, stamp_ns, TYPES.serialize_cdr(info, CameraInfo.__msgtype__))


def test_teach_from_a_ros2_bag_written_by_rosbags(tmp_path):
    bag = tmp_path / "bag"
    write_bag(bag, rendered_frames(9))
    path = make_teach(tmp_path / "bag.mcap", bag=bag)  # intrinsics from the bag's CameraInfo
    reader = TeachReader(path)
    frames = list(reader.frames())
    assert len(frames) == 9 and reader.camera.fx == 500.0
    assert frames[-1].t == pytest.approx(8 * 0.033333333, abs=1e-6)


def test_bad_input_one_line_nonzero_exit_no_output(tmp_path, calibration_file):
    empty = tmp_path / "empty"
    empty.mkdir()
    one_frame = tmp_path / "one"
    one_frame.mkdir()
    cv2.imwrite(str(one_frame / "f0.png"), rendered_frames(1)[0])
    bad_csv = tmp_path / "bad.csv"
    bad_csv.write_text("time,speed\n0,1\n")
    backwards = tmp_path / "backwards.csv"
    backwards.write_text("t,v,w\n0,0.1,0\n1,0.1,0\n0.5,0.1,0\n")
    garbage_calibration = tmp_path / "cal.yaml"
    garbage_calibration.write_text("camera_matrix: [1, 2]\n")
    no_image_bag = tmp_path / "noimage"
    write_bag(no_image_bag, rendered_frames(2), images=False)
    two_topic_bag = tmp_path / "twotopics"
    write_bag(two_topic_bag, rendered_frames(2), second_topic=True)
    cases = [
        (["--video", str(tmp_path / "missing.avi"), "--calibration", str(calibration_file)], 3),
        (["--images", str(empty), "--calibration", str(calibration_file)], 3),
        (["--images", str(one_frame)], 2),  # no calibration
        (["--bag", str(no_image_bag)], 3),
        (["--bag", str(two_topic_bag)], 2),  # a choice for the user (--topic): a usage problem
        (["--path", "zigzag"], 2),
        (["--path", str(bad_csv)], 3),
        (["--path", str(backwards)], 3),
        (["--calibration", str(garbage_calibration)], 3),
        (["--video", "x.avi", "--images", "y"], 2),
    ]
    output = tmp_path / "out.mcap"
    for k, (args, code) in enumerate(cases):
        # The first case (OpenCV opening a missing video) as a user runs it; the others in
        # this process (the same parsing and error mapping, without a new interpreter each).
        result = (run_hbvs if k == 0 else call_hbvs)("teach", *args, "-o", str(output))
        lines = result.stderr.decode().strip().splitlines()
        assert result.returncode == code, (args, result.stderr)
        assert len(lines) == 1 and lines[0].startswith("hbvs: error:"), (args, lines)
        assert "Traceback" not in result.stderr.decode()
        assert not output.exists() and not list(tmp_path.glob("out.mcap*.partial"))


def test_sample_recording_and_calibration_are_small_and_readable():
    teach = SAMPLES / "teach.mcap"
    assert teach.stat().st_size < 2 * 2**20
    reader = TeachReader(teach)
    frames = list(reader.frames())
    assert len(frames) >= 30 and reader.world_description is not None
    from hbvs_cli.io.calibration import load_calibration

    camera = load_calibration(SAMPLES / "camera.yaml")
    assert (camera.width, camera.height, camera.fx) == (320, 240, 250.0)
    assert reader.camera == camera  # the sample recording was made with the sample calibration


class FakeRos2Topic:
    """What :class:`~hbvs_cli.io.sources.ros2_topic.Ros2TopicSource` yields without a DDS
    network: frames stamped by their headers (1.7e18 ns, the epoch of a real clock), its time
    base known only once the first frame arrives."""

    frame_id = "camera"

    def __init__(self, frames, first_stamp_ns: int) -> None:
        from hbvs_cli.core.camera import DEFAULT_CAMERA

        self.camera = DEFAULT_CAMERA
        self.frames, self.first_stamp_ns = frames, first_stamp_ns
        self.time_base_ns = 0

    def describe(self):
        return {"kind": "ros2", "topic": "/cam/image"}

    def __iter__(self):
        from hbvs_cli.io.sources import SourceFrame

        for k, image in enumerate(self.frames):
            stamp_ns = self.first_stamp_ns + k * 33_333_333
            if k == 0:
                self.time_base_ns = stamp_ns
            yield SourceFrame(t=k * 33_333_333e-9, image=image, stamp_ns=stamp_ns, command=(0.1, 0.0))


def test_a_teach_from_a_ros2_topic_starts_at_its_first_frame_not_in_1970(tmp_path, monkeypatch):
    """The calibration is logged at the first frame's stamp (issue 46: at 0, ``info`` showed a
    start of 1970-01-01 and a duration of 1.8e9 s)."""
    from hbvs_cli.io.file_info import read_file_info
    from hbvs_cli.stages import teach
    from hbvs_cli.stages.info import info_document

    first = 1_700_000_000_000_000_000
    monkeypatch.setattr(teach, "_open_source", lambda kind, options: FakeRos2Topic(rendered_frames(6), first))
    path = make_teach(tmp_path / "ros2.mcap", ros2_image="/cam/image")
    document = info_document(read_file_info(str(path)))
    assert document["start_ns"] == first and document["end_ns"] == first + 5 * 33_333_333
    assert document["duration_s"] == pytest.approx(5 * 0.033333333, abs=1e-9)
    assert document["frames"] == 6


def test_teach_camera_takes_what_repeat_live_camera_takes(tmp_path, monkeypatch):
    """--camera is an index, a device path or a URL, as for repeat --live --camera (before: an
    integer only), and a video file is read as --video."""
    from hbvs_cli.stages import teach
    from hbvs_cli.stages.teach import TeachOptions

    opened = []
    monkeypatch.setattr(teach.sources, "open_source", lambda kind, spec, **_: opened.append((kind, spec)))
    for device in ("0", "2", "/dev/video4", "http://127.0.0.1:8080/stream.mjpg", "rtsp://camera.local/live"):
        teach._open_source("camera", TeachOptions(camera=device))
    video = tmp_path / "drive.avi"
    video.write_bytes(b"x")
    teach._open_source("camera", TeachOptions(camera=str(video)))
    assert opened == [("camera", 0), ("camera", 2), ("camera", "/dev/video4"), ("camera", "http://127.0.0.1:8080/stream.mjpg"),
                      ("camera", "rtsp://camera.local/live"), ("video", str(video))]


def test_sim_teach_writes_practice_footage_and_its_calibration(tmp_path):
    """--video-out: every simulated frame in a video that ``teach --video`` (or ``--camera FILE``)
    reads back frame for frame (within MJPG's loss); --calibration-out: the simulated camera."""
    import cv2

    from hbvs_cli.core.camera import DEFAULT_CAMERA
    from hbvs_cli.io.calibration import load_calibration

    path = make_teach(tmp_path / "practice.mcap", duration=1.0, video_out=tmp_path / "drive.avi",
                      calibration_out=tmp_path / "camera.yaml")
    assert load_calibration(tmp_path / "camera.yaml") == DEFAULT_CAMERA
    stored = [cv2.imdecode(np.frombuffer(frame.stored_image().data, np.uint8), cv2.IMREAD_GRAYSCALE) for frame in TeachReader(path).frames()]
    back = make_teach(tmp_path / "from_video.mcap", camera=str(tmp_path / "drive.avi"), calibration=tmp_path / "camera.yaml")
    again = [cv2.imdecode(np.frombuffer(frame.stored_image().data, np.uint8), cv2.IMREAD_GRAYSCALE) for frame in TeachReader(back).frames()]
    assert len(stored) == len(again) == 30
    differences = [float(np.mean(np.abs(a.astype(float) - b.astype(float)))) for a, b in zip(stored, again)]
    assert max(differences) < 3.0, differences          # gray levels: two lossy encodings, the same frames
    assert not list(tmp_path.glob(".drive.avi.*"))       # the temporary folder is gone
    # Refused before any work: a suffix hbvs does not write, an output that is an input.
    for extra, words in ((["--video-out", str(tmp_path / "drive.gif")], "suffix"),
                         (["--video-out", str(tmp_path / "x.avi"), "--calibration-out", str(tmp_path / "x.avi")], "same file")):
        result = call_hbvs("teach", "--sim", "--duration", "0.2", "-o", str(tmp_path / "t.mcap"), *extra)
        assert result.returncode == 2 and words in result.stderr.decode(), result.stderr.decode()
        assert not (tmp_path / "t.mcap").exists()


@pytest.mark.campaign
def test_teach_records_robot_sims_mjpeg_camera_by_url(tmp_path, request, extent="campaign"):
    """The issue's case end to end (``-m campaign``, ~8 s): ``robot-sim --mjpeg PORT`` serves
    the camera on 127.0.0.1 and ``teach --camera http://127.0.0.1:PORT/`` records it."""
    import os
    import socket
    import subprocess
    import sys
    import time

    from conftest import REPO, campaign_extent

    campaign_extent(request, extent)
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    commands = tmp_path / "commands"
    os.mkfifo(commands)
    hbvs = [sys.executable, "-m", "hbvs_cli"]
    robot = subprocess.Popen([*hbvs, "robot-sim", str(SAMPLES / "fit.mcap"), "--mjpeg", str(port), "--cmd-in", str(commands),
                              "--duration", "60", "-q"], env=dict(os.environ, PYTHONPATH=str(REPO)))
    # The robot's command stream stays open and silent (it stands still); opened without
    # blocking, so that a robot-sim that failed to start fails the test instead of hanging it.
    deadline, writer = time.monotonic() + 60, None
    while writer is None:
        try:
            writer = os.open(commands, os.O_WRONLY | os.O_NONBLOCK)
        except OSError:                                  # ENXIO: robot-sim has not opened it yet
            assert robot.poll() is None and time.monotonic() < deadline, "robot-sim did not start"
            time.sleep(0.1)
    try:
        result = subprocess.run([*hbvs, "teach", "--camera", f"http://127.0.0.1:{port}/", "--duration", "2", "--calibration",
                                 str(SAMPLES / "camera.yaml"), "-o", str(tmp_path / "teach.mcap"), "-q"],
                                capture_output=True, text=True, timeout=120, env=dict(os.environ, PYTHONPATH=str(REPO)))
    finally:
        os.close(writer)
        robot.terminate()
        robot.wait(timeout=30)
    assert result.returncode == 0, result.stderr
    frames = list(TeachReader(str(tmp_path / "teach.mcap")).frames())
    assert len(frames) >= 5 and frames[-1].t < 2.0
