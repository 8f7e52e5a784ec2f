"""ROS 2 bags as users record them (issue 14, input side), written with the independent
``rosbags`` writer in each layout: ``teach --bag`` then ``fit`` gives the same desired
trajectory whatever the storage, compression, split or raw encoding, and the bag's
``/cmd_vel`` gives d* from (25) within 2 % of the truth.

The drive is hbvs's simulated s-curve (so the truth is known); the bag is written by
rosbags, read by rosbags' AnyReader, and every image goes through the bag as a ROS
message in the layout under test.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

from conftest import call_hbvs, errors_against_drive, make_fit, make_teach, rendered_s_curve
from test_io_sources import TYPES, CameraInfo, CompressedImage, Header, Image, RegionOfInterest, Time

from hbvs_cli.core.camera import DEFAULT_CAMERA
from hbvs_cli.io.fit_file import read_fit_file
from hbvs_cli.io.sources import BagSource
from hbvs_cli.io.teach_file import TeachReader

Twist = TYPES.types["geometry_msgs/msg/Twist"]
TwistStamped = TYPES.types["geometry_msgs/msg/TwistStamped"]
Vector3 = TYPES.types["geometry_msgs/msg/Vector3"]
Odometry = TYPES.types["nav_msgs/msg/Odometry"]

#: 6 s of the s-curve at 30 fps: d* from (25) within 0.07 % (measured), and lean enough for the suite.
FRAMES = 180
STAMP0 = 1_700_000_000_000_000_000
PERIOD_NS = 33_333_333
FRAME_ID = "front_camera_optical"


def _header(ns: int) -> object:
    return Header(stamp=Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000), frame_id=FRAME_ID)


def _camera_info(ns: int, model: str = "plumb_bob", d=(0.0,) * 5) -> object:
    camera = DEFAULT_CAMERA
    return CameraInfo(
        header=_header(ns), height=camera.height, width=camera.width, distortion_model=model, d=np.array(d, float),
        k=camera.K.ravel(), r=np.eye(3).ravel(),
        p=np.array([camera.fx, 0, camera.cx, 0, 0, camera.fy, camera.cy, 0, 0, 0, 1, 0], float),
        binning_x=0, binning_y=0, roi=RegionOfInterest(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
    )


def _raw_image(gray: np.ndarray, encoding: str, ns: int) -> object:
    """``gray`` in a raw encoding whose conversion back to gray is exact (bayer aside)."""
    height, width = gray.shape
    if encoding == "mono8":
        data = gray
    elif encoding == "mono16":
        data = (gray.astype(np.uint16) * 257).astype("<u2").view(np.uint8)
    elif encoding in ("bgra8", "rgba8"):
        data = np.dstack([gray, gray, gray, np.full_like(gray, 255)])
    elif encoding in ("yuv422", "yuv422_yuy2"):
        chroma = np.full_like(gray, 128)
        pair = (chroma, gray) if encoding == "yuv422" else (gray, chroma)  # UYVY / YUYV
        data = np.dstack(pair)
    elif encoding.startswith("bayer_"):
        data = gray  # a gray scene seen through a colour filter array of equal gains
    else:
        raise ValueError(encoding)
    data = np.ascontiguousarray(data).reshape(height, -1)
    step = data.shape[1] + 8  # padded rows, as some drivers send them
    padded = np.zeros((height, step), np.uint8)
    padded[:, : data.shape[1]] = data
    return Image(header=_header(ns), height=height, width=width, encoding=encoding, is_bigendian=0,
                 step=step, data=padded.reshape(-1))


@pytest.fixture(scope="module")
def drive():
    world, profile, start, times, images = rendered_s_curve(seed=4, frames=FRAMES)
    frames = list(images)
    v, w = profile.commands_at(times)
    return world, profile, start, times, frames, np.column_stack([v, w])


def write_bag(path: Path, drive, *, storage=StoragePlugin.MCAP, encoding="png", commands="twist",
              compression: CompressionMode | None = None, frames: slice = slice(None), version: int = 8) -> Path:
    """A bag of the drive: images (PNG CompressedImage or a raw encoding), one CameraInfo,
    and the operator's commands (Twist on /cmd_vel, TwistStamped, Odometry or none)."""
    _, _, _, times, images, velocity = drive
    writer = Writer(path, version=version, storage_plugin=storage)
    if compression is not None:
        writer.set_compression(compression, CompressionFormat.ZSTD)
    with writer:
        image_type = CompressedImage if encoding == "png" else Image
        image_topic = "/front/image/compressed" if encoding == "png" else "/front/image_raw"
        image = writer.add_connection(image_topic, image_type.__msgtype__, typestore=TYPES)
        info = writer.add_connection("/front/camera_info", CameraInfo.__msgtype__, typestore=TYPES)
        command_types = {"twist": ("/cmd_vel", Twist), "stamped": ("/cmd_vel", TwistStamped), "odometry": ("/odom", Odometry)}
        command = None
        if commands in command_types:
            topic, kind = command_types[commands]
            command = (writer.add_connection(topic, kind.__msgtype__, typestore=TYPES), kind)
        for k in range(len(times))[frames]:
            ns = STAMP0 + k * PERIOD_NS
            log_ns = ns + 2_000_000  # received 2 ms after the stamp
            if k == (frames.start or 0):  # one CameraInfo per storage file
                writer.write(info, log_ns, TYPES.serialize_cdr(_camera_info(ns), CameraInfo.__msgtype__))
            if command is not None:
                twist = TYPES.types["geometry_msgs/msg/Twist"](
                    linear=Vector3(x=float(velocity[k, 0]), y=0.0, z=0.0), angular=Vector3(x=0.0, y=0.0, z=float(velocity[k, 1])))
                connection, kind = command
                if kind is Twist:
                    message = twist
                elif kind is TwistStamped:
                    message = TwistStamped(header=_header(ns), twist=twist)
                else:
                    message = _odometry(ns, twist)
                writer.write(connection, log_ns - 1_000_000, TYPES.serialize_cdr(message, kind.__msgtype__))
            if encoding == "png":
                data = cv2.imencode(".png", images[k])[1].ravel()
                message = CompressedImage(header=_header(ns), format="png", data=data)
            else:
                message = _raw_image(images[k], encoding, ns)
            writer.write(image, log_ns, TYPES.serialize_cdr(message, image_type.__msgtype__))
    return path


def _odometry(ns: int, twist) -> object:
    names = TYPES.types
    pose = names["geometry_msgs/msg/PoseWithCovariance"](
        pose=names["geometry_msgs/msg/Pose"](position=names["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0),
                                             orientation=names["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)),
        covariance=np.zeros(36))
    return Odometry(header=_header(ns), child_frame_id="base_link", pose=pose,
                    twist=names["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)))


def write_split_bag(path: Path, drive, **options) -> Path:
    """Two storage files listed in one metadata.yaml, as ``ros2 bag record --max-bag-duration`` writes."""
    half = FRAMES // 2
    first = write_bag(path, drive, frames=slice(0, half), **options)
    second = write_bag(path.parent / (path.name + "_part"), drive, frames=slice(half, None), **options)
    meta_first = yaml.safe_load((first / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    meta_second = yaml.safe_load((second / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    (old,) = meta_second["relative_file_paths"]
    new = f"{first.name}_1{Path(old).suffix}"
    shutil.move(second / old, first / new)
    meta_first["relative_file_paths"].append(new)
    meta_first["files"].append({**meta_second["files"][0], "path": new})
    meta_first["message_count"] += meta_second["message_count"]
    counts = {t["topic_metadata"]["name"]: t["message_count"] for t in meta_second["topics_with_message_count"]}
    for topic in meta_first["topics_with_message_count"]:
        topic["message_count"] += counts[topic["topic_metadata"]["name"]]
    end = meta_second["starting_time"]["nanoseconds_since_epoch"] + meta_second["duration"]["nanoseconds"]
    meta_first["duration"]["nanoseconds"] = end - meta_first["starting_time"]["nanoseconds_since_epoch"]
    (first / "metadata.yaml").write_text(yaml.safe_dump({"rosbag2_bagfile_information": meta_first}, sort_keys=False))
    shutil.rmtree(second)
    return first


def teach_and_fit(bag: Path, folder: Path, **teach_options):
    teach = make_teach(folder / f"{bag.name}.teach.mcap", bag=bag, **teach_options)
    fit = folder / f"{bag.name}.fit.mcap"
    make_fit(teach, fit)
    return teach, read_fit_file(fit).model


@pytest.fixture(scope="module")
def reference(drive, tmp_path_factory):
    """The MCAP-storage bag with PNG images and /cmd_vel, taught and fitted."""
    folder = tmp_path_factory.mktemp("reference")
    bag = write_bag(folder / "mcap_png", drive)
    teach, model = teach_and_fit(bag, folder)
    return bag, teach, model


def _same_trajectory(model, other, times, tolerance):
    ours, theirs = model.trajectory.evaluate(times), other.trajectory.evaluate(times)
    for name in ("theta_d", "x_hd1", "x_hd2"):
        assert np.max(np.abs(getattr(ours, name) - getattr(theirs, name))) <= tolerance, name
    assert abs(model.dhat0 - other.dhat0) <= tolerance


def test_cmd_vel_gives_d_star_within_two_percent_and_keeps_stamps(drive, reference):
    world, profile, start, times, _, velocity = drive
    bag, teach, model = reference
    errors = errors_against_drive(model, world, profile, start, times)
    assert model.dhat0_source == "commands"
    assert abs(model.dhat0 - errors["d_star"]) < 0.02 * errors["d_star"]
    reader = TeachReader(teach)
    frames = list(reader.frames())
    # The teach file keeps the bag's clock and frame_id, and the taught (v, w) of each frame.
    assert frames[0].log_time_ns == STAMP0 and frames[-1].log_time_ns == STAMP0 + (FRAMES - 1) * PERIOD_NS
    np.testing.assert_allclose([f.command for f in frames], velocity, atol=1e-12)
    source = reader.info["settings"]["source"]
    assert source["time_base_ns"] == STAMP0 and source["frame_id"] == FRAME_ID
    assert source["cmd_topic"] == "/cmd_vel" and source["cmd_type"] == "geometry_msgs/msg/Twist"


LAYOUTS = {
    "sqlite": {"storage": StoragePlugin.SQLITE3},
    "split-mcap": {},
    "file-compressed": {"compression": CompressionMode.FILE},
    "message-compressed-sqlite": {"storage": StoragePlugin.SQLITE3, "compression": CompressionMode.MESSAGE},
}


def _teach_frames(path):
    return [(f.log_time_ns, f.image_message, f.command) for f in TeachReader(path).frames()]


@pytest.mark.parametrize("layout", sorted(LAYOUTS))
def test_every_storage_layout_gives_the_same_teach_frames(drive, reference, tmp_path, layout):
    """What fit reads (stamps, image bytes, commands) is the same to the byte whatever the
    storage; fit is deterministic, and runs here on the most different layout (a
    message-compressed SQLite bag), whose desired trajectory is the MCAP bag's."""
    writer = write_split_bag if layout == "split-mcap" else write_bag
    bag = writer(tmp_path / layout.replace("-", "_"), drive, **LAYOUTS[layout])
    teach = make_teach(tmp_path / "teach.mcap", bag=bag)
    reader = TeachReader(teach)
    assert [(f.log_time_ns, f.image_message, f.command) for f in reader.frames()] == _teach_frames(reference[1])
    storage = reader.info["settings"]["source"]["storage"]
    expected = {"sqlite": ("sqlite3", 1, "none"), "split-mcap": ("mcap", 2, "none"),
                "file-compressed": ("mcap", 1, "file zstd"), "message-compressed-sqlite": ("sqlite3", 1, "message zstd")}
    assert (storage["storage"], storage["files"], storage["compression"]) == expected[layout]
    if layout == "message-compressed-sqlite":
        make_fit(teach, tmp_path / "fit.mcap")
        _same_trajectory(reference[2], read_fit_file(tmp_path / "fit.mcap").model, drive[3], 1e-9)


@pytest.mark.parametrize("encoding", ["mono8", "mono16", "bgra8", "rgba8", "yuv422", "yuv422_yuy2"])
def test_lossless_raw_encodings_give_the_same_frames(drive, tmp_path, encoding):
    """Each raw encoding decodes to the very pixels of the PNG bag, so teach and fit agree
    to the bit: the frames are compared here, the fit once in the next test."""
    bag = write_bag(tmp_path / encoding, drive, encoding=encoding, frames=slice(0, 6))
    source = BagSource(bag)
    frames = list(source)
    assert len(frames) == 6
    for k, frame in enumerate(frames):
        np.testing.assert_array_equal(frame.image, drive[4][k])
        assert frame.stamp_ns == STAMP0 + k * PERIOD_NS


def test_a_raw_bag_fits_as_the_png_bag_and_bayer_close_to_it(drive, reference, tmp_path):
    # Raw frames have no bytes to keep: stored as PNG (lossless), as the PNG bag's are.
    _, model = teach_and_fit(write_bag(tmp_path / "bgra8", drive, encoding="bgra8"), tmp_path, image_format="png")
    _same_trajectory(reference[2], model, drive[3], 1e-9)
    bayer = BagSource(write_bag(tmp_path / "bayer", drive, encoding="bayer_rggb8", frames=slice(0, 2)))
    image = next(iter(bayer)).image
    # A Bayer camera is a colour camera: its frames are kept in colour (demosaicing a
    # flat-gain mosaic leaves colour fringes at edges). Their luminance blurs edges by a
    # pixel: close to the scene, not equal.
    assert image.shape == (*drive[4][0].shape, 3)
    assert np.mean(np.abs(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY).astype(float) - drive[4][0])) < 3.0


@pytest.mark.parametrize("commands", ["stamped", "odometry"])
def test_twist_stamped_and_odometry_give_the_same_commands(drive, tmp_path, commands):
    bag = write_bag(tmp_path / commands, drive, commands=commands, frames=slice(0, 30))
    source = BagSource(bag)
    assert source.cmd_topic == ("/odom" if commands == "odometry" else "/cmd_vel")
    np.testing.assert_allclose([f.command for f in source], drive[5][:30], atol=1e-12)


def test_refusals_exit_with_the_right_code_and_one_line(drive, tmp_path):
    """In this process (call_hbvs): the same parsing, stages and mapping of errors to one line."""
    two = tmp_path / "two_topics"
    with Writer(two, version=8, storage_plugin=StoragePlugin.MCAP) as writer:
        for topic in ("/left/image/compressed", "/right/image/compressed"):
            connection = writer.add_connection(topic, CompressedImage.__msgtype__, typestore=TYPES)
            data = cv2.imencode(".png", drive[4][0])[1].ravel()
            writer.write(connection, STAMP0, TYPES.serialize_cdr(
                CompressedImage(header=_header(STAMP0), format="png", data=data), CompressedImage.__msgtype__))
    fisheye_unknown = tmp_path / "unknown_model"
    with Writer(fisheye_unknown, version=8, storage_plugin=StoragePlugin.MCAP) as writer:
        image = writer.add_connection("/cam/image/compressed", CompressedImage.__msgtype__, typestore=TYPES)
        info = writer.add_connection("/cam/camera_info", CameraInfo.__msgtype__, typestore=TYPES)
        writer.write(info, STAMP0, TYPES.serialize_cdr(_camera_info(STAMP0, "double_sphere", (0.1, 0.2, 0.3, 0.4)),
                                                       CameraInfo.__msgtype__))
        data = cv2.imencode(".png", drive[4][0])[1].ravel()
        writer.write(image, STAMP0, TYPES.serialize_cdr(
            CompressedImage(header=_header(STAMP0), format="png", data=data), CompressedImage.__msgtype__))
    output = tmp_path / "out.mcap"
    cases = [
        (["--bag", str(two)], 2, ["several image topics", "/left/image/compressed", "/right/image/compressed", "--topic"]),
        (["--bag", str(fisheye_unknown)], 2, ["--calibration", "unsupported distortion model 'double_sphere'"]),
        (["--bag", str(two), "--topic", "/left/image/compressed", "--cmd-topic", "/cmd_vel"], 3, ["no topic '/cmd_vel'"]),
        (["--sim", "--cmd-topic", "/cmd_vel"], 2, ["--cmd-topic goes with --bag"]),
    ]
    for args, code, words in cases:
        result = call_hbvs("teach", *args, "-o", str(output))
        lines = result.stderr.decode().strip().splitlines()
        assert result.returncode == code, (args, result.stderr)
        assert len(lines) == 1 and lines[0].startswith("hbvs: error:"), (args, lines)
        assert all(word in lines[0] for word in words), (args, lines)
        assert not output.exists()


def test_damaged_bag_folders_are_input_errors_naming_the_bag(drive, tmp_path):
    from hbvs_cli.errors import InputError

    cut = write_bag(tmp_path / "cut", drive, frames=slice(0, 3))
    storage = next(cut.glob("*.mcap"))
    storage.write_bytes(storage.read_bytes()[:2000])
    garbage = write_bag(tmp_path / "garbage", drive, storage=StoragePlugin.SQLITE3, frames=slice(0, 3))
    next(garbage.glob("*.db3")).write_bytes(b"\0" * 4096)
    missing = write_bag(tmp_path / "missing", drive, frames=slice(0, 3))
    next(missing.glob("*.mcap")).unlink()
    for bag in (cut, garbage, missing):
        with pytest.raises(InputError, match=rf"{bag.name}: cannot read the bag \("):
            list(BagSource(bag))


def test_command_topic_choice(drive, tmp_path):
    """Two Twist topics: no guess (exit 2 naming both) until --cmd-topic picks one; a topic
    of another type is refused; Odometry is not used when a Twist topic exists."""
    from hbvs_cli.errors import InputError, UsageError
    from hbvs_cli.io.sources import open_source

    bag = tmp_path / "two_commands"
    with Writer(bag, version=8, storage_plugin=StoragePlugin.MCAP) as writer:
        image = writer.add_connection("/cam/image/compressed", CompressedImage.__msgtype__, typestore=TYPES)
        teleop = writer.add_connection("/teleop/cmd_vel", Twist.__msgtype__, typestore=TYPES)
        nav = writer.add_connection("/nav/cmd_vel", Twist.__msgtype__, typestore=TYPES)
        odom = writer.add_connection("/odom", Odometry.__msgtype__, typestore=TYPES)
        for k in range(3):
            ns = STAMP0 + k * PERIOD_NS
            for connection, speed in ((teleop, 0.1), (nav, 0.2)):
                twist = Twist(linear=Vector3(x=speed * (k + 1), y=0.0, z=0.0), angular=Vector3(x=0.0, y=0.0, z=0.0))
                writer.write(connection, ns, TYPES.serialize_cdr(twist, Twist.__msgtype__))
            writer.write(odom, ns, TYPES.serialize_cdr(_odometry(ns, twist), Odometry.__msgtype__))
            data = cv2.imencode(".png", drive[4][k])[1].ravel()
            writer.write(image, ns + 1, TYPES.serialize_cdr(
                CompressedImage(header=_header(ns), format="png", data=data), CompressedImage.__msgtype__))
    with pytest.raises(UsageError, match="several command topics: /nav/cmd_vel, /teleop/cmd_vel; choose one with --cmd-topic"):
        open_source("bag", bag)
    source = open_source("bag", bag, cmd_topic="/teleop/cmd_vel")
    assert [f.command for f in source] == [(0.1, 0.0), (0.2, 0.0), pytest.approx((0.3, 0.0))]
    with pytest.raises(InputError, match="topic /cam/image/compressed carries sensor_msgs/msg/CompressedImage, not"):
        open_source("bag", bag, cmd_topic="/cam/image/compressed")
