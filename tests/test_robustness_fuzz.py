"""Every reader against mutated and truncated inputs: the fuzz campaign.

Inputs are small valid files (a 1 s teach from an 80x60 camera, a fit and a run made from a
1 s teach, calibration files in the three formats, a pendant CSV, a TOML config, a two-frame
ROS 2 bag). Each case mutates one of them three ways:

* **bytes** of the file as written (chunks compressed, with CRCs): truncation, bit flips,
  overwrites with boundary integers (where length fields sit), insertions, deletions,
  duplicated spans, syntax tokens of the format;
* **bytes of a plain re-write** (chunks uncompressed and without CRCs, or no chunks at all),
  so that damage reaches the record parsers instead of failing a checksum;
* **structure**: messages re-encoded with a JSON value (or raw text such as a 400-digit
  integer or 100 nested brackets) put anywhere in them or in the metadata, schema names
  and encodings changed, messages dropped, duplicated or moved; for the bag, CDR payloads
  and message definitions damaged.

The only outcomes allowed are success, or an :class:`~hbvs_cli.errors.HbvsError` whose
message is one non-empty line. Any other exception fails the test, and so does a case that
runs longer than :data:`CASE_SECONDS` (a SIGALRM stops it) or memory beyond
:data:`MEMORY_HEADROOM` (``RLIMIT_AS`` turns it into a MemoryError).

The cases are seeded (``derandomize=True``), so every run tries the same ones. The default
campaign runs :data:`TOTAL_CASES` cases; ``pytest -m fuzz_long tests/test_robustness_fuzz.py``
runs :data:`LONG_FACTOR` times as many, from another seed.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import resource
import signal
import struct
import threading
import time
from dataclasses import dataclass, replace
from datetime import timedelta
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

from conftest import make_fit, make_run, make_teach
from hbvs_cli.errors import HbvsError
from hbvs_cli.io.mcap import McapMessage as Message

#: Wall-clock bound of one case (a typical one takes a few milliseconds).
CASE_SECONDS = 5.0
#: Address space a campaign may add to what the process already maps.
MEMORY_HEADROOM = 2 * 2**30
#: How many times more cases the long campaign runs.
LONG_FACTOR = 20


# ----------------------------------------------------------------------------- inputs
@dataclass(frozen=True)
class Recording:
    """An MCAP file taken apart: its messages in order, and its metadata."""

    messages: tuple[Message, ...]
    metadata: tuple[tuple[str, tuple[tuple[str, str], ...]], ...]
    profile: str = ""


def decompose(data: bytes) -> Recording:
    from mcap.reader import make_reader

    reader = make_reader(io.BytesIO(data))
    messages = tuple(
        Message(channel.topic, schema.name if schema else "", schema.encoding if schema else "",
                bytes(schema.data) if schema else b"", channel.message_encoding, message.log_time, bytes(message.data))
        for schema, channel, message in reader.iter_messages(log_time_order=False)
    )
    metadata = tuple((record.name, tuple(record.metadata.items())) for record in reader.iter_metadata())
    return Recording(messages, metadata, reader.get_header().profile)


def compose(recording: Recording, compression: str = "zstd", crcs: bool = True, chunked: bool = True) -> bytes:
    """An MCAP file of ``recording``, written by the mcap library (not by hbvs)."""
    from mcap.writer import CompressionType, Writer

    sink = io.BytesIO()
    writer = Writer(sink, chunk_size=4096, compression=CompressionType[compression.upper()],
                    use_chunking=chunked, enable_crcs=crcs)
    writer.start(profile=recording.profile, library="fuzz")
    schemas: dict[tuple[str, str, bytes], int] = {}
    channels: dict[tuple[str, str, int], int] = {}
    for name, values in recording.metadata:
        writer.add_metadata(name, dict(values))
    for sequence, message in enumerate(recording.messages):
        schema_key = (message.schema_name, message.schema_encoding, message.schema_data)
        if schema_key not in schemas:
            schemas[schema_key] = writer.register_schema(*schema_key)
        channel_key = (message.topic, message.message_encoding, schemas[schema_key])
        if channel_key not in channels:
            channels[channel_key] = writer.register_channel(*channel_key)
        writer.add_message(channels[channel_key], message.log_time, message.data, message.log_time, sequence)
    writer.finish()
    return sink.getvalue()


def tiny_png(value: int = 128) -> bytes:
    import cv2

    return cv2.imencode(".png", np.full((6, 8), value, np.uint8))[1].tobytes()


def shrunk_fit(data: bytes) -> bytes:
    """A fit file with its reference and template images replaced by 8x6 ones (the reader
    does not look inside them), so that a case reads a few kilobytes."""
    from hbvs_cli.io.images import compressed_image_message, read_compressed_image

    recording = decompose(data)
    messages = []
    for message in recording.messages:
        if message.topic in ("/reference/image", "/detector/template"):
            stamp = read_compressed_image(message.data).stamp_ns
            message = replace(message, data=compressed_image_message(stamp, tiny_png(), "png").SerializeToString())
        messages.append(message)
    return compose(replace(recording, messages=tuple(messages)))


def write_bag(folder: Path) -> bytes:
    """A two-frame ROS 2 bag (CompressedImage and CameraInfo), written with rosbags."""
    import cv2
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    types = get_typestore(Stores.ROS2_HUMBLE)
    t = types.types
    header = lambda ns: t["std_msgs/msg/Header"](  # noqa: E731
        stamp=t["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9), frame_id="cam")
    image_type, info_type = "sensor_msgs/msg/CompressedImage", "sensor_msgs/msg/CameraInfo"
    with Writer(folder, version=8, storage_plugin=StoragePlugin.MCAP) as writer:
        image = writer.add_connection("/cam/image/compressed", image_type, typestore=types)
        info = writer.add_connection("/cam/camera_info", info_type, typestore=types)
        for k in range(2):
            ns = 10**9 + k * 10**8
            png = cv2.imencode(".png", np.full((12, 16), 40 * k, np.uint8))[1].reshape(-1)
            calibration = t[info_type](
                header=header(ns), height=12, width=16, distortion_model="plumb_bob", d=np.zeros(5),
                k=np.array([20.0, 0, 7.5, 0, 20.0, 5.5, 0, 0, 1]), r=np.eye(3).ravel(), p=np.zeros(12),
                binning_x=0, binning_y=0,
                roi=t["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))
            writer.write(info, ns, types.serialize_cdr(calibration, info_type))
            writer.write(image, ns, types.serialize_cdr(t[image_type](header=header(ns), format="png", data=png), image_type))
    return next(folder.glob("*.mcap")).read_bytes()


ROS_YAML = """image_width: 640
image_height: 480
camera_name: front
camera_matrix: {rows: 3, cols: 3, data: [500.0, 0.0, 319.5, 0.0, 500.0, 239.5, 0.0, 0.0, 1.0]}
distortion_model: plumb_bob
distortion_coefficients: {rows: 1, cols: 5, data: [-0.1, 0.01, 0.0, 0.0, 0.0]}
rectification_matrix: {rows: 3, cols: 3, data: [1, 0, 0, 0, 1, 0, 0, 0, 1]}
projection_matrix: {rows: 3, cols: 4, data: [500, 0, 319.5, 0, 0, 500, 239.5, 0, 0, 0, 1, 0]}
"""

OPENCV_YAML = """%YAML:1.0
---
image_width: 640
image_height: 480
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 500., 0., 319.5, 0., 500., 239.5, 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 1
   cols: 5
   dt: d
   data: [ -0.1, 0.01, 0., 0., 0. ]
"""

JSON_CALIBRATION = """{"K": [[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]],
 "D": [-0.1, 0.01, 0.0, 0.0, 0.0], "width": 640, "height": 480, "distortion_model": "plumb_bob"}
"""

PENDANT_CSV = "t,v,w\n" + "".join(f"{0.1 * k:.1f},0.1,{0.02 * math.sin(k):.4f}\n" for k in range(12))


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict[str, Any]:
    """The valid inputs every case starts from, built once."""
    from hbvs_cli.core.camera import CameraIntrinsics
    from hbvs_cli.io.calibration import save_calibration_ros

    folder = tmp_path_factory.mktemp("fuzz_inputs")
    tiny_camera = CameraIntrinsics(fx=62.5, fy=62.5, cx=39.5, cy=29.5, width=80, height=60)
    save_calibration_ros(tiny_camera, folder / "tiny.yaml")
    teach = make_teach(folder / "teach.mcap", calibration=folder / "tiny.yaml", fps=5.0, duration=1.0)
    short = make_teach(folder / "short.mcap", fps=10.0, duration=1.0)
    make_fit(short, folder / "fit.mcap")
    make_run(folder / "fit.mcap", folder / "run.mcap", sim=True, perception="points")
    files = {
        "teach": teach.read_bytes(),
        "fit": shrunk_fit((folder / "fit.mcap").read_bytes()),
        "run": (folder / "run.mcap").read_bytes(),
        "bag": write_bag(folder / "bag"),
    }
    recordings = {kind: decompose(data) for kind, data in files.items()}
    texts = {
        "ros_yaml": ROS_YAML.encode(), "opencv_yaml": OPENCV_YAML.encode(), "json": JSON_CALIBRATION.encode(),
        "csv": PENDANT_CSV.encode(), "toml": (Path(__file__).parent.parent / "samples" / "gains.toml").read_bytes(),
    }
    return {"files": files, "recordings": recordings, "texts": texts, "scratch": tmp_path_factory.mktemp("fuzz_cases")}


# ----------------------------------------------------------------------------- readers under test
def read_teach(data: bytes) -> None:
    """What ``hbvs fit`` does with a teach file, up to the detector: every frame and image."""
    from hbvs_cli.stages.frame_decoding import decode_frame
    from hbvs_cli.io.teach_file import TeachReader

    reader = TeachReader(io.BytesIO(data), name="teach.mcap")
    for frame in reader.frames():
        decode_frame(frame, "teach.mcap")


def read_fit(data: bytes) -> None:
    from hbvs_cli.io.fit_file import read_fit_file

    read_fit_file(io.BytesIO(data), name="fit.mcap")


def read_run_file(data: bytes) -> None:
    from hbvs_cli.io.run_file import read_run

    read_run(io.BytesIO(data), name="run.mcap")


def on_disk(name: str, reader: Callable[[Path], Any]) -> Callable[[bytes, Path], None]:
    """A reader of a file path, given bytes: they are written to ``name`` in a scratch folder."""
    def read(data: bytes, scratch: Path) -> None:
        path = scratch / name
        path.write_bytes(data)
        reader(path)
    return read


def _calibration(path: Path) -> None:
    from hbvs_cli.io.calibration import load_calibration

    load_calibration(path)


def _pendant(path: Path) -> None:
    from hbvs_cli.io.path_csv import load_command_profile

    load_command_profile(path)


def _config(path: Path) -> None:
    from hbvs_cli.settings.config import load_config

    load_config(path)


def _bag(path: Path) -> None:
    from hbvs_cli.io.sources import BagSource

    for _ in BagSource(path):
        pass


# ----------------------------------------------------------------------------- mutations
#: Little-endian boundary integers, written where length and count fields may sit.
BOUNDARY_INTEGERS = [
    struct.pack("<B", 0), struct.pack("<B", 0xFF), struct.pack("<H", 0xFFFF), struct.pack("<I", 0x7FFFFFFF),
    struct.pack("<I", 0xFFFFFFFF), struct.pack("<Q", 2**63 - 1), struct.pack("<Q", 2**64 - 1),
    struct.pack("<Q", 2**40), struct.pack("<I", 1), struct.pack("<Q", 0),
]
#: Pieces of syntax (YAML, JSON, CSV, TOML, OpenCV, MCAP) and hostile literals.
TOKENS = [
    b"\n", b"[", b"]", b"{", b"}", b'"', b"'", b",", b":", b"=", b"- ", b"---\n", b"\x00", b"\xff\xfe", b"\t",
    b"1e999", b"-inf", b"nan", b"NaN", b"9" * 400, b"9" * 5000, b"[" * 200, b"{" * 200, b"&a [1, *a]", b"*a",
    b"!!python/object/apply:os.system ['true']", b"!!opencv-matrix", b"%YAML:1.0\n", b"<?xml version='1.0'?>",
    b'"""', b"[[gains]]\n", b"[gains.extra]\n", b"0x7fffffffffffffffffff", b"\x89MCAP0\r\n", b"\xef\xbb\xbf",
    b"rows: 100000\ncols: 100000\n", b"true", b"null", b"1_000", b" " * 64,
]
EDIT_KINDS = ("truncate", "flip", "overwrite", "integer", "token", "insert", "delete", "duplicate")

edits = st.lists(
    st.tuples(st.sampled_from(EDIT_KINDS), st.integers(0, 2**31), st.integers(0, 2**16), st.binary(max_size=12)),
    min_size=1, max_size=4,
)


def apply_edits(data: bytes, changes: list[tuple[str, int, int, bytes]]) -> bytes:
    """``data`` with each edit applied at ``where`` (taken modulo the current length)."""
    buffer = bytearray(data)
    for kind, where, number, payload in changes:
        at = where % (len(buffer) + 1)
        if kind == "truncate":
            del buffer[at:]
        elif kind == "flip" and buffer:
            buffer[at % len(buffer)] ^= 1 << (number % 8)
        elif kind == "overwrite":
            buffer[at:at + len(payload)] = payload
        elif kind == "integer":
            value = BOUNDARY_INTEGERS[number % len(BOUNDARY_INTEGERS)]
            buffer[at:at + len(value)] = value
        elif kind == "token":
            buffer[at:at] = TOKENS[number % len(TOKENS)]
        elif kind == "insert":
            buffer[at:at] = payload
        elif kind == "delete":
            del buffer[at:at + 1 + number % 64]
        elif kind == "duplicate":
            buffer[at:at] = buffer[at:at + 1 + number % 512]
    return bytes(buffer)


#: Raw JSON text for places a JSON value goes: what a Python value cannot express.
RAW_JSON = [
    "9" * 400, "-" + "9" * 309, "1e999", "-1e999", "NaN", "Infinity", "[" * 100 + "]" * 100,
    "{" + '"a":{' * 80 + "1" + "}" * 81, '"' + "\\ud800" + '"', "[1,2", "}", "",
]
json_leaves = st.one_of(
    st.none(), st.booleans(), st.integers(-(2**70), 2**70), st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=12), st.sampled_from([0, -1, 1, 2**31, 2**63, 1e308, -1e-308, 0.0, 1.0]),
)
json_values = st.recursive(
    json_leaves, lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
    max_leaves=10,
)
RAW_MARK = "\x00raw\x00"


def json_paths(value: Any, path: tuple = ()) -> list[tuple]:
    """Every position in a JSON value (the value itself, then everything inside it)."""
    paths = [path]
    if isinstance(value, dict):
        for key, inner in value.items():
            paths += json_paths(inner, path + (key,))
    elif isinstance(value, list):
        for index, inner in enumerate(value):
            paths += json_paths(inner, path + (index,))
    return paths


def put(value: Any, path: tuple, new: Any) -> Any:
    """A copy of ``value`` with ``new`` at ``path``."""
    if not path:
        return new
    head, rest = path[0], path[1:]
    copy = dict(value) if isinstance(value, dict) else list(value)
    copy[head] = put(value[head], rest, new)
    return copy


def replaced_json(text: bytes | str, where: int, new: Any, raw: str | None) -> str:
    """JSON ``text`` with the value at position ``where`` replaced by ``new`` (or raw text)."""
    try:
        value = json.loads(text)
    except ValueError:
        return raw if raw is not None else json.dumps(new)
    paths = json_paths(value)
    encoded = json.dumps(put(value, paths[where % len(paths)], RAW_MARK if raw is not None else new))
    return encoded.replace(json.dumps(RAW_MARK), raw) if raw is not None else encoded


STRUCTURE_KINDS = ("json", "json", "json", "metadata", "schema", "encoding", "drop", "duplicate", "move", "topic", "data")


@st.composite
def structural_changes(draw: Any) -> dict[str, Any]:
    return {
        "kind": draw(st.sampled_from(STRUCTURE_KINDS)),
        "index": draw(st.integers(0, 2**20)),
        "where": draw(st.integers(0, 2**20)),
        "value": draw(json_values),
        "raw": draw(st.none() | st.sampled_from(RAW_JSON)),
        "text": draw(st.sampled_from(["", "foxglove.CompressedImage", "hbvs.FitModel", "cdr", "json", "protobuf",
                                      "hbvs.ControllerState", "x" * 300])),
        "data": draw(st.binary(max_size=64)),
        "layout": draw(st.sampled_from([("zstd", True, True), ("none", False, True), ("lz4", True, True),
                                        ("none", False, False)])),
    }


def restructure(recording: Recording, change: dict[str, Any], focus: set[str]) -> bytes:
    """The recording with one structural change, written as a (framing-valid) MCAP file.

    Half the changes go to a message on a ``focus`` topic (if any), the ones the reader
    looks at most closely.
    """
    messages = list(recording.messages)
    metadata = [(name, list(values)) for name, values in recording.metadata]
    kind, k = change["kind"], change["index"] % max(len(messages), 1)
    focused = [i for i, m in enumerate(messages) if m.topic in focus]
    if focused and change["index"] % 2:
        k = focused[change["index"] // 2 % len(focused)]
    message = messages[k]
    if kind == "json":
        messages[k] = replace(message, data=replaced_json(message.data, change["where"], change["value"], change["raw"]).encode())
    elif kind == "metadata" and metadata:
        name, values = metadata[change["index"] % len(metadata)]
        if values:
            key, text = values[change["where"] % len(values)]
            values[change["where"] % len(values)] = (key, replaced_json(text, change["where"] // 7, change["value"], change["raw"]))
    elif kind == "schema":
        messages = [replace(m, schema_name=change["text"]) if m.topic == message.topic else m for m in messages]
    elif kind == "encoding":
        messages = [replace(m, message_encoding=change["text"]) if m.topic == message.topic else m for m in messages]
    elif kind == "drop":
        del messages[k]
    elif kind == "duplicate":
        messages.insert(k, message)
    elif kind == "move":
        messages.insert(change["where"] % len(messages), messages.pop(k))
    elif kind == "topic":
        other = messages[change["where"] % len(messages)]
        messages[k] = replace(message, topic=other.topic)
    elif kind == "data":
        messages[k] = replace(message, data=change["data"])
    compression, crcs, chunked = change["layout"]
    frozen = tuple((name, tuple(values)) for name, values in metadata)
    return compose(replace(recording, messages=tuple(messages), metadata=frozen), compression, crcs, chunked)


def damaged_cdr(recording: Recording, change: dict[str, Any], changes: list) -> bytes:
    """A bag with one message's CDR payload, or one message definition, damaged."""
    messages = list(recording.messages)
    k = change["index"] % len(messages)
    if change["where"] % 3:
        messages[k] = replace(messages[k], data=apply_edits(messages[k].data, changes))
    else:
        schema = apply_edits(messages[k].schema_data, changes)
        messages = [replace(m, schema_data=schema) if m.topic == messages[k].topic else m for m in messages]
    compression, crcs, chunked = change["layout"]
    return compose(replace(recording, messages=tuple(messages)), compression, crcs, chunked)


# ----------------------------------------------------------------------------- the harness
class CaseTooSlow(Exception):
    """A case ran longer than its bound."""


@contextlib.contextmanager
def bounded_case(seconds: float = CASE_SECONDS) -> Any:
    """Stop a case that runs longer than ``seconds`` (SIGALRM, main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def too_slow(signum: int, frame: Any) -> None:
        raise CaseTooSlow(f"a case ran longer than {seconds} s")

    previous = signal.signal(signal.SIGALRM, too_slow)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def mapped_bytes() -> int:
    with open("/proc/self/statm") as handle:
        return int(handle.read().split()[0]) * resource.getpagesize()


@contextlib.contextmanager
def bounded_memory() -> Any:
    """Cap the address space at what is mapped now plus MEMORY_HEADROOM (MemoryError beyond)."""
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    limit = mapped_bytes() + MEMORY_HEADROOM
    if hard != resource.RLIM_INFINITY:
        limit = min(limit, hard)
    resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


def check_outcome(read: Callable[[], Any]) -> str:
    """Run one case: success or a one-line HbvsError, nothing else."""
    with bounded_case():
        try:
            read()
        except HbvsError as exc:
            message = str(exc)
            assert message.strip(), f"{type(exc).__name__} without a message"
            assert "\n" not in message, f"a message of several lines: {message!r}"
            return type(exc).__name__
    return "ok"


@dataclass
class Tally:
    cases: int = 0
    seconds: float = 0.0


TALLY = Tally()


def campaign(strategy: Any, produce: Callable[[Any], bytes], read: Callable[[bytes], None], examples: int,
             long_seed: int | None = None) -> dict[str, int]:
    """Read ``produce(value)`` for ``examples`` values drawn from ``strategy``; outcomes by kind.

    With ``HBVS_FUZZ_LOG=FILE`` in the environment, every input is appended to FILE (a
    4-byte length, then the bytes) before it is read: the way to find an input that kills
    the process, which hypothesis cannot report.
    """
    outcomes: dict[str, int] = {}
    log = os.environ.get("HBVS_FUZZ_LOG")
    started = time.perf_counter()

    @settings(max_examples=examples, derandomize=long_seed is None, database=None, deadline=timedelta(seconds=2),
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large], print_blob=True)
    @given(strategy)
    def run(value: Any) -> None:
        data = produce(value)
        if log:
            with open(log, "ab") as handle:
                handle.write(len(data).to_bytes(4, "little") + data)
        outcome = check_outcome(lambda: read(data))
        outcomes[outcome] = outcomes.get(outcome, 0) + 1

    if long_seed is not None:
        run = seed(long_seed)(run)
    with bounded_memory():
        run()
    TALLY.cases += sum(outcomes.values())
    TALLY.seconds += time.perf_counter() - started
    assert sum(outcomes.values()) >= examples
    return outcomes


# ----------------------------------------------------------------------------- campaigns
MCAP_READERS = {"teach": read_teach, "fit": read_fit, "run": read_run_file}
#: Topics whose messages the structural changes favour.
FOCUS = {"fit": {"/fit/model"}, "run": {"/repeat/state", "/repeat/events"}, "teach": {"/camera/image", "/camera/calibration"}}
TEXT_READERS = {
    "ros_yaml": on_disk("camera.yaml", _calibration), "opencv_yaml": on_disk("opencv.yaml", _calibration),
    "json": on_disk("camera.json", _calibration), "csv": on_disk("pendant.csv", _pendant),
    "toml": on_disk("gains.toml", _config),
}
#: Cases per campaign: (input, mutation) -> examples. The total is TOTAL_CASES.
CAMPAIGNS = {
    ("teach", "bytes"): 300, ("teach", "plain"): 350, ("teach", "structure"): 400,
    ("fit", "bytes"): 200, ("fit", "plain"): 250, ("fit", "structure"): 500,
    ("run", "bytes"): 200, ("run", "plain"): 250, ("run", "structure"): 350,
    ("ros_yaml", "text"): 250, ("opencv_yaml", "text"): 250, ("json", "text"): 250,
    ("csv", "text"): 250, ("toml", "text"): 250,
    ("bag", "bytes"): 120, ("bag", "plain"): 150, ("bag", "cdr"): 200,
}
TOTAL_CASES = sum(CAMPAIGNS.values())


def run_campaign(inputs: dict[str, Any], name: str, mutation: str, examples: int, long_seed: int | None) -> dict[str, int]:
    scratch = inputs["scratch"]
    if name in TEXT_READERS:
        reader, base = TEXT_READERS[name], inputs["texts"][name]
        return campaign(edits, lambda changes: apply_edits(base, changes), lambda data: reader(data, scratch),
                        examples, long_seed)
    recording = inputs["recordings"][name]
    read = (lambda data: on_disk("bag.mcap", _bag)(data, scratch)) if name == "bag" else MCAP_READERS[name]
    if mutation == "bytes":
        base = inputs["files"][name]
        return campaign(edits, lambda changes: apply_edits(base, changes), read, examples, long_seed)
    if mutation == "plain":
        layouts = [compose(recording, "none", False, True), compose(recording, "none", False, False)]
        strategy = st.tuples(st.integers(0, 1), edits)
        return campaign(strategy, lambda value: apply_edits(layouts[value[0]], value[1]), read, examples, long_seed)
    if mutation == "cdr":
        strategy = st.tuples(structural_changes(), edits)
        return campaign(strategy, lambda value: damaged_cdr(recording, *value), read, examples, long_seed)
    focus = FOCUS.get(name, set())
    return campaign(structural_changes(), lambda change: restructure(recording, change, focus), read, examples, long_seed)


@pytest.mark.parametrize("name, mutation", list(CAMPAIGNS), ids=[f"{n}-{m}" for n, m in CAMPAIGNS])
def test_readers_survive_mutated_inputs(inputs, name, mutation):
    outcomes = run_campaign(inputs, name, mutation, CAMPAIGNS[name, mutation], long_seed=None)
    # Most mutations must still be caught as errors (a fuzzer that only ever produced
    # valid files would prove nothing); the readers' successes show mutations stay close.
    assert sum(count for kind, count in outcomes.items() if kind != "ok") > 0, outcomes


def test_the_valid_inputs_read_cleanly(inputs):
    """The campaigns start from files every reader accepts as they are."""
    scratch = inputs["scratch"]
    for name, read in MCAP_READERS.items():
        assert check_outcome(lambda: read(inputs["files"][name])) == "ok", name
        for layout in (("none", False, True), ("none", False, False), ("lz4", True, True)):
            assert check_outcome(lambda: read(compose(inputs["recordings"][name], *layout))) == "ok", (name, layout)
    for name, read in TEXT_READERS.items():
        assert check_outcome(lambda: read(inputs["texts"][name], scratch)) == "ok", name
    assert check_outcome(lambda: on_disk("bag.mcap", _bag)(inputs["files"]["bag"], scratch)) == "ok"


def test_the_harness_catches_hangs_and_memory_blowups():
    """The bounds the campaign relies on do fire."""
    with pytest.raises(CaseTooSlow):
        with bounded_case(0.05):
            while True:
                pass
    with pytest.raises(MemoryError):
        with bounded_memory():
            np.ones(MEMORY_HEADROOM + 2**30, dtype=np.uint8)


def test_the_campaign_is_large_enough(inputs, capsys):
    """At least 2000 cases in the default suite (counted as they ran, when all ran here)."""
    assert TOTAL_CASES >= 2000
    if TALLY.cases:
        with capsys.disabled():
            print(f"\nfuzz: {TALLY.cases} cases in {TALLY.seconds:.1f} s")


@pytest.mark.fuzz_long
@pytest.mark.parametrize("name, mutation", list(CAMPAIGNS), ids=[f"{n}-{m}" for n, m in CAMPAIGNS])
def test_long_campaign(request, inputs, name, mutation):
    """LONG_FACTOR times the cases, from another seed: ``pytest -m fuzz_long``."""
    if "fuzz_long" not in (request.config.option.markexpr or ""):
        pytest.skip("the long fuzz campaign runs with: pytest -m fuzz_long tests/test_robustness_fuzz.py")
    run_campaign(inputs, name, mutation, CAMPAIGNS[name, mutation] * LONG_FACTOR, long_seed=20031027)
