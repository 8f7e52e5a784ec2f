"""The MCAP edge: round trips, pipes, atomic output, truncated and hostile files."""

from __future__ import annotations

import io
import json
import struct

import numpy as np
import pytest

from hbvs_cli.errors import InputError, OutputError, RecordingError
from hbvs_cli.io.mcap import MAX_CHUNK_BYTES, McapStream, McapWriter, encode_json, json_ready, open_output, read_metadata


def write_sample(stream, messages: int = 50, chunk_size: int = 1024, metadata: bool = True) -> list[dict]:
    writer = McapWriter(stream, chunk_size=chunk_size)
    if metadata:
        writer.metadata("hbvs", {"file_kind": "teach", "settings": {"seed": 3}})
    sent = []
    for k in range(messages):
        message = {"timestamp": {"sec": k, "nsec": 5}, "v": 0.1 * k, "w": -0.01 * k}
        writer.write("/teach/cmd_vel", "hbvs.VelocityCommand", k * 1_000_000_000 + 5, message)
        sent.append(message)
    writer.finish()
    return sent


def test_round_trip_preserves_every_message_byte_for_byte(tmp_path):
    path = tmp_path / "a.mcap"
    with open(path, "wb") as handle:
        sent = write_sample(handle)
    stream = McapStream(path)
    received = list(stream)
    assert stream.complete and not stream.truncated
    assert [m.data for m in received] == [encode_json(s) for s in sent]
    assert [m.log_time for m in received] == [k * 1_000_000_000 + 5 for k in range(50)]
    assert {m.schema_name for m in received} == {"hbvs.VelocityCommand"}
    assert read_metadata(stream, "hbvs") == {"file_kind": "teach", "settings": {"seed": 3}}


def test_official_reader_accepts_what_we_write(tmp_path):
    from mcap.reader import make_reader

    path = tmp_path / "a.mcap"
    with open(path, "wb") as handle:
        write_sample(handle)
    with open(path, "rb") as handle:
        reader = make_reader(handle)
        summary = reader.get_summary()
        assert summary.statistics.message_count == 50
        assert len(list(reader.iter_messages())) == 50


def test_same_input_gives_identical_bytes():
    a, b = io.BytesIO(), io.BytesIO()
    write_sample(a)
    write_sample(b)
    assert a.getvalue() == b.getvalue()


def test_atomic_output_keeps_the_old_file_when_the_writer_fails(tmp_path):
    target = tmp_path / "out.mcap"
    target.write_bytes(b"precious")
    with pytest.raises(RuntimeError):
        with open_output(target) as writer:
            writer.write("/teach/cmd_vel", "hbvs.VelocityCommand", 0, {"timestamp": {"sec": 0, "nsec": 0}, "v": 0, "w": 0})
            raise RuntimeError("boom")
    assert target.read_bytes() == b"precious"
    assert not list(tmp_path.glob("out.mcap*.partial"))
    with open_output(target) as writer:
        writer.write("/teach/cmd_vel", "hbvs.VelocityCommand", 0, {"timestamp": {"sec": 0, "nsec": 0}, "v": 1.0, "w": 0})
    assert len(list(McapStream(target))) == 1


def test_output_errors_are_clear(tmp_path):
    with pytest.raises(OutputError, match="does not exist"):   # exit 6: an output that cannot be written
        with open_output(tmp_path / "missing" / "x.mcap"):
            pass
    with pytest.raises(InputError, match="directory"):
        with open_output(tmp_path):
            pass


@pytest.mark.parametrize("fraction", [0.05, 0.3, 0.55, 0.8, 0.97])
def test_truncated_file_yields_its_complete_prefix(tmp_path, fraction):
    full = io.BytesIO()
    sent = write_sample(full, messages=200, chunk_size=512)
    data = full.getvalue()
    cut = data[: int(len(data) * fraction)]
    stream = McapStream(io.BytesIO(cut))
    received = list(stream)
    assert stream.truncated and not stream.complete
    # Every message read is one that was written, in order: a clean prefix.
    assert [m.data for m in received] == [encode_json(s) for s in sent[: len(received)]]
    if fraction > 0.3:
        assert len(received) > 0


def test_not_an_mcap_file(tmp_path):
    for content in (b"", b"hello world, not mcap", b"\x89MCAP0\r\n" + b"\x00" * 3):
        path = tmp_path / "bad.mcap"
        path.write_bytes(content)
        with pytest.raises(RecordingError):
            list(McapStream(path))
    with pytest.raises(InputError, match="no such file"):
        list(McapStream(tmp_path / "nope.mcap"))


def test_declared_huge_record_is_refused_without_allocating(tmp_path):
    magic = b"\x89MCAP0\r\n"
    header = struct.pack("<BQ", 0x01, 8) + struct.pack("<I", 0) + struct.pack("<I", 0)
    huge = struct.pack("<BQ", 0x06, 2**40)  # a chunk declaring one terabyte
    path = tmp_path / "hostile.mcap"
    path.write_bytes(magic + header + huge + b"\x00" * 16)
    with pytest.raises(RecordingError):
        list(McapStream(path))


def test_chunk_declaring_more_than_the_cap_is_refused(tmp_path):
    from mcap.records import Chunk
    from mcap.data_stream import RecordBuilder

    builder = RecordBuilder()
    Chunk(compression="", data=b"\x00" * 10, message_start_time=0, message_end_time=0,
          uncompressed_crc=0, uncompressed_size=MAX_CHUNK_BYTES + 1).write(builder)
    magic = b"\x89MCAP0\r\n"
    header = struct.pack("<BQ", 0x01, 8) + struct.pack("<I", 0) + struct.pack("<I", 0)
    path = tmp_path / "bomb.mcap"
    path.write_bytes(magic + header + builder.end())
    with pytest.raises(RecordingError, match="MiB"):
        list(McapStream(path))


def test_json_ready_turns_numpy_and_nan_into_json():
    value = json_ready({"a": np.float64(1.5), "b": np.array([1, 2]), "c": float("nan"), "d": [np.inf, 2]})
    assert value == {"a": 1.5, "b": [1, 2], "c": None, "d": [None, 2]}
    json.dumps(value, allow_nan=False)
