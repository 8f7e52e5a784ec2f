"""Files a user can keep: how frames are stored (issue 18), measured in bytes.

Before issue 18 a simulated 20 s teach (600 frames, the default) was 80 916 159 bytes:
3-byte-per-pixel PNG-sized frames, each base64-encoded inside a JSON message. Now frames
are one gray channel, JPEG at quality 90 when hbvs compresses them, and the bytes sit in a
protobuf ``foxglove.CompressedImage`` as they are. ``python -m bench.file_sizes`` measures
the same figures on every source.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from hbvs_cli.io.images import bytes_to_store, encode_image, is_gray8_png, read_compressed_image
from hbvs_cli.io.mcap import McapStream
from hbvs_cli.io.teach_file import TeachReader

from conftest import SAMPLES, make_teach

#: The default 20 s simulated teach before issue 18 (bytes), measured on commit 72a80c9.
TEACH_BYTES_BEFORE = 80_916_159


def image_bytes(path) -> list[int]:
    return [len(frame.stored_image().data) for frame in TeachReader(path).frames()]


def test_a_default_teach_is_under_a_quarter_of_its_old_size_and_within_1_1x_of_its_images(default_teach):
    size = default_teach.stat().st_size
    images = image_bytes(default_teach)
    assert len(images) == 600
    per_frame, per_image = size / len(images), float(np.mean(images))
    print(f"\ndefault teach: {size} bytes ({size / TEACH_BYTES_BEFORE:.3f} of before), "
          f"{per_frame:.0f} bytes a frame for a {per_image:.0f}-byte JPEG ({per_frame / per_image:.4f}x)")
    # Measured: 16.4 MB (0.203 of before); 27 400 bytes a frame, 1.018x the JPEG.
    assert size <= TEACH_BYTES_BEFORE / 4
    assert per_frame <= 1.1 * per_image


def test_frames_are_one_channel_jpeg_at_the_stated_quality(default_teach):
    reader = TeachReader(default_teach)
    frame = next(reader.frames())
    stored = frame.stored_image()
    image = cv2.imdecode(np.frombuffer(stored.data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert stored.format == "jpeg" and image.ndim == 2 and image.shape == (480, 640)
    assert reader.info["settings"]["jpeg_quality"] == 90
    # Re-encoding the decoded frame at quality 90 gives about the same size: the quality
    # stated in the metadata is the one used.
    again = encode_image(image, "jpeg", 90)
    assert abs(len(again) - len(stored.data)) < 0.05 * len(stored.data)


def test_files_written_before_issue_18_are_still_read():
    """samples/teach.mcap holds its images as base64 JSON, as hbvs wrote them before."""
    stream = McapStream(SAMPLES / "teach.mcap", topics={"/camera/image"})
    first = next(iter(stream))
    assert first.message_encoding == "json"
    frames = list(TeachReader(SAMPLES / "teach.mcap").frames())
    stored = frames[0].stored_image()
    assert frames[0].image_encoding == "json" and stored.format in ("png", "jpeg")
    assert cv2.imdecode(np.frombuffer(stored.data, np.uint8), cv2.IMREAD_GRAYSCALE) is not None


def noisy_frame(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    image = np.full((120, 160), 200.0)
    cv2.circle(image, (80, 60), 20, 40.0, -1)
    return np.clip(image + rng.normal(0, 2.0, image.shape), 0, 255).astype(np.uint8)


def test_what_each_source_stores():
    gray = noisy_frame()
    colour = cv2.merge([gray, gray, gray])
    colour_png = cv2.imencode(".png", colour)[1].tobytes()
    gray_png = cv2.imencode(".png", gray)[1].tobytes()
    jpeg = cv2.imencode(".jpg", colour, [cv2.IMWRITE_JPEG_QUALITY, 80])[1].tobytes()
    # A colour PNG becomes a gray PNG, lossless, about a third of the size.
    data, fmt = bytes_to_store(gray, colour_png, "png")
    assert fmt == "png" and is_gray8_png(data) and not is_gray8_png(colour_png)
    assert np.array_equal(cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED), gray)
    assert len(data) < 0.5 * len(colour_png)
    # A gray PNG and any JPEG are kept byte for byte.
    assert bytes_to_store(gray, gray_png, "png") == (gray_png, "png")
    assert bytes_to_store(gray, jpeg, "jpeg") == (jpeg, "jpeg")
    # Frames without bytes (simulator, video, camera): JPEG at the quality asked for.
    data, fmt = bytes_to_store(gray, jpeg_quality=75)
    assert fmt == "jpeg" and data == encode_image(gray, "jpeg", 75)
    # --format png: lossless for those too; --format jpeg re-encodes a PNG source.
    assert bytes_to_store(gray, image_format="png")[1] == "png"
    assert bytes_to_store(gray, gray_png, "png", image_format="jpeg")[1] == "jpeg"


def test_an_image_folder_of_colour_pngs_is_stored_as_gray(tmp_path):
    from hbvs_cli.core.camera import CameraIntrinsics
    from hbvs_cli.io.calibration import save_calibration_ros

    folder = tmp_path / "frames"
    folder.mkdir()
    files = []
    for k in range(5):
        gray = noisy_frame(k)
        files.append(folder / f"f{k}.png")
        cv2.imwrite(str(files[-1]), cv2.merge([gray, gray, gray]))
    calibration = tmp_path / "camera.yaml"
    save_calibration_ros(CameraIntrinsics(fx=100.0, fy=100.0, cx=79.5, cy=59.5, width=160, height=120), calibration)
    path = make_teach(tmp_path / "images.mcap", images=str(folder), calibration=calibration)
    stored = [frame.stored_image().data for frame in TeachReader(path).frames()]
    colour_bytes = sum(f.stat().st_size for f in files)
    assert all(is_gray8_png(data) for data in stored)
    assert sum(map(len, stored)) < 0.5 * colour_bytes
    for data, file in zip(stored, files):
        assert np.array_equal(cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED),
                              cv2.imread(str(file), cv2.IMREAD_GRAYSCALE))


def test_protobuf_images_round_trip_their_bytes_and_stamp():
    from hbvs_cli.io.images import encode_compressed_image

    data = encode_image(noisy_frame(), "jpeg")
    stored = read_compressed_image("protobuf", encode_compressed_image(1_500_000_123, data, "jpeg"))
    assert (stored.data, stored.format, stored.stamp_ns) == (data, "jpeg", 1_500_000_123)
    assert len(encode_compressed_image(1_500_000_123, data, "jpeg")) - len(data) < 40


@pytest.mark.parametrize("encoding", ["protobuf", "json"])
def test_teach_bag_reads_foxglove_image_files(tmp_path, encoding):
    """``teach --bag`` on an MCAP of foxglove.CompressedImage: hbvs's own teach file
    (protobuf) or an older one / another tool's (JSON), with its foxglove.CameraCalibration."""
    source = make_teach(tmp_path / "source.mcap", duration=0.5) if encoding == "protobuf" else SAMPLES / "teach.mcap"
    again = make_teach(tmp_path / "again.mcap", bag=source)
    original = TeachReader(source)
    before = [(frame.stored_image().data, frame.t) for frame in original.frames()]
    reader = TeachReader(again)
    after = [(frame.stored_image().data, frame.t) for frame in reader.frames()]
    assert [data for data, _ in after] == [data for data, _ in before]  # the same bytes, not re-encoded
    assert np.allclose([t for _, t in after], [t for _, t in before], atol=1e-6)
    assert reader.camera == original.camera
    assert reader.info["source"] == "bag" and "noise" not in reader.info["settings"]


def test_teach_bag_reads_another_tools_protobuf_foxglove_recording(tmp_path):
    """A recording written by mcap-protobuf-support with Foxglove's protobuf schemas (as the
    Foxglove SDK writes them): images with their own stamps, and a protobuf CameraCalibration."""
    from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
    from mcap_protobuf.writer import Writer

    recording = tmp_path / "foxglove.mcap"
    jpegs = [cv2.imencode(".jpg", noisy_frame(k), [cv2.IMWRITE_JPEG_QUALITY, 85])[1].tobytes() for k in range(4)]
    with open(recording, "wb") as handle:
        writer = Writer(handle)
        calibration = CameraCalibration(frame_id="cam", width=160, height=120, distortion_model="plumb_bob",
                                         D=[0.0] * 5, K=[100, 0, 79.5, 0, 100, 59.5, 0, 0, 1],
                                         R=[1, 0, 0, 0, 1, 0, 0, 0, 1], P=[100, 0, 79.5, 0, 0, 100, 59.5, 0, 0, 0, 1, 0])
        writer.write_message("/cam/calibration", calibration, log_time=0, publish_time=0)
        for k, jpeg in enumerate(jpegs):
            image = CompressedImage(frame_id="cam", data=jpeg, format="jpeg")
            image.timestamp.FromNanoseconds(5_000_000_000 + k * 50_000_000)  # 20 Hz from t = 5 s
            writer.write_message("/cam/image", image, log_time=k, publish_time=k)
        writer.finish()
    reader = TeachReader(make_teach(tmp_path / "teach.mcap", bag=recording))
    frames = list(reader.frames())
    assert [frame.stored_image().data for frame in frames] == jpegs
    assert np.allclose([frame.t for frame in frames], [0.0, 0.05, 0.1, 0.15])
    assert (reader.camera.fx, reader.camera.cx, reader.camera.width) == (100.0, 79.5, 160)
