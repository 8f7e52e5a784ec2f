"""Reading and writing MCAP files safely: capped, streaming, atomic.

MCAP framing on the write side is the ``mcap`` library's; reading is done here, record by
record, because hbvs promises more than that library's readers give:

* **Streaming both ways**: every stage reads a file or stdin (``-``) front to back in
  constant memory, and writes a file or stdout. The mcap ``Writer`` calls ``tell()``, which
  a pipe does not have, so stdout is wrapped in :class:`CountingStream`.
* **Atomic output**: a file is written as ``FILE.partial`` and renamed over ``FILE`` only
  when it is finished; a failed or interrupted command leaves any previous ``FILE``
  untouched and removes the partial file. After a hard crash (power loss, SIGKILL), the
  ``.partial`` file holds every chunk flushed so far and is itself readable.
* **Hostile input**: every declared length (a record, a field inside a record, a chunk
  before and after decompression) is checked against what contains it and against caps
  before anything is allocated; the number of schemas and channels and the bytes they and
  the metadata hold are capped; JSON is decoded under caps on size, number of values and
  nesting (:func:`decode_json`); nothing is ever unpickled or evaluated: messages are JSON
  (or CDR decoded by mcap-ros2-support).
* **Truncated files** (a crashed recorder: no summary, no footer, half a chunk) are read up
  to the last complete record; :attr:`McapStream.truncated` tells the caller.
"""

from __future__ import annotations

import io
import json
import math
import os
import re
import struct
import sys
import zlib
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, BinaryIO, Iterator

from ..errors import InputError, RecordingError
from .schemas import SCHEMAS

#: Largest MCAP record hbvs reads (a chunk, an attachment, an uncompressed image...).
MAX_RECORD_BYTES = 64 * 2**20
#: Largest decompressed chunk hbvs accepts.
MAX_CHUNK_BYTES = 128 * 2**20
#: Most schemas, and most channels, one file may declare (MCAP ids are 16-bit; a real
#: recording has tens of topics).
MAX_SCHEMAS = 4096
MAX_CHANNELS = 4096
#: Bytes that the schemas, channels and metadata of one file may hold in total.
MAX_DECLARED_BYTES = 64 * 2**20
#: Largest JSON message decoded (images travel in it base64-encoded).
MAX_JSON_BYTES = 64 * 2**20
#: Most values (counted as commas, colons and brackets) in one JSON document. Each becomes
#: a Python object of tens of bytes, so this bounds memory where the byte cap cannot.
MAX_JSON_ITEMS = 2**21
#: Deepest nesting of JSON arrays and objects decoded; hbvs writes at most six levels.
MAX_JSON_DEPTH = 64
#: Profile string in the MCAP header of every file hbvs writes.
PROFILE = ""

NANOSECONDS = 1_000_000_000


# ----------------------------------------------------------------------------- helpers
def seconds_to_ns(t: float) -> int:
    """Seconds (>= 0) to integer nanoseconds, rounded."""
    return int(round(float(t) * NANOSECONDS))


def time_message(ns: int) -> dict[str, int]:
    """The ``{"sec", "nsec"}`` time of Foxglove messages from nanoseconds."""
    ns = max(int(ns), 0)
    return {"sec": ns // NANOSECONDS, "nsec": ns % NANOSECONDS}


def json_ready(value: Any) -> Any:
    """A copy of ``value`` that ``json.dumps`` accepts: numpy to Python, NaN/inf to None."""
    if isinstance(value, dict):
        return {str(k): json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(v) for v in value]
    if hasattr(value, "tolist") and not isinstance(value, (str, bytes)):
        return json_ready(value.tolist())
    if isinstance(value, bool) or value is None or isinstance(value, (str, int)):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    try:
        number = float(value)
    except (TypeError, ValueError):
        return str(value)
    return number if math.isfinite(number) else None


def encode_json(message: dict[str, Any]) -> bytes:
    """Deterministic compact JSON bytes of a message."""
    return json.dumps(json_ready(message), separators=(",", ":"), allow_nan=False).encode("utf-8")


# ----------------------------------------------------------------------------- writing
class CountingStream:
    """A write-only wrapper that answers ``tell()`` by counting bytes: for pipes.

    The mcap ``Writer`` records chunk offsets with ``tell()``; stdout cannot seek.
    """

    def __init__(self, stream: IO[bytes]) -> None:
        self._stream = stream
        self._count = 0

    def write(self, data: bytes) -> int:
        self._stream.write(data)
        self._count += len(data)
        return len(data)

    def tell(self) -> int:
        return self._count

    def flush(self) -> None:
        self._stream.flush()


class McapWriter:
    """Writes one hbvs MCAP file: JSON messages on topics with registered schemas.

    Parameters
    ----------
    stream : binary stream with ``write``, ``tell`` and ``flush``
    chunk_size : int
        Bytes per chunk; each finished chunk is flushed to the stream, so a crash loses
        at most the chunk in progress.
    """

    def __init__(self, stream: Any, chunk_size: int = 1024 * 1024) -> None:
        from mcap.writer import CompressionType, Writer

        from .. import __version__

        self._stream = stream
        self._writer = Writer(stream, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        self._writer.start(profile=PROFILE, library=f"hbvs {__version__}")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._sequence = 0
        self._chunk_size = chunk_size
        self._finished = False

    def _channel(self, topic: str, schema_name: str) -> int:
        if topic in self._channels:
            return self._channels[topic]
        if schema_name not in self._schemas:
            schema = SCHEMAS[schema_name]
            self._schemas[schema_name] = self._writer.register_schema(
                name=schema_name, encoding="jsonschema", data=json.dumps(schema, separators=(",", ":")).encode()
            )
        channel_id = self._writer.register_channel(
            topic=topic, message_encoding="json", schema_id=self._schemas[schema_name]
        )
        self._channels[topic] = channel_id
        return channel_id

    def write(self, topic: str, schema_name: str, log_time_ns: int, message: dict[str, Any]) -> None:
        """Write one message, JSON-encoded."""
        self.write_encoded(topic, schema_name, log_time_ns, encode_json(message))

    def write_encoded(self, topic: str, schema_name: str, log_time_ns: int, data: bytes) -> None:
        """Write one message whose JSON bytes are already encoded (e.g. copied from input)."""
        channel_id = self._channel(topic, schema_name)
        self._writer.add_message(
            channel_id=channel_id, log_time=int(log_time_ns), publish_time=int(log_time_ns),
            data=data, sequence=self._sequence,
        )
        self._sequence += 1

    def metadata(self, name: str, values: dict[str, Any]) -> None:
        """A metadata record; values are stored as strings (dicts and lists as JSON)."""
        encoded = {
            str(k): v if isinstance(v, str) else json.dumps(json_ready(v), separators=(",", ":"))
            for k, v in values.items()
        }
        self._writer.add_metadata(name, encoded)

    def flush(self) -> None:
        """Finish the chunk in progress and push it to the stream (crash safety)."""
        self._writer.flush()

    def finish(self) -> None:
        """Write the summary and footer; the file is complete afterwards."""
        if not self._finished:
            self._writer.finish()
            self._stream.flush()
            self._finished = True


def partial_path(target: Path) -> Path:
    """Where an output file is written until it is complete."""
    return target.with_name(target.name + ".partial")


@contextmanager
def open_output(target: str | os.PathLike[str], chunk_size: int = 1024 * 1024, stdout: IO[bytes] | None = None) -> Iterator[McapWriter]:
    """An :class:`McapWriter` on a file (atomically) or on stdout (``"-"``).

    On success the file is complete and renamed into place; if the body raises (an
    error, KeyboardInterrupt, or the exception the CLI raises on SIGTERM), the partial
    file is removed and an existing output is left as it was. Only a hard crash, which
    runs no code, leaves the partial file behind.
    """
    if str(target) == "-":
        stream = CountingStream(stdout if stdout is not None else sys.stdout.buffer)
        writer = McapWriter(stream, chunk_size=chunk_size)
        yield writer
        writer.finish()
        return
    path = Path(target)
    if path.is_dir():
        raise InputError(f"{path}: is a directory; give a file name for the output")
    if not path.parent.exists():
        raise InputError(f"{path}: the folder {path.parent} does not exist")
    temporary = partial_path(path)
    try:
        handle = open(temporary, "wb")
    except OSError as exc:
        raise InputError(f"{path}: cannot write ({exc.strerror})") from None
    except BaseException:
        # A signal can land after open() created the file but before `handle` was bound.
        _remove_quietly(temporary)
        raise
    try:
        with handle:
            writer = McapWriter(handle, chunk_size=chunk_size)
            yield writer
            writer.finish()
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(temporary, path)
    except BaseException:
        _remove_quietly(temporary)
        raise


def _remove_quietly(path: Path) -> None:
    try:
        path.unlink()
    except OSError:
        pass


# ----------------------------------------------------------------------------- reading
#: The eight bytes that open (and close) every MCAP file.
MAGIC = b"\x89MCAP0\r\n"

# Opcodes of the MCAP records the reader acts on; every other record is skipped whole.
_OP_INVALID = 0x00
_OP_FOOTER = 0x02
_OP_SCHEMA = 0x03
_OP_CHANNEL = 0x04
_OP_MESSAGE = 0x05
_OP_CHUNK = 0x06
_OP_STATISTICS = 0x0B
_OP_METADATA = 0x0C

#: Bytes of the unsigned integers of MCAP records, by struct code.
_INTEGER_SIZES = {"H": 2, "I": 4, "Q": 8}
#: Opcode and length in front of every record.
_RECORD_HEAD = struct.Struct("<BQ")
#: Channel id, sequence, log time and publish time in front of a message's data.
_MESSAGE_HEAD = struct.Struct("<HIQQ")
#: A footer record (opcode, length, summary start, summary offset start, CRC) and the magic.
_FOOTER_TAIL = struct.Struct("<BQQQI8s")


class _Damaged(Exception):
    """The data stops making sense here; what was read before it is kept."""


@dataclass(frozen=True)
class _Schema:
    name: str
    encoding: str
    data: bytes


@dataclass(frozen=True)
class _Channel:
    topic: str
    message_encoding: str
    schema_id: int


class _Fields:
    """Reads the fields of one record in order, never past the record's end.

    The mcap library's parsers read inner lengths (a chunk's data, a metadata map, a
    string) straight from the file, so a record could declare 100 bytes and then ask for
    a terabyte; here every length is checked against the record it sits in.
    """

    __slots__ = ("_data", "_offset", "_what")

    def __init__(self, data: bytes | memoryview, what: str) -> None:
        self._data = memoryview(data)
        self._offset = 0
        self._what = what

    def _take(self, size: int) -> memoryview:
        end = self._offset + size
        if end > len(self._data):
            raise _Damaged(f"a {self._what} record is shorter than its fields declare")
        view = self._data[self._offset:end]
        self._offset = end
        return view

    def number(self, code: str) -> int:
        """One little-endian unsigned integer: ``"H"``, ``"I"`` or ``"Q"``."""
        return int.from_bytes(self._take(_INTEGER_SIZES[code]), "little")

    def blob(self, code: str) -> memoryview:
        """Bytes prefixed with their length (a ``code`` integer)."""
        return self._take(self.number(code))

    def string(self) -> str:
        try:
            return str(self.blob("I"), "utf-8")
        except UnicodeDecodeError:
            raise _Damaged(f"a {self._what} record holds a string that is not UTF-8") from None

    def string_map(self) -> dict[str, str]:
        """A map of strings prefixed with its length in bytes."""
        length = self.number("I")
        end = self._offset + length
        if end > len(self._data):
            raise _Damaged(f"a {self._what} record is shorter than its map declares")
        values: dict[str, str] = {}
        while self._offset < end:
            key = self.string()
            values[key] = self.string()
        if self._offset != end:
            raise _Damaged(f"a map in a {self._what} record overruns its declared length")
        return values


def _framed_records(data: bytes | memoryview, where: str) -> Iterator[tuple[int, memoryview]]:
    """``(opcode, body)`` of the records packed in a chunk or a summary section."""
    view = memoryview(data)
    offset = 0
    while offset < len(view):
        if offset + _RECORD_HEAD.size > len(view):
            raise _Damaged(f"{where} ends in the middle of a record")
        opcode, length = _RECORD_HEAD.unpack_from(view, offset)
        start = offset + _RECORD_HEAD.size
        if opcode == _OP_INVALID or start + length > len(view):
            raise _Damaged(f"a record in {where} has a damaged opcode or length")
        yield opcode, view[start:start + length]
        offset = start + length


def _read_up_to(stream: BinaryIO, size: int) -> bytes:
    """``size`` bytes, or fewer when the stream ends (pipes may return short reads)."""
    data = stream.read(size)
    if data is None or len(data) == size or not data:
        return data or b""
    parts = [data]
    missing = size - len(data)
    while missing > 0:
        part = stream.read(missing)
        if not part:
            break
        parts.append(part)
        missing -= len(part)
    return b"".join(parts)


class _Declarations:
    """The schemas and channels of a file read so far, under count and byte caps.

    Ids are 16-bit, so a hostile file could declare 65 536 schemas of 64 MiB each; real
    recordings have tens. ``charge`` also accounts for metadata, which shares the budget.
    """

    def __init__(self, name: str) -> None:
        self.name = name
        self.schemas: dict[int, _Schema] = {}
        self.channels: dict[int, _Channel] = {}
        self._sizes: dict[tuple[int, Any], int] = {}
        self._bytes = 0

    @property
    def empty(self) -> bool:
        return not self.schemas and not self.channels

    def charge(self, key: tuple[int, Any], size: int) -> None:
        """Account ``size`` bytes to ``key`` (replacing what it held before)."""
        self._bytes += size - self._sizes.get(key, 0)
        self._sizes[key] = size
        if self._bytes > MAX_DECLARED_BYTES:
            raise RecordingError(
                f"{self.name}: its schemas, channels and metadata exceed the {MAX_DECLARED_BYTES // 2**20} MiB "
                "hbvs accepts; not a recording hbvs can read"
            )

    def add(self, opcode: int, body: memoryview) -> None:
        """Keep a schema or channel record (anything else is ignored)."""
        if opcode == _OP_SCHEMA:
            fields = _Fields(body, "schema")
            schema_id = fields.number("H")
            schema = _Schema(name=fields.string(), encoding=fields.string(), data=bytes(fields.blob("I")))
            self._store(self.schemas, schema_id, schema, opcode, len(body), MAX_SCHEMAS, "schemas")
        elif opcode == _OP_CHANNEL:
            fields = _Fields(body, "channel")
            channel_id, schema_id = fields.number("H"), fields.number("H")
            channel = _Channel(topic=fields.string(), message_encoding=fields.string(), schema_id=schema_id)
            fields.string_map()  # validated, not needed
            self._store(self.channels, channel_id, channel, opcode, len(body), MAX_CHANNELS, "channels")

    def _store(self, table: dict[int, Any], key: int, value: Any, opcode: int, size: int, limit: int, what: str) -> None:
        if key not in table and len(table) >= limit:
            raise RecordingError(f"{self.name}: declares more than {limit} {what}; not a recording hbvs can read")
        self.charge((opcode, key), size)
        table[key] = value

    def channel_of(self, channel_id: int) -> tuple[_Channel, _Schema | None]:
        channel = self.channels.get(channel_id)
        if channel is None:
            raise RecordingError(f"{self.name}: a message refers to channel {channel_id}, which was never declared")
        schema = self.schemas.get(channel.schema_id)
        if channel.schema_id != 0 and schema is None:
            raise RecordingError(f"{self.name}: channel {channel.topic!r} refers to an undeclared schema")
        return channel, schema


@dataclass(frozen=True)
class McapMessage:
    """One message as read from a file, before decoding.

    Attributes
    ----------
    topic, schema_name, schema_encoding, message_encoding : str
    schema_data : bytes
    log_time : int
        Nanoseconds.
    data : bytes
    """

    topic: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes
    message_encoding: str
    log_time: int
    data: bytes

    def json(self, source: str = "") -> dict[str, Any]:
        """The message decoded as a JSON object; :class:`RecordingError` if it is not one.

        Size, number of values and nesting are capped (:func:`decode_json`).
        """
        if self.message_encoding != "json":
            raise RecordingError(f"{source}: message on {self.topic} is {self.message_encoding!r}, expected JSON")
        value = decode_json(self.data, f"{source}: message on {self.topic}")
        if not isinstance(value, dict):
            raise RecordingError(f"{source}: message on {self.topic} is not a JSON object")
        return value


@dataclass
class McapStream:
    """Iterate over the messages of an MCAP file or stream, in file order, safely.

    Parameters
    ----------
    source : str, path or binary stream
        ``"-"`` reads stdin.
    topics : set of str, optional
        Only these topics are yielded (others are still parsed, as they share chunks).
    name : str
        How to name the source in error messages.

    Attributes (filled while iterating)
    ----------
    metadata : dict
        Metadata records by name.
    truncated : bool
        The stream ended before the MCAP footer (a crashed writer), or became unreadable
        after some good records; everything up to the last complete record was yielded.
    stop_reason : str
        Why reading stopped early, when ``truncated``.
    messages : int
        Messages yielded.
    complete : bool
        The footer was reached.

    Raises
    ------
    InputError
        The file is missing or unreadable.
    RecordingError
        Not an MCAP file; damaged before any schema or channel; a record or chunk larger
        than :data:`MAX_RECORD_BYTES` / :data:`MAX_CHUNK_BYTES`; more schemas, channels or
        declared bytes than the caps; a message on an undeclared channel; an unsupported
        chunk compression.
    """

    source: Any
    topics: set[str] | None = None
    name: str = ""
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    truncated: bool = False
    messages: int = 0
    complete: bool = False
    stop_reason: str = ""

    def __post_init__(self) -> None:
        if not self.name:
            self.name = "stdin" if str(self.source) == "-" else str(self.source)

    def _open(self) -> tuple[BinaryIO, bool]:
        if str(self.source) == "-":
            return sys.stdin.buffer, False
        if isinstance(self.source, (str, os.PathLike)):
            path = Path(self.source)
            if not path.exists():
                raise InputError(f"{path}: no such file")
            if path.is_dir():
                raise InputError(f"{path}: is a directory, expected an MCAP file")
            try:
                return open(path, "rb"), True
            except OSError as exc:
                raise InputError(f"{path}: cannot read ({exc.strerror})") from None
        return self.source, False

    def __iter__(self) -> Iterator[McapMessage]:
        stream, owned = self._open()
        declarations = _Declarations(self.name)
        try:
            magic = _read_up_to(stream, len(MAGIC))
            if magic != MAGIC:
                raise RecordingError(f"{self.name}: not an MCAP file" + ("" if magic else " (it is empty)"))
            while True:
                try:
                    opcode, body = self._next_record(stream)
                    if opcode == _OP_FOOTER:
                        self.complete = True
                        return
                    if opcode == _OP_CHUNK:
                        for inner_opcode, inner in _framed_records(self._chunk_data(body), "a chunk"):
                            yield from self._record(inner_opcode, inner, declarations)
                    elif opcode == _OP_METADATA:
                        self._metadata(body, declarations)
                    else:
                        yield from self._record(opcode, body, declarations)
                except _Damaged as exc:
                    if self.messages == 0 and declarations.empty:
                        raise RecordingError(f"{self.name}: not a readable MCAP file ({exc})") from None
                    # Damage after good data is what a crashed writer leaves: keep what was read.
                    self.truncated = True
                    self.stop_reason = str(exc)
                    return
        except OSError as exc:
            raise InputError(f"{self.name}: cannot read ({exc.strerror or exc})") from None
        finally:
            if owned:
                stream.close()

    def _next_record(self, stream: BinaryIO) -> tuple[int, bytes]:
        head = _read_up_to(stream, _RECORD_HEAD.size)
        if len(head) < _RECORD_HEAD.size:
            raise _Damaged("the file ends before its footer" if not head else "the file ends in the middle of a record")
        opcode, length = _RECORD_HEAD.unpack(head)
        if opcode == _OP_INVALID:
            raise _Damaged("a record has the invalid opcode 0")
        if length > MAX_RECORD_BYTES:
            raise RecordingError(
                f"{self.name}: a record declares {length} bytes, more than the {MAX_RECORD_BYTES // 2**20} MiB hbvs accepts"
            )
        body = _read_up_to(stream, length)
        if len(body) < length:
            raise _Damaged("the file ends in the middle of a record")
        return opcode, body

    def _record(self, opcode: int, body: memoryview | bytes, declarations: _Declarations) -> Iterator[McapMessage]:
        if opcode != _OP_MESSAGE:
            declarations.add(opcode, memoryview(body))
            return
        if len(body) < _MESSAGE_HEAD.size:
            raise _Damaged("a message record is shorter than its header")
        channel_id, _sequence, log_time, _publish_time = _MESSAGE_HEAD.unpack_from(body)
        channel, schema = declarations.channel_of(channel_id)
        if self.topics is not None and channel.topic not in self.topics:
            return
        self.messages += 1
        yield McapMessage(
            topic=channel.topic,
            schema_name=schema.name if schema else "",
            schema_encoding=schema.encoding if schema else "",
            schema_data=schema.data if schema else b"",
            message_encoding=channel.message_encoding,
            log_time=int(log_time),
            data=bytes(body[_MESSAGE_HEAD.size:]),
        )

    def _metadata(self, body: bytes, declarations: _Declarations) -> None:
        fields = _Fields(body, "metadata")
        name = fields.string()
        values = fields.string_map()
        declarations.charge((_OP_METADATA, name), len(body))
        self.metadata[name] = values

    def _chunk_data(self, body: bytes) -> bytes:
        """The records of a chunk, decompressed under the size cap and checked."""
        fields = _Fields(body, "chunk")
        fields.number("Q")  # message start time
        fields.number("Q")  # message end time
        declared = fields.number("Q")
        crc = fields.number("I")
        compression = fields.string()
        records = fields.blob("Q")
        if declared > MAX_CHUNK_BYTES:
            raise RecordingError(
                f"{self.name}: a chunk declares {declared} bytes uncompressed, "
                f"more than the {MAX_CHUNK_BYTES // 2**20} MiB hbvs accepts"
            )
        try:
            data = _decompress_capped(compression, records, declared, self.name)
        except _DECOMPRESSION_ERRORS:
            raise _Damaged("a chunk cannot be decompressed") from None
        if len(data) != declared:
            raise _Damaged(f"a chunk holds {len(data)} bytes, not the {declared} it declares")
        if crc and zlib.crc32(data) != crc:
            raise _Damaged("a chunk fails its CRC check")
        return data


#: What damaged compressed data raises: zstandard.ZstdError and lz4's RuntimeError among them.
_DECOMPRESSION_ERRORS: tuple[type[BaseException], ...] = (ValueError, RuntimeError, EOFError, OSError, struct.error)
try:  # pragma: no cover - zstandard is a dependency of mcap
    import zstandard as _zstandard

    _DECOMPRESSION_ERRORS += (_zstandard.ZstdError,)
except ImportError:  # pragma: no cover
    pass


def _decompress_capped(compression: str, data: bytes | memoryview, declared: int, name: str) -> bytes:
    """Decompress a chunk, producing at most ``declared + 1`` bytes whatever its headers claim."""
    limit = declared + 1
    if compression == "":
        return bytes(data)
    if compression == "zstd":
        import zstandard

        # A streaming read bounds the output; one-shot decompression would trust the
        # frame header's content size (a hostile file could claim gigabytes).
        with zstandard.ZstdDecompressor().stream_reader(io.BytesIO(data), read_across_frames=True) as reader:
            return _read_up_to(reader, limit)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.LZ4FrameDecompressor().decompress(bytes(data), max_length=limit)
    raise RecordingError(f"{name}: unsupported chunk compression {compression[:40]!r}")


# ----------------------------------------------------------------------------- summary
@dataclass(frozen=True)
class ChannelSummary:
    """One channel as an MCAP file's summary section lists it.

    Attributes
    ----------
    topic, schema_name, schema_encoding, message_encoding : str
    message_count : int or None
        From the statistics record; None when the file has none.
    """

    topic: str
    schema_name: str
    schema_encoding: str
    message_encoding: str
    message_count: int | None


def read_summary(path: str | os.PathLike[str], name: str = "") -> list[ChannelSummary] | None:
    """The channels listed in the summary section of an MCAP file, read under the caps.

    Only the footer and the summary section are read, so this is cheap on a large file.

    Returns
    -------
    list of ChannelSummary, or None
        None when the file has no usable summary (a crashed writer never wrote one, or it
        is damaged): stream the file with :class:`McapStream` instead.

    Raises
    ------
    InputError
        The file cannot be read.
    RecordingError
        The summary declares more than the caps allow.
    """
    name = name or str(path)
    declarations = _Declarations(name)
    counts: dict[int, int] | None = None
    try:
        with open(path, "rb") as stream:
            size = stream.seek(0, os.SEEK_END)
            footer_at = size - _FOOTER_TAIL.size
            if footer_at < len(MAGIC):
                return None
            stream.seek(footer_at)
            opcode, length, start, _offsets, _crc, magic = _FOOTER_TAIL.unpack(_read_up_to(stream, _FOOTER_TAIL.size))
            if opcode != _OP_FOOTER or length != _FOOTER_TAIL.size - _RECORD_HEAD.size - len(MAGIC) or magic != MAGIC:
                return None
            if start == 0 or not len(MAGIC) <= start <= footer_at or footer_at - start > MAX_RECORD_BYTES:
                return None
            stream.seek(start)
            section = _read_up_to(stream, footer_at - start)
    except OSError as exc:
        raise InputError(f"{name}: cannot read ({exc.strerror or exc})") from None
    try:
        for opcode, body in _framed_records(section, "the summary section"):
            if opcode == _OP_STATISTICS:
                counts = _channel_message_counts(body)
            else:
                declarations.add(opcode, body)
    except _Damaged:
        return None
    if not declarations.channels:
        return None
    listed = []
    for channel_id, channel in declarations.channels.items():
        schema = declarations.schemas.get(channel.schema_id)
        listed.append(ChannelSummary(
            topic=channel.topic,
            schema_name=schema.name if schema else "",
            schema_encoding=schema.encoding if schema else "",
            message_encoding=channel.message_encoding,
            message_count=counts.get(channel_id, 0) if counts is not None else None,
        ))
    return listed


def _channel_message_counts(body: memoryview) -> dict[int, int]:
    """Messages per channel id, from a statistics record."""
    fields = _Fields(body, "statistics")
    for code in "QHIIIIQQ":  # message, schema, channel, attachment, metadata, chunk counts; times
        fields.number(code)
    packed = fields.blob("I")
    entry = struct.Struct("<HQ")
    if len(packed) % entry.size:
        raise _Damaged("a statistics record has a damaged channel count map")
    return {channel: count for channel, count in entry.iter_unpack(packed)}


# ----------------------------------------------------------------------------- JSON
#: Every byte but the brackets, commas and colons that give JSON its structure.
_NOT_JSON_STRUCTURE = bytes(sorted(set(range(256)) - set(b"[]{},:")))
#: A JSON string literal (escapes included), to blank out before counting brackets.
_JSON_STRING = re.compile(rb'"[^"\\]*(?:\\.[^"\\]*)*"', re.DOTALL)


def check_json_limits(data: bytes | str, what: str) -> None:
    """Refuse JSON whose size, number of values or nesting could exhaust memory or the stack.

    Counting structural bytes takes one pass (base64 image data holds none), and the
    nesting is only measured when there are enough brackets to exceed the cap.

    Raises
    ------
    RecordingError
        More than :data:`MAX_JSON_BYTES`, :data:`MAX_JSON_ITEMS` values or
        :data:`MAX_JSON_DEPTH` levels.
    """
    raw = data.encode("utf-8", "surrogatepass") if isinstance(data, str) else data
    if len(raw) > MAX_JSON_BYTES:
        raise RecordingError(f"{what}: {len(raw)} bytes of JSON, more than the {MAX_JSON_BYTES // 2**20} MiB hbvs accepts")
    structure = raw.translate(None, _NOT_JSON_STRUCTURE)
    containers = structure.count(b"[") + structure.count(b"{")
    if len(structure) > MAX_JSON_ITEMS:
        raise RecordingError(f"{what}: JSON with more than {MAX_JSON_ITEMS} values, more than hbvs accepts")
    if containers > MAX_JSON_DEPTH and _json_depth(raw) > MAX_JSON_DEPTH:
        raise RecordingError(f"{what}: JSON nested more than {MAX_JSON_DEPTH} levels deep")


def _json_depth(raw: bytes) -> int:
    """The deepest nesting of arrays and objects (brackets inside strings do not count)."""
    import numpy as np

    steps = np.zeros(256, dtype=np.int8)
    steps[[ord("["), ord("{")]] = 1
    steps[[ord("]"), ord("}")]] = -1
    marks = steps[np.frombuffer(_JSON_STRING.sub(b'""', raw), dtype=np.uint8)]
    marks = marks[marks != 0]
    return int(np.cumsum(marks, dtype=np.int64).max()) if marks.size else 0


def _bounded_int(text: str) -> int:
    # Every number hbvs reads becomes a float somewhere; an integer literal beyond float
    # range would raise OverflowError far from the file that held it.
    if len(text.lstrip("-")) > 308:
        raise ValueError("an integer literal with more than 308 digits")
    return int(text)


def decode_json(data: bytes | str, what: str) -> Any:
    """JSON text to Python values under :func:`check_json_limits`; :class:`RecordingError` if malformed."""
    check_json_limits(data, what)
    try:
        return json.loads(data, parse_int=_bounded_int)
    except (ValueError, UnicodeDecodeError, RecursionError) as exc:
        raise RecordingError(f"{what}: malformed JSON ({_short(exc)})") from None


def _short(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    return text.splitlines()[0][:120]


def read_metadata(stream: McapStream, name: str) -> dict[str, Any]:
    """A metadata record with its JSON values decoded (values that are not JSON stay strings)."""
    raw = stream.metadata.get(name)
    if raw is None:
        return {}
    decoded: dict[str, Any] = {}
    for key, value in raw.items():
        check_json_limits(value, f"{stream.name}: metadata {name}.{key}")
        try:
            decoded[key] = json.loads(value, parse_int=_bounded_int)
        except (ValueError, RecursionError):
            decoded[key] = value
    return decoded
