"""Files a user can keep: how frames are stored (issue 18), measured in bytes.

Before issue 18 a simulated 20 s teach (600 frames, the default) was 80 916 159 bytes:
3-byte-per-pixel PNG-sized frames, each base64-encoded inside a JSON message. Now frames
are one gray channel (in colour when the source has colour), JPEG at quality 90 when hbvs
compresses them, and the bytes sit in a protobuf ``foxglove.CompressedImage`` as they are.
``python -m bench.file_sizes`` measures the same figures on every source.
"""

from __future__ import annotations

import cv2
import numpy as np

from hbvs_cli.io.images import bytes_to_store, encode_image, is_png8, read_compressed_image
from hbvs_cli.io.teach_file import TeachReader

from conftest import make_teach, rendered_s_curve

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
    assert fmt == "png" and is_png8(data) and not is_png8(colour_png)
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
    # Colour: a colour PNG and a colour JPEG are kept byte for byte, a frame without bytes
    # becomes a colour JPEG; --gray stores one channel, encoding a colour JPEG again.
    red = colour.copy()
    red[50:70, 70:90] = (40, 40, 220)
    red_png = cv2.imencode(".png", red)[1].tobytes()
    red_jpeg = cv2.imencode(".jpg", red)[1].tobytes()
    assert bytes_to_store(red, red_png, "png") == (red_png, "png")
    assert bytes_to_store(red, red_jpeg, "jpeg") == (red_jpeg, "jpeg")
    assert cv2.imdecode(np.frombuffer(bytes_to_store(red)[0], np.uint8), cv2.IMREAD_UNCHANGED).shape == red.shape
    for encoded, fmt in ((red_png, "png"), (red_jpeg, "jpeg"), (None, None)):
        data, _ = bytes_to_store(red, encoded, fmt, gray=True)
        assert cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED).ndim == 2


def test_a_simulated_teach_stores_the_gray_jpeg_it_stored_before(default_teach):
    """Colour changed nothing for gray sources: the default teach's frames are the JPEG of
    the rendered gray frame, encoded as before colour (quality 90, optimised Huffman tables),
    and its metadata has no --gray (the simulator's frames are gray anyway)."""
    _, _, _, _, images = rendered_s_curve(0, frames=3)
    reader = TeachReader(default_teach)
    for frame, image in zip(reader.frames(), images):
        before = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 90, cv2.IMWRITE_JPEG_OPTIMIZE, 1])[1].tobytes()
        assert frame.stored_image().data == before
    assert "gray" not in reader.info["settings"]


def _drive_video(path, colour: bool, frames: int = 6):
    """A small MJPG video of dots on a wall: red dots on grey (colour), or gray dots on gray."""
    rng = np.random.default_rng(5)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (160, 120), True)
    for k in range(frames):
        image = np.full((120, 160, 3), 111, np.uint8)
        for centre in ((40 + k, 40), (120 + k, 45), (80 + k, 90)):
            cv2.circle(image, centre, 8, (60, 60, 230) if colour else (60, 60, 60), -1, cv2.LINE_AA)
        noisy = np.clip(image + rng.normal(0, 2.0, image.shape), 0, 255).astype(np.uint8)
        writer.write(noisy if colour else cv2.cvtColor(cv2.cvtColor(noisy, cv2.COLOR_BGR2GRAY), cv2.COLOR_GRAY2BGR))
    writer.release()
    return path


def test_a_colour_video_is_stored_in_colour_a_gray_one_in_gray(tmp_path):
    from hbvs_cli.core.camera import CameraIntrinsics
    from hbvs_cli.io.calibration import save_calibration_ros

    calibration = tmp_path / "camera.yaml"
    save_calibration_ros(CameraIntrinsics(fx=100.0, fy=100.0, cx=79.5, cy=59.5, width=160, height=120), calibration)
    channels, sizes = {}, {}
    for name, colour, gray in (("colour", True, False), ("gray", False, False), ("forced", True, True)):
        video = _drive_video(tmp_path / f"{name}.avi", colour)
        path = make_teach(tmp_path / f"{name}.mcap", video=video, calibration=calibration, gray=gray)
        reader = TeachReader(path)
        stored = [frame.stored_image() for frame in reader.frames()]
        decoded = [cv2.imdecode(np.frombuffer(s.data, np.uint8), cv2.IMREAD_UNCHANGED) for s in stored]
        channels[name] = {1 if image.ndim == 2 else image.shape[2] for image in decoded}
        sizes[name] = sum(len(s.data) for s in stored)
        assert all(s.format == "jpeg" for s in stored) and len(stored) == 6
        assert reader.info["settings"]["gray"] is gray
    # A gray video in OpenCV's colour MJPG container (channels 2 levels apart) is gray.
    assert channels == {"colour": {3}, "gray": {1}, "forced": {1}}
    assert sizes["forced"] < sizes["colour"]
    print(f"\ncolour video: {sizes['colour']} bytes of JPEG in colour, {sizes['forced']} with --gray")


def test_an_image_folder_of_colour_pngs_is_kept_as_it_is(tmp_path):
    from hbvs_cli.core.camera import CameraIntrinsics
    from hbvs_cli.io.calibration import save_calibration_ros

    folder = tmp_path / "frames"
    folder.mkdir()
    files = []
    for k in range(3):
        image = cv2.merge([noisy_frame(k), noisy_frame(k + 10), noisy_frame(k + 20)])  # colour noise
        files.append(folder / f"f{k}.png")
        cv2.imwrite(str(files[-1]), image)
    calibration = tmp_path / "camera.yaml"
    save_calibration_ros(CameraIntrinsics(fx=100.0, fy=100.0, cx=79.5, cy=59.5, width=160, height=120), calibration)
    path = make_teach(tmp_path / "images.mcap", images=str(folder), calibration=calibration)
    stored = [frame.stored_image().data for frame in TeachReader(path).frames()]
    assert stored == [file.read_bytes() for file in files]


def test_an_image_folder_of_colour_pngs_of_gray_content_is_stored_as_gray(tmp_path):
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
    assert all(is_png8(data) for data in stored)
    assert sum(map(len, stored)) < 0.5 * colour_bytes
    for data, file in zip(stored, files):
        assert np.array_equal(cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED),
                              cv2.imread(str(file), cv2.IMREAD_GRAYSCALE))


def test_protobuf_images_round_trip_their_bytes_and_stamp():
    from hbvs_cli.io.images import compressed_image_message

    data = encode_image(noisy_frame(), "jpeg")
    message = compressed_image_message(1_500_000_123, data, "jpeg").SerializeToString()
    stored = read_compressed_image(message)
    assert (stored.data, stored.format, stored.stamp_ns) == (data, "jpeg", 1_500_000_123)
    assert len(message) - len(data) < 40


def test_teach_bag_reads_foxglove_image_files(tmp_path):
    """``teach --bag`` on an MCAP of foxglove.CompressedImage: hbvs's own teach file, with
    its foxglove.CameraCalibration."""
    source = make_teach(tmp_path / "source.mcap", duration=0.5)
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
