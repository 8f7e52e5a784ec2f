"""Frame sources: video files, image folders, a (fake) live camera and ROS 2 MCAP bags.

The bags are written with the independent ``rosbags`` library, so the reader (built on
mcap-ros2-support) is checked against a second implementation of the format.
"""

from __future__ import annotations

import inspect

import cv2
import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from hbvs_cli.core.camera import CameraIntrinsics
from hbvs_cli.errors import InputError, UsageError
from hbvs_cli.io.sources import (
    BagSource,
    CameraSource,
    ImageFolderSource,
    SourceFrame,
    VideoSource,
)
from hbvs_cli.io.images import as_image8

WIDTH, HEIGHT = 64, 48


def pattern(index: int, width: int = WIDTH, height: int = HEIGHT) -> np.ndarray:
    """A gray frame that identifies ``index``: a level plus a bright square that moves."""
    image = np.full((height, width), 30 + 15 * index, np.uint8)
    x = 4 + 3 * index
    image[10:26, x : x + 16] = 240
    return image


def colour(index: int) -> np.ndarray:
    """A BGR frame whose gray conversion is :func:`pattern` (equal channels)."""
    return cv2.cvtColor(pattern(index), cv2.COLOR_GRAY2BGR)


# ----------------------------------------------------------------------------- video
def _write_video(path, frames, fps=10.0):
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (WIDTH, HEIGHT))
    assert writer.isOpened()
    for frame in frames:
        writer.write(frame)
    writer.release()
    return path


@pytest.fixture
def video(tmp_path):
    return _write_video(tmp_path / "run.avi", [colour(i) for i in range(10)])


def test_video_frames_timestamps_and_content(video):
    source = VideoSource(video)
    assert inspect.isgenerator(iter(source))  # lazy: one frame at a time
    frames = list(source)
    assert len(frames) == 10
    assert [f.t for f in frames] == pytest.approx([i / 10 for i in range(10)], abs=1e-12)
    for i, frame in enumerate(frames):
        assert isinstance(frame, SourceFrame)
        assert frame.image.dtype == np.uint8 and frame.image.shape == (HEIGHT, WIDTH)
        assert frame.encoded is None and frame.format is None
        error = np.abs(frame.image.astype(float) - pattern(i)).mean()
        assert error < 4.0, (i, error)  # MJPEG is lossy, but the frames are in order
    description = source.describe()
    assert description == {
        "kind": "video", "path": str(video), "frame_count": 10, "fps": 10.0,
        "width": WIDTH, "height": HEIGHT, "timestamps": "frame rate",
    }
    assert source.camera is None


def test_video_fps_override(video):
    source = VideoSource(video, fps=4.0)
    assert [f.t for f in source] == pytest.approx([i / 4 for i in range(10)], abs=1e-12)
    assert source.describe()["fps"] == 4.0


def test_video_without_frame_rate_uses_the_container_clock(video):
    source = VideoSource(video)
    source._container_fps = None  # as for a container that declares no usable rate
    assert source.fps is None and source.describe()["timestamps"] == "container clock"
    assert [f.t for f in source] == pytest.approx([i / 10 for i in range(10)], abs=1e-6)


def test_video_errors(tmp_path):
    with pytest.raises(InputError, match=r"missing\.avi: no such file"):
        VideoSource(tmp_path / "missing.avi")
    with pytest.raises(InputError, match="is a directory"):
        VideoSource(tmp_path)
    junk = tmp_path / "junk.avi"
    junk.write_bytes(b"this is not a video at all" * 20)
    with pytest.raises(InputError, match=r"junk\.avi"):
        VideoSource(junk)
    empty = _write_video(tmp_path / "empty.avi", [])
    with pytest.raises(InputError, match=r"no frames could be decoded from .*empty\.avi"):
        VideoSource(empty)


# ----------------------------------------------------------------------------- images
@pytest.fixture
def image_folder(tmp_path):
    folder = tmp_path / "frames"
    folder.mkdir()
    for i, name in [(0, "frame1.png"), (1, "frame2.png"), (2, "frame10.png")]:
        cv2.imwrite(str(folder / name), colour(i))
    cv2.imwrite(str(folder / "frame11.jpg"), colour(3), [cv2.IMWRITE_JPEG_QUALITY, 95])
    cv2.imwrite(str(folder / "frame12.BMP"), pattern(4))
    (folder / "notes.txt").write_text("not an image")
    return folder


def test_image_folder_natural_order_and_encoded_bytes(image_folder):
    source = ImageFolderSource(image_folder, fps=5.0)
    assert [p.name for p in source.files] == ["frame1.png", "frame2.png", "frame10.png", "frame11.jpg", "frame12.BMP"]
    assert inspect.isgenerator(iter(source))
    frames = list(source)
    assert [f.t for f in frames] == pytest.approx([0.0, 0.2, 0.4, 0.6, 0.8], abs=1e-12)
    for i in (0, 1, 2, 4):  # lossless formats: exact
        np.testing.assert_array_equal(frames[i].image, pattern(i))
    assert np.abs(frames[3].image.astype(float) - pattern(3)).mean() < 2.0
    assert [f.format for f in frames] == ["png", "png", "png", "jpeg", None]
    assert frames[2].encoded == (image_folder / "frame10.png").read_bytes()
    assert frames[4].encoded is None
    description = source.describe()
    assert description["kind"] == "images" and description["frame_count"] == 5 and description["fps"] == 5.0


def test_image_glob(image_folder):
    source = ImageFolderSource(str(image_folder / "frame*.png"), fps=2)
    assert [p.name for p in source.files] == ["frame1.png", "frame2.png", "frame10.png"]
    assert [f.t for f in source] == [0.0, 0.5, 1.0]


def test_image_folder_errors(tmp_path, image_folder):
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "readme.md").write_text("no images here")
    with pytest.raises(InputError, match=r"empty: no images"):
        ImageFolderSource(empty, fps=10)
    with pytest.raises(InputError, match="no image files .* match"):
        ImageFolderSource(str(tmp_path / "*.png"), fps=10)
    with pytest.raises(InputError, match="no such folder"):
        ImageFolderSource(tmp_path / "absent", fps=10)


def test_unreadable_image_is_named(tmp_path):
    folder = tmp_path / "broken"
    folder.mkdir()
    cv2.imwrite(str(folder / "a1.png"), pattern(0))
    (folder / "a2.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00" * 40)  # a truncated PNG
    frames = iter(ImageFolderSource(folder, fps=10))
    assert next(frames).t == 0.0
    with pytest.raises(InputError, match=r"a2\.png: cannot be decoded"):
        next(frames)


def test_image_size_change_is_refused(tmp_path):
    folder = tmp_path / "sizes"
    folder.mkdir()
    cv2.imwrite(str(folder / "a1.png"), pattern(0))
    cv2.imwrite(str(folder / "a2.png"), pattern(1, width=32, height=24))
    with pytest.raises(InputError, match=r"a2\.png: image is 32x24 but earlier frames are 64x48"):
        list(ImageFolderSource(folder, fps=10))


def test_to_image8_keeps_colour_and_makes_equal_channels_gray():
    bgr = np.zeros((2, 3, 3), np.uint8)
    bgr[..., 2] = 255  # pure red: kept in colour
    assert np.array_equal(as_image8(bgr, "x"), bgr)
    bgra = np.dstack([bgr, np.full((2, 3), 7, np.uint8)])
    assert np.array_equal(as_image8(bgra, "x"), bgr)  # alpha dropped
    # Three equal channels (a gray video in a colour container) become one gray channel.
    assert as_image8(cv2.merge([pattern(0)] * 3), "x").shape == pattern(0).shape
    assert as_image8(np.full((2, 2), 0xABCD, np.uint16), "x")[0, 0] == 0xAB
    assert np.array_equal(as_image8(np.full((2, 2, 3), (0x1234, 0x5678, 0x9ABC), np.uint16), "x")[0, 0], (0x12, 0x56, 0x9A))
    with pytest.raises(InputError, match="x: unsupported pixel type float32"):
        as_image8(np.zeros((2, 2), np.float32), "x")


# ----------------------------------------------------------------------------- camera
class FakeCapture:
    """Stands in for cv2.VideoCapture: a list of frames (None = a failed read)."""

    def __init__(self, frames, opened=True, fps=30.0):
        self.frames = list(frames)
        self.opened = opened
        self.fps = fps
        self.released = False
        self.reads = 0

    def isOpened(self):
        return self.opened

    def read(self):
        self.reads += 1
        if not self.frames:
            return False, None
        frame = self.frames.pop(0)
        return (frame is not None), frame

    def get(self, prop):
        return {cv2.CAP_PROP_FPS: self.fps, cv2.CAP_PROP_FRAME_WIDTH: WIDTH,
                cv2.CAP_PROP_FRAME_HEIGHT: HEIGHT}.get(prop, 0.0)

    def release(self):
        self.released = True


class FakeClock:
    def __init__(self, start=100.0, step=0.25):
        self.now = start - step
        self.step = step

    def __call__(self):
        self.now += self.step
        return self.now


def test_camera_frames_then_failure():
    capture = FakeCapture([colour(0), colour(1), None, colour(2)])  # one dropped frame, then dead
    source = CameraSource(0, capture_factory=lambda index: capture, clock=FakeClock(), max_failed_reads=2)
    assert source.describe() == {"kind": "camera", "path": None, "device": 0, "frame_count": None, "fps": 30.0,
                                 "duration": None, "width": WIDTH, "height": HEIGHT}
    frames = []
    with pytest.raises(InputError, match="camera 0: stopped delivering frames after 3 frames"):
        for frame in source:
            frames.append(frame)
    assert len(frames) == 3
    # The clock ticks on every read, the dropped frame included.
    assert [f.t for f in frames] == [0.0, 0.25, 0.75]
    for i, frame in enumerate(frames):
        np.testing.assert_array_equal(frame.image, pattern(i))
        assert frame.encoded is None
    assert capture.released


def test_camera_duration_stops_on_the_fake_clock():
    capture = FakeCapture([colour(i % 5) for i in range(100)])
    source = CameraSource(2, duration=1.0, capture_factory=lambda index: capture, clock=FakeClock(step=0.25))
    frames = list(source)
    assert [f.t for f in frames] == [0.0, 0.25, 0.5, 0.75]
    assert capture.reads == 5 and capture.released


def test_camera_released_when_the_consumer_stops():
    capture = FakeCapture([colour(0)] * 10)
    iterator = iter(CameraSource(0, capture_factory=lambda index: capture, clock=FakeClock()))
    next(iterator)
    assert not capture.released
    iterator.close()  # what a `for` loop broken by Ctrl-C ends up doing
    assert capture.released and capture.reads == 1


def test_camera_errors():
    closed = FakeCapture([], opened=False)
    with pytest.raises(InputError, match="camera 3: cannot open the device"):
        CameraSource(3, capture_factory=lambda index: closed)
    assert closed.released
    silent = FakeCapture([])
    with pytest.raises(InputError, match="delivered no frames"):
        list(CameraSource(0, capture_factory=lambda index: silent, clock=FakeClock()))
    with pytest.raises(UsageError):
        CameraSource(0, duration=-2, capture_factory=lambda index: FakeCapture([]))
    held = FakeCapture([])
    with CameraSource(0, capture_factory=lambda index: held):
        pass
    assert held.released


# ----------------------------------------------------------------------------- ROS 2 bags

TYPES = get_typestore(Stores.ROS2_HUMBLE)
Time = TYPES.types["builtin_interfaces/msg/Time"]
Header = TYPES.types["std_msgs/msg/Header"]
CompressedImage = TYPES.types["sensor_msgs/msg/CompressedImage"]
Image = TYPES.types["sensor_msgs/msg/Image"]
CameraInfo = TYPES.types["sensor_msgs/msg/CameraInfo"]
RegionOfInterest = TYPES.types["sensor_msgs/msg/RegionOfInterest"]
String = TYPES.types["std_msgs/msg/String"]

BAG_CAMERA = CameraIntrinsics(fx=80.5, fy=81.25, cx=31.5, cy=23.75, width=WIDTH, height=HEIGHT,
                              distortion_model="plumb_bob", distortion=(-0.25, 0.0625, 0.001, -0.002, 0.0))


def _header(ns: int) -> object:
    return Header(stamp=Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000), frame_id="cam")


def _camera_info(camera: CameraIntrinsics | None, ns: int) -> object:
    """A CameraInfo of ``camera``, or an uncalibrated one (all zeros) for None."""
    k = camera.K.ravel() if camera is not None else np.zeros(9)
    d = np.array(camera.distortion if camera is not None and camera.distortion else [0.0] * 5)
    p = np.zeros(12) if camera is None else np.array(
        [camera.fx, 0, camera.cx, 0, 0, camera.fy, camera.cy, 0, 0, 0, 1, 0], float)
    height, width = (HEIGHT, WIDTH) if camera is None else (camera.height, camera.width)
    return CameraInfo(
        header=_header(ns), height=height, width=width, distortion_model="plumb_bob", d=d, k=k,
        r=np.eye(3).ravel(), p=p, binning_x=0, binning_y=0,
        roi=RegionOfInterest(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
    )


def _raw(index: int, encoding: str) -> object:
    gray = pattern(index)
    if encoding == "mono8":
        data, step = gray, WIDTH
    elif encoding == "mono16":
        data, step = (gray.astype(np.uint16) * 257 + 3).astype("<u2").view(np.uint8), 2 * WIDTH
    elif encoding in ("rgb8", "bgr8"):
        data, step = cv2.cvtColor(gray, cv2.COLOR_GRAY2RGB), 3 * WIDTH
    else:  # an encoding hbvs does not read; the bytes do not matter
        data, step = np.zeros((HEIGHT, 2 * WIDTH), np.uint8), 2 * WIDTH
    return Image(header=_header(0), height=HEIGHT, width=WIDTH, encoding=encoding, is_bigendian=0,
                 step=step, data=np.ascontiguousarray(data).reshape(-1))


def write_bag(path, topics, n_frames=5, stamp0=1_700_000_000_000_000_000, log0=5_000_000_000,
              period_ns=50_000_000, camera_info=BAG_CAMERA, zero_stamps=False):
    """A ROS 2 MCAP bag; ``topics`` maps topic -> "png", "jpeg", a raw encoding or "info"/"string".

    Header stamps and log times are on different clocks (log time runs at twice the
    period) so a test can tell which one the reader used.
    """
    with Writer(path, version=8, storage_plugin=StoragePlugin.MCAP) as writer:
        connections = {}
        for topic, kind in topics.items():
            msgtype = {"info": CameraInfo, "string": String}.get(
                kind, CompressedImage if kind in ("png", "jpeg") else Image).__msgtype__
            connections[topic] = (writer.add_connection(topic, msgtype, typestore=TYPES), msgtype, kind)
        for i in range(n_frames):
            stamp = 0 if zero_stamps else stamp0 + i * period_ns
            log_time = log0 + i * 2 * period_ns
            for topic, (connection, msgtype, kind) in connections.items():
                if kind == "info":
                    message = _camera_info(camera_info, stamp)
                elif kind == "string":
                    message = String(data=f"hello {i}")
                elif kind in ("png", "jpeg"):
                    ok, data = cv2.imencode("." + kind, colour(i))
                    message = CompressedImage(header=_header(stamp), format=kind, data=data.reshape(-1))
                else:
                    message = _raw(i, kind)
                    message.header = _header(stamp)
                writer.write(connection, log_time, TYPES.serialize_cdr(message, msgtype))
    return path


@pytest.fixture
def compressed_bag(tmp_path):
    return write_bag(tmp_path / "compressed_bag", {"/cam/image/compressed": "png", "/cam/camera_info": "info"})


def test_bag_compressed_images_timestamps_and_camera_info(compressed_bag):
    source = BagSource(compressed_bag)
    assert source.topic == "/cam/image/compressed"  # chosen automatically
    assert source.camera == BAG_CAMERA and source.camera_problem is None
    assert inspect.isgenerator(iter(source))
    frames = list(source)
    assert len(frames) == 5
    # header stamps 50 ms apart (the log times are 100 ms apart)
    assert [f.t for f in frames] == pytest.approx([0.0, 0.05, 0.1, 0.15, 0.2], abs=1e-12)
    for i, frame in enumerate(frames):
        np.testing.assert_array_equal(frame.image, pattern(i))
        assert frame.format == "png"
        assert frame.encoded == cv2.imencode(".png", colour(i))[1].tobytes()
    description = source.describe()
    assert description["kind"] == "ros2_bag" and description["topic"] == "/cam/image/compressed"
    assert description["message_type"] == "sensor_msgs/msg/CompressedImage"
    assert description["frame_count"] == 5 and description["camera_info_topic"] == "/cam/camera_info"


def test_bag_mcap_file_and_metadata_paths(compressed_bag):
    mcap_file = next(compressed_bag.glob("*.mcap"))
    for path in (mcap_file, compressed_bag / "metadata.yaml", str(compressed_bag)):
        source = BagSource(path)
        assert source.topic == "/cam/image/compressed"
        assert sum(1 for _ in source) == 5


def test_bag_jpeg_frames(tmp_path):
    source = BagSource(write_bag(tmp_path / "jpeg_bag", {"/front/image/compressed": "jpeg"}, n_frames=3))
    frames = list(source)
    assert [f.format for f in frames] == ["jpeg"] * 3
    assert all(f.encoded.startswith(b"\xff\xd8") for f in frames)
    assert np.abs(frames[2].image.astype(float) - pattern(2)).mean() < 3.0
    assert source.camera is None and source.describe()["camera_info_topic"] is None


@pytest.mark.parametrize("encoding", ["mono8", "rgb8", "bgr8", "mono16"])
def test_bag_raw_images(tmp_path, encoding):
    bag = write_bag(tmp_path / f"raw_{encoding}", {"/cam/image_raw": encoding, "/cam/camera_info": "info"}, n_frames=3)
    source = BagSource(bag)
    assert source.topic == "/cam/image_raw"
    frames = list(source)
    assert [f.t for f in frames] == pytest.approx([0.0, 0.05, 0.1], abs=1e-12)
    for i, frame in enumerate(frames):
        np.testing.assert_array_equal(frame.image, pattern(i))  # mono16 keeps the high byte
        assert frame.encoded is None and frame.format is None
    assert source.camera == BAG_CAMERA


@pytest.mark.parametrize("encoding", ["32FC1", "nonsense"])
def test_bag_unsupported_raw_encoding(tmp_path, encoding):
    bag = write_bag(tmp_path / "float", {"/cam/image_raw": encoding}, n_frames=1)
    with pytest.raises(InputError, match=rf"/cam/image_raw message 0: unsupported image encoding '{encoding}'"):
        list(BagSource(bag))


def test_bag_with_two_image_topics_needs_a_topic(tmp_path):
    bag = write_bag(tmp_path / "two", {"/cam/image_raw": "mono8", "/cam/image/compressed": "png",
                                       "/cam/camera_info": "info"}, n_frames=2)
    with pytest.raises(UsageError) as info:  # a choice the user has to make: exit 2
        BagSource(bag)
    message = str(info.value)
    assert "/cam/image_raw" in message and "/cam/image/compressed" in message and "--topic" in message
    source = BagSource(bag, topic="/cam/image_raw")
    assert [f.format for f in source] == [None, None]
    assert source.camera == BAG_CAMERA
    with pytest.raises(InputError, match="no topic '/nope'"):
        BagSource(bag, topic="/nope")
    with pytest.raises(InputError, match="carries sensor_msgs/msg/CameraInfo"):
        BagSource(bag, topic="/cam/camera_info")


def test_bag_without_image_topic(tmp_path):
    bag = write_bag(tmp_path / "no_images", {"/chatter": "string", "/cam/camera_info": "info"}, n_frames=2)
    with pytest.raises(InputError, match=r"no image topic in .*no_images"):
        BagSource(bag)


def test_bag_camera_info_matching_the_image_namespace(tmp_path):
    other = CameraIntrinsics(fx=99.0, fy=99.0, cx=30.0, cy=20.0, width=WIDTH, height=HEIGHT)
    path = tmp_path / "two_cameras"
    with Writer(path, version=8, storage_plugin=StoragePlugin.MCAP) as writer:
        image = writer.add_connection("/front/image/compressed", CompressedImage.__msgtype__, typestore=TYPES)
        front = writer.add_connection("/front/camera_info", CameraInfo.__msgtype__, typestore=TYPES)
        rear = writer.add_connection("/rear/camera_info", CameraInfo.__msgtype__, typestore=TYPES)
        writer.write(rear, 1, TYPES.serialize_cdr(_camera_info(other, 1), CameraInfo.__msgtype__))
        writer.write(front, 2, TYPES.serialize_cdr(_camera_info(BAG_CAMERA, 2), CameraInfo.__msgtype__))
        png = cv2.imencode(".png", pattern(0))[1].reshape(-1)
        writer.write(image, 3, TYPES.serialize_cdr(CompressedImage(header=_header(3), format="png", data=png),
                                                   CompressedImage.__msgtype__))
    source = BagSource(path)
    assert source.camera_info_topic == "/front/camera_info" and source.camera == BAG_CAMERA


def test_bag_uncalibrated_camera_info_and_zero_stamps(tmp_path):
    bag = write_bag(tmp_path / "uncal", {"/cam/image_raw": "mono8", "/cam/camera_info": "info"},
                    n_frames=3, camera_info=None, zero_stamps=True)
    source = BagSource(bag)
    assert source.camera is None
    assert "all zeros" in source.camera_problem
    # no header stamps: the log times (100 ms apart) are used
    assert [f.t for f in source] == pytest.approx([0.0, 0.1, 0.2], abs=1e-12)


def test_bag_path_errors(tmp_path):
    with pytest.raises(InputError, match="no such file or directory"):
        BagSource(tmp_path / "absent")
    not_mcap = tmp_path / "fake.mcap"
    not_mcap.write_bytes(b"SQLite format 3\x00" + b"\x00" * 100)
    with pytest.raises(InputError, match=r"fake\.mcap: not an MCAP file"):
        BagSource(not_mcap)
    sqlite_bag = tmp_path / "sqlite_bag"
    sqlite_bag.mkdir()
    (sqlite_bag / "sqlite_bag_0.db3").write_bytes(b"SQLite format 3\x00")
    with pytest.raises(InputError, match="SQLite storage.*needs its metadata.yaml"):
        BagSource(sqlite_bag)
    empty = tmp_path / "empty_dir"
    empty.mkdir()
    with pytest.raises(InputError, match=r"no \.mcap file and no metadata.yaml"):
        BagSource(empty)


def test_truncated_bag_is_an_input_error(compressed_bag, tmp_path):
    data = next(compressed_bag.glob("*.mcap")).read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match=r"cut\.mcap: cannot read the bag, the MCAP file is damaged or truncated"):
        list(BagSource(cut))


def test_bag_without_summary_section_is_streamed(compressed_bag, tmp_path):
    """An MCAP whose recorder never wrote the summary (no index, no statistics) still reads."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, IndexType
    from mcap.writer import Writer as McapWriter

    source_file = next(compressed_bag.glob("*.mcap"))
    target = tmp_path / "no_summary.mcap"
    with source_file.open("rb") as stream, target.open("wb") as out:
        reader = make_reader(stream)
        writer = McapWriter(out, compression=CompressionType.ZSTD, index_types=IndexType.NONE,
                            repeat_channels=False, repeat_schemas=False, use_statistics=False,
                            use_summary_offsets=False)
        writer.start(profile="ros2", library="test")
        ids: dict[int, int] = {}
        for schema, channel, message in reader.iter_messages():
            if channel.id not in ids:
                schema_id = writer.register_schema(schema.name, schema.encoding, schema.data)
                ids[channel.id] = writer.register_channel(channel.topic, channel.message_encoding, schema_id)
            writer.add_message(ids[channel.id], message.log_time, message.data, message.publish_time)
        writer.finish()
    with target.open("rb") as stream:
        assert make_reader(stream).get_summary() is None
    source = BagSource(target)
    assert source.topic == "/cam/image/compressed" and source.camera == BAG_CAMERA
    assert source.describe()["frame_count"] == 5
    frames = list(source)
    assert [f.t for f in frames] == pytest.approx([0.0, 0.05, 0.1, 0.15, 0.2], abs=1e-12)
    np.testing.assert_array_equal(frames[4].image, pattern(4))
