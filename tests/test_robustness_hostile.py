"""Hostile files, one construct at a time: what each reader does with it.

The fuzz campaign (test_robustness_fuzz.py) throws random damage at the readers; these
tests pin down the specific attacks the readers are built to stop, with the error each
one gets. Records are assembled by hand here, so that a file can lie in ways no writer
would produce.
"""

from __future__ import annotations

import io
import json
import struct
import zlib

import numpy as np
import pytest

from hbvs_cli.errors import CalibrationError, InputError, RecordingError
from hbvs_cli.io.mcap import (
    MAX_CHANNELS, MAX_JSON_DEPTH, MAX_JSON_ITEMS, MAX_SCHEMAS, McapStream, decode_json, encode_json, read_metadata,
)

MAGIC = b"\x89MCAP0\r\n"


# ----------------------------------------------------------------------------- MCAP by hand
def record(opcode: int, body: bytes) -> bytes:
    return struct.pack("<BQ", opcode, len(body)) + body


def string(text: str | bytes) -> bytes:
    data = text.encode() if isinstance(text, str) else text
    return struct.pack("<I", len(data)) + data


def string_map(values: dict[str, str]) -> bytes:
    packed = b"".join(string(k) + string(v) for k, v in values.items())
    return struct.pack("<I", len(packed)) + packed


def header() -> bytes:
    return record(0x01, string("") + string("test"))


def schema(schema_id: int, name: str, data: bytes = b"{}") -> bytes:
    return record(0x03, struct.pack("<H", schema_id) + string(name) + string("jsonschema") + string(data))


def channel(channel_id: int, schema_id: int, topic: str, encoding: str = "json") -> bytes:
    return record(0x04, struct.pack("<HH", channel_id, schema_id) + string(topic) + string(encoding) + string_map({}))


def message(channel_id: int, data: bytes, log_time: int = 0) -> bytes:
    return record(0x05, struct.pack("<HIQQ", channel_id, 0, log_time, log_time) + data)


def metadata(name: str, values: dict[str, str]) -> bytes:
    return record(0x0C, string(name) + string_map(values))


def chunk(records: bytes, compression: str = "", declared: int | None = None, crc: int | None = None,
          stored: bytes | None = None, extra_length: int = 0) -> bytes:
    """A chunk record; each argument makes one of its declared lengths or checks lie."""
    payload = records if stored is None else stored
    size = len(records) if declared is None else declared
    body = struct.pack("<QQQI", 0, 0, size, zlib.crc32(records) if crc is None else crc)
    return record(0x06, body + string(compression) + struct.pack("<Q", len(payload) + extra_length) + payload)


def footer() -> bytes:
    return record(0x02, struct.pack("<QQI", 0, 0, 0)) + MAGIC


def mcap(*records: bytes, finished: bool = True) -> io.BytesIO:
    return io.BytesIO(MAGIC + header() + b"".join(records) + (footer() if finished else b""))


VELOCITY = json.dumps({"timestamp": {"sec": 0, "nsec": 0}, "v": 0.1, "w": 0.0}).encode()


def declared_velocity_topic() -> bytes:
    return schema(1, "hbvs.VelocityCommand") + channel(1, 1, "/teach/cmd_vel")


# ----------------------------------------------------------------------------- records
def test_a_field_longer_than_its_record_stops_reading_without_allocating():
    # A metadata map declaring 4 GiB inside a 20-byte record: the mcap library asks the
    # stream for 4 GiB, which the capped input refuses before anything is allocated.
    lying = record(0x0C, string("hbvs") + struct.pack("<I", 2**32 - 1) + b"abcd")
    stream = McapStream(mcap(declared_velocity_topic(), message(1, VELOCITY), lying))
    assert len(list(stream)) == 1 and stream.truncated
    assert "more than any record hbvs accepts" in stream.stop_reason
    with pytest.raises(RecordingError, match="not a readable MCAP file"):
        list(McapStream(mcap(lying)))


def test_a_chunk_whose_lengths_disagree_is_damage_not_an_allocation():
    inner = declared_velocity_topic() + message(1, VELOCITY)
    for bad in (
        chunk(inner, declared=len(inner) + 10),                       # decompresses short
        chunk(inner, crc=zlib.crc32(inner) ^ 1),                      # CRC mismatch
        chunk(inner, extra_length=2**40),                             # records overrun the chunk
        chunk(inner, compression="zstd", stored=b"\x28\xb5\x2f\xfd" + b"\x00" * 20),  # not zstd data
    ):
        stream = McapStream(mcap(declared_velocity_topic(), message(1, VELOCITY), bad, finished=False))
        assert len(list(stream)) == 1 and stream.truncated


def test_a_zstd_frame_holding_more_than_its_chunk_declares_is_cut_at_the_cap():
    import zstandard

    inner = declared_velocity_topic() + message(1, VELOCITY)
    frame = zstandard.ZstdCompressor(write_content_size=True).compress(inner * 1000)
    stream = McapStream(mcap(declared_velocity_topic(), chunk(inner, compression="zstd", stored=frame)))
    # The frame expands to a thousand times the declared size; one byte past it is read.
    assert list(stream) == [] and stream.truncated and "not the" in stream.stop_reason


def test_thousands_of_schemas_or_channels_are_refused():
    many = b"".join(schema(i, f"s{i}") for i in range(1, MAX_SCHEMAS + 2))
    with pytest.raises(RecordingError, match=f"more than {MAX_SCHEMAS} schemas"):
        list(McapStream(mcap(many)))
    many = schema(1, "s") + b"".join(channel(i, 1, f"/t{i}") for i in range(1, MAX_CHANNELS + 2))
    with pytest.raises(RecordingError, match=f"more than {MAX_CHANNELS} channels"):
        list(McapStream(mcap(many)))
    # Re-declaring the same ids (summary sections repeat them) is no attack.
    repeated = b"".join(schema(1, "s") + channel(1, 1, "/t") for _ in range(MAX_SCHEMAS + 10))
    assert list(McapStream(mcap(repeated, message(1, b"{}")))) != []


def test_declarations_share_a_byte_budget():
    big = b"x" * (20 * 2**20)
    with pytest.raises(RecordingError, match="exceed the 64 MiB"):
        list(McapStream(mcap(*(schema(i, "s", big) for i in range(1, 5)))))


def test_a_message_on_an_undeclared_channel_is_refused():
    with pytest.raises(RecordingError, match="channel 7, which was never declared"):
        list(McapStream(mcap(declared_velocity_topic(), message(7, VELOCITY))))
    with pytest.raises(RecordingError, match="undeclared schema"):
        list(McapStream(mcap(channel(1, 9, "/teach/cmd_vel"), message(1, VELOCITY))))


def test_opcode_zero_is_damage_like_the_zero_tail_of_a_crashed_file():
    stream = McapStream(io.BytesIO(MAGIC + header() + declared_velocity_topic() + message(1, VELOCITY) + b"\x00" * 4096))
    # The mcap library skips the empty opcode-0 records until the data runs out.
    assert len(list(stream)) == 1 and stream.truncated and not stream.complete


# ----------------------------------------------------------------------------- JSON
@pytest.mark.parametrize("text, error", [
    (b"[" * 100_000 + b"]" * 100_000, "nested more than"),
    (b"[" * (MAX_JSON_DEPTH + 1) + b"]" * (MAX_JSON_DEPTH + 1), "nested more than"),
    (b"[" + b"0," * MAX_JSON_ITEMS + b"0]", "values"),
    (b'{"v": ' + b"9" * 400 + b"}", "308 digits"),
    (b'{"v": ' + b"9" * 5000 + b"}", "308 digits"),
    (b'{"v": 1', "malformed JSON"),
])
def test_json_is_decoded_under_caps(text, error):
    with pytest.raises(RecordingError, match=error):
        decode_json(text, "msg")


def test_brackets_inside_strings_do_not_count_as_nesting():
    text = json.dumps({"label": "[" * 500 + "{" * 500}).encode()
    assert decode_json(text, "msg")["label"].startswith("[[[")
    assert isinstance(decode_json(b"[" * MAX_JSON_DEPTH + b"]" * MAX_JSON_DEPTH, "msg"), list)


def test_metadata_values_are_capped_too():
    stream = McapStream(mcap(metadata("hbvs", {"file_kind": '"teach"', "world": "[" * 1000 + "]" * 1000})))
    list(stream)
    with pytest.raises(RecordingError, match="metadata hbvs.world"):
        read_metadata(stream, "hbvs")


# ----------------------------------------------------------------------------- file kinds
def test_unknown_schema_names_on_known_topics_are_refused(tmp_path):
    from hbvs_cli.io.fit_file import read_fit_file
    from hbvs_cli.io.run_file import read_run
    from hbvs_cli.io.teach_file import TeachReader

    cases = [
        (lambda source: list(TeachReader(source).frames()), "/camera/image", "foxglove.RawImage"),
        (read_fit_file, "/fit/model", "hbvs.Model"),
        (read_run, "/repeat/state", "hbvs.State"),
    ]
    for read, topic, wrong in cases:
        source = mcap(schema(1, wrong) + channel(1, 1, topic), message(1, b"{}"))
        with pytest.raises(RecordingError, match=f"topic {topic} has schema '{wrong}'"):
            read(source)


def test_a_teach_image_that_is_not_protobuf_is_refused():
    from hbvs_cli.io.teach_file import TeachReader

    for encoding in ("cdr", "json"):
        source = mcap(schema(1, "foxglove.CompressedImage") + channel(1, 1, "/camera/image", encoding), message(1, b"{}"))
        with pytest.raises(RecordingError, match="expected protobuf"):
            list(TeachReader(source).frames())
    garbage = mcap(schema(1, "foxglove.CompressedImage") + channel(1, 1, "/camera/image", "protobuf"), message(1, b"\x0a\xff\xff\xff\xff\x0f"))
    frame = next(TeachReader(garbage).frames())
    with pytest.raises(RecordingError, match="not a protobuf foxglove.CompressedImage"):
        frame.stored_image("garbage")


def world_description(**changes) -> dict:
    from hbvs_cli.sim.world import default_world

    world = default_world().to_dict()
    for path, value in changes.items():
        keys = path.split("__")
        target = world
        for key in keys[:-1]:
            target = target[key]
        target[keys[-1]] = value
    return world


@pytest.mark.parametrize("changes, error", [
    ({"target__poster__width_m": 1000.0}, "poster"),
    ({"target__poster__right": [0.0, 0.0, 0.0]}, "axes"),
    ({"camera__width": 100_000, "camera__cx": 50_000.0}, "implausibly large"),
    ({"camera__width": 16_000, "camera__height": 16_000, "camera__cx": 8000.0, "camera__cy": 8000.0}, "more pixels"),
    ({"camera_height_m": float("inf")}, "camera height"),
    ({"target__points_poster_m": [[0.1, 0.1]] * 100}, "target points"),
    ({"camera": "not a camera"}, "malformed world"),
])
def test_world_descriptions_are_bounded_before_anything_renders_them(changes, error):
    """io checks what it uses (camera, height) as it reads; sim the rest as it builds the world."""
    from hbvs_cli.io.teach_file import world_description as checked_description
    from hbvs_cli.sim.world import world_from_description

    with pytest.raises(RecordingError, match=error):
        world_from_description(checked_description(world_description(**changes), "teach.mcap"), "teach.mcap")


@pytest.fixture(scope="module")
def small_fit_model(tmp_path_factory):
    """The model of a fit of a 1 s teach at 10 fps: quick to make, complete in every field."""
    from conftest import make_fit, make_teach

    folder = tmp_path_factory.mktemp("small_fit")
    return make_fit(make_teach(folder / "teach.mcap", fps=10.0, duration=1.0), folder / "fit.mcap").model


@pytest.mark.parametrize("change, error", [
    (lambda m: m.update(format_version="1"), "format_version"),
    (lambda m: m["reference"].update(m_ref=[[1.0, float("nan"), 0.1]] * 3, pixels=[[0.0, 0.0]] * 3), "NaN"),
    (lambda m: m.update(normal=[0.0, 0.0, 0.0]), "normal"),
    (lambda m: m.update(dhat0="4"), "dhat0"),
    (lambda m: m["camera"].update(width=10**6), "implausibly large"),
    (lambda m: m["frames"].update(frame_interval_s=-1), "frame_interval_s"),
    (lambda m: m.update(render={"noise": "loud"}), "noise"),
    (lambda m: m["reference"].update(index=float("inf")), "malformed"),
    (lambda m: m.update(detector={"kind": "aruco"}), "detector kind"),
    (lambda m: m.update(trajectory={"channels": []}), "malformed"),
])
def test_fit_models_are_validated_where_repeat_would_trip(small_fit_model, change, error):
    from hbvs_cli.io.fit_file import model_from_message, model_message

    message = json.loads(encode_json(model_message(small_fit_model, 0)))
    change(message)
    with pytest.raises(RecordingError, match=error):
        model_from_message(message, "fit.mcap")


def test_run_files_with_mistyped_events_or_metadata_are_refused():
    from hbvs_cli.io.run_file import read_run

    state = {key: 0.0 for key in ("t", "v_c", "w_c", "dhat")} | {"saturated": False, "target_lost": False}
    topics = schema(1, "hbvs.ControllerState") + channel(1, 1, "/repeat/state") + schema(2, "foxglove.Log") + channel(2, 2, "/repeat/events")
    good = metadata("hbvs", {"file_kind": '"run"'})
    with pytest.raises(RecordingError, match="expected a protobuf foxglove message"):
        read_run(mcap(good, topics, message(1, json.dumps(state).encode()), message(2, b'{"level": "high"}')))
    with pytest.raises(RecordingError, match="settings"):
        read_run(mcap(metadata("hbvs", {"file_kind": '"run"', "settings": "[1]"}), topics, message(1, json.dumps(state).encode())))
    with pytest.raises(RecordingError, match="step times"):
        read_run(mcap(good, topics, message(1, json.dumps(state | {"t": None}).encode())))
    route = metadata("hbvs", {"file_kind": '"run"', "route": '{"switch_times": [1.0]}'})
    for made in ('"soon"', '[true]', '["1"]'):
        with pytest.raises(RecordingError, match="hbvs.route_switches"):
            read_run(mcap(route, metadata("hbvs.route_switches", {"switch_times": made}), topics, message(1, json.dumps(state).encode())))
    kept = read_run(mcap(route, metadata("hbvs.route_switches", {"switch_times": "[1.25]"}), topics, message(1, json.dumps(state).encode())))
    assert kept.info["route"] == {"switch_times": [1.25], "planned_switch_times": [1.0]}


# ----------------------------------------------------------------------------- images
def png(width: int = 16, height: int = 12) -> bytes:
    import cv2

    return cv2.imencode(".png", np.zeros((height, width), np.uint8))[1].tobytes()


def test_a_png_chunk_declaring_gigabytes_is_refused_before_opencv():
    from hbvs_cli.io.images import decode_image

    data = bytearray(png())
    data[33:37] = (0x79000026).to_bytes(4, "big")  # the IDAT length: ~2 GB (OpenCV took 2.5 s)
    with pytest.raises(InputError, match="runs past the end"):
        decode_image(bytes(data), "frame")
    data = bytearray(png())
    data[30] ^= 1  # the IHDR CRC
    with pytest.raises(InputError, match="CRC"):
        decode_image(bytes(data), "frame")


def test_a_damaged_byte_anywhere_in_a_long_png_chunk_is_refused():
    """A chunk's CRC is summed in pieces (CRC_PIECE_BYTES): a byte flipped in its first,
    a middle or its last piece is found, and the intact PNG decodes to its pixels."""
    import cv2

    from hbvs_cli.io.images import CRC_PIECE_BYTES, decode_image

    image = np.random.default_rng(4).integers(0, 256, (120, 160), dtype=np.uint8)
    data = cv2.imencode(".png", image)[1].tobytes()
    length = int.from_bytes(data[33:37], "big")  # the first IDAT's, after the IHDR
    assert data[37:41] == b"IDAT" and length >= 2 * CRC_PIECE_BYTES
    np.testing.assert_array_equal(decode_image(data, "frame"), image)
    for offset in (41, 41 + CRC_PIECE_BYTES + 7, 41 + length - 1):
        damaged = bytearray(data)
        damaged[offset] ^= 0x10
        with pytest.raises(InputError, match=r"frame: cannot be decoded as an image \(a b'IDAT' chunk fails its CRC check"):
            decode_image(bytes(damaged), "frame")


def test_image_headers_declaring_more_pixels_than_the_data_can_hold_are_refused():
    from hbvs_cli.io.images import decode_image

    data = bytearray(png())
    data[16:24] = struct.pack(">II", 8000, 8000)
    data[29:33] = zlib.crc32(bytes(data[12:29])).to_bytes(4, "big")
    with pytest.raises(InputError, match="cannot hold"):
        decode_image(bytes(data), "frame")
    with pytest.raises(InputError, match="more than hbvs accepts"):
        decode_image(b"BM" + b"\x00" * 16 + struct.pack("<ii", 100_000, 100_000) + b"\x00" * 30, "frame")


# ----------------------------------------------------------------------------- text inputs
def test_an_opencv_matrix_without_rows_is_refused_without_touching_opencvs_reader(tmp_path):
    from hbvs_cli.io.calibration import load_calibration

    # FileNode.mat() on this raises and then corrupts OpenCV's heap (a later double free).
    text = ("%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\ncamera_matrix: !!opencv-matrix\n"
            "   colss: 3\n   rows: 3\n   dt: d\n   data: [ 500., 0., 319.5, 0., 500., 239.5, 0., 0., 1. ]\n")
    (tmp_path / "cv.yaml").write_text(text)
    for _ in range(3):
        with pytest.raises(CalibrationError, match="cols must be a whole number"):
            load_calibration(tmp_path / "cv.yaml")


@pytest.mark.parametrize("text", [
    "camera_matrix: &a [*a]\n",
    "a: &a [1, 1]\nb: &b [*a, *a, *a, *a]\nc: &c [*b, *b, *b, *b]\ncamera_matrix: [*c, *c, *c, *c]\n",
    "camera_matrix: !!python/object/apply:os.system ['touch /tmp/hbvs-pwned']\n",
    "camera_matrix: " + "[" * 10000 + "]" * 10000 + "\n",
])
def test_yaml_calibrations_are_loaded_safely(tmp_path, text):
    from hbvs_cli.io.calibration import load_calibration

    (tmp_path / "c.yaml").write_text(text)
    with pytest.raises(CalibrationError):
        load_calibration(tmp_path / "c.yaml")


@pytest.mark.parametrize("text, error", [
    ("[gains]\nk_v = " + "9" * 400 + "\n", "out of range"),
    ("[gains]\nk_v = " + "9" * 5000 + "\n", "malformed TOML"),
    ("[limits]\nlatency = " + "9" * 30 + "\n", "out of range"),
    ("law = " + "[" * 5000 + "]" * 5000 + "\n", "malformed TOML"),
])
def test_toml_configs_with_huge_or_deep_values_are_refused(tmp_path, text, error):
    from hbvs_cli.settings.config import load_config

    (tmp_path / "gains.toml").write_text(text)
    with pytest.raises(InputError, match=error):
        load_config(tmp_path / "gains.toml")


def test_pendant_csv_errors_stay_on_one_line(tmp_path):
    from hbvs_cli.io.path_csv import load_command_profile

    (tmp_path / "p.csv").write_text("t,v,w\n0,0.1,0\n" + "x" * 100_000 + ",1,1\n")
    with pytest.raises(InputError) as info:
        load_command_profile(tmp_path / "p.csv")
    assert "\n" not in str(info.value) and len(str(info.value)) < 300
    (tmp_path / "p.csv").write_text("t,v,w\n0,0.1,0\n1e308,0.1,0\n")
    with pytest.raises(InputError, match="too large"):
        load_command_profile(tmp_path / "p.csv")
