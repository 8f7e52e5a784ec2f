"""Reading MCAP files as streams, under caps, keeping what a truncated file holds.

The ``mcap`` library parses the records; hbvs caps every read before it allocates, decompresses chunks
under a cap, counts against :mod:`..limits`, and ends the stream at damage after good data (a crashed
recorder) with :attr:`McapStream.truncated` instead of an error."""

from __future__ import annotations

import io
import json
import os
import struct
import sys
import zlib
from contextlib import suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, Iterator

from ...errors import InputError, RecordingError
from .. import limits
from .caps import MAX_CHANNELS, MAX_CHUNK_BYTES, MAX_DECLARED_BYTES, MAX_LOG_TIME_NS, MAX_RECORD_BYTES, MAX_SCHEMAS
from .json_codec import _bounded_int, _short, check_json_limits, decode_json


class _FieldTooLarge(Exception):
    """A record asked to read a field larger than any record hbvs accepts."""


class _Damaged(Exception):
    """The data stops making sense here; what was read before it is kept."""


class _CappedInput:
    """The stream the mcap library reads: reads above :data:`MAX_RECORD_BYTES` refused, short pipe reads completed."""

    def __init__(self, raw: BinaryIO) -> None:
        self._raw = raw

    def read(self, size: int = -1) -> bytes:
        if size is None or size < 0 or size > MAX_RECORD_BYTES:
            raise _FieldTooLarge(f"a field declares {size} bytes, more than any record hbvs accepts")
        return _read_up_to(self._raw, size)

    def seek(self, offset: int, whence: int = 0) -> int:
        return self._raw.seek(offset, whence)

    def tell(self) -> int:
        return self._raw.tell()


def _read_up_to(stream: Any, size: int) -> bytes:
    """``size`` bytes, or fewer when the stream ends."""
    parts, missing = [], size
    while missing > 0:
        part = stream.read(missing)
        if not part:
            break
        parts.append(part)
        missing -= len(part)
    return b"".join(parts)


class _Declarations:
    """The schemas and channels read so far, capped in number and, with the metadata, in bytes."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.schemas: dict[int, Any] = {}
        self.channels: dict[int, Any] = {}
        self._sizes: dict[tuple[str, Any], int] = {}
        self._bytes = 0

    def charge(self, key: tuple[str, Any], size: int) -> None:
        """Account ``size`` bytes to ``key`` (replacing what it held before)."""
        self._bytes += size - self._sizes.get(key, 0)
        self._sizes[key] = size
        if self._bytes > MAX_DECLARED_BYTES:
            raise RecordingError(
                f"{self.name}: its schemas, channels and metadata exceed the {MAX_DECLARED_BYTES // 2**20} MiB "
                "hbvs accepts; not a recording hbvs can read"
            )

    def add(self, record: Any) -> None:
        """Keep a Schema or Channel record."""
        from mcap.records import Schema

        if isinstance(record, Schema):
            table, kind, limit = self.schemas, "schemas", MAX_SCHEMAS
            size = len(record.name) + len(record.encoding) + len(record.data)
        else:
            table, kind, limit = self.channels, "channels", MAX_CHANNELS
            size = len(record.topic) + len(record.message_encoding) + sum(len(k) + len(v) for k, v in record.metadata.items())
        if record.id not in table and len(table) >= limit:
            raise RecordingError(f"{self.name}: declares more than {limit} {kind}; not a recording hbvs can read")
        self.charge((kind, record.id), size)
        table[record.id] = record

    def channel_of(self, channel_id: int) -> tuple[Any, Any]:
        channel = self.channels.get(channel_id)
        if channel is None:
            raise RecordingError(f"{self.name}: a message refers to channel {channel_id}, which was never declared")
        schema = self.schemas.get(channel.schema_id)
        if channel.schema_id != 0 and schema is None:
            raise RecordingError(f"{self.name}: channel {channel.topic!r} refers to an undeclared schema")
        return channel, schema


@dataclass(frozen=True)
class McapMessage:
    """One message as read from a file, before decoding (``log_time`` in ns)."""

    topic: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes
    message_encoding: str
    log_time: int
    data: bytes

    def json(self, source: str = "") -> dict[str, Any]:
        """An ``hbvs.*`` message as a JSON object; :class:`RecordingError` if it is not one."""
        if self.message_encoding != "json":
            raise RecordingError(f"{source}: message on {self.topic} is {self.message_encoding[:40]!r}, expected JSON")
        value = decode_json(self.data, f"{source}: message on {self.topic}")
        if not isinstance(value, dict):
            raise RecordingError(f"{source}: message on {self.topic} is not a JSON object")
        return value

    def foxglove(self, source: str = "") -> Any:
        """A ``foxglove.*`` message as its protobuf class; :class:`RecordingError` if it is not one."""
        import importlib

        from google.protobuf.message import DecodeError

        # foxglove.<Name> is the class <Name> of foxglove_schemas_protobuf.<Name>_pb2.
        package, _, name = self.schema_name.partition(".")
        message_class = None
        if package == "foxglove" and name.isidentifier():
            with suppress(ImportError, AttributeError):
                message_class = getattr(importlib.import_module(f"foxglove_schemas_protobuf.{name}_pb2"), name)
        if self.message_encoding != "protobuf" or message_class is None:
            raise RecordingError(
                f"{source}: message on {self.topic} is {self.message_encoding[:40]!r} {self.schema_name[:60]!r}, "
                "expected a protobuf foxglove message"
            )
        try:
            return message_class.FromString(self.data)
        except (DecodeError, ValueError, RuntimeError):
            raise RecordingError(f"{source}: malformed {self.schema_name} message on {self.topic}") from None


@dataclass
class ChannelSummary:
    """A topic's channel as a file's summary section lists it (``message_count`` None without statistics)
    or as :class:`McapStream` read it (then also its first and last log times, ns); also a ROS 2 bag's topic."""

    topic: str
    schema_name: str
    schema_encoding: str
    message_encoding: str
    message_count: int | None
    first_ns: int = 0
    last_ns: int = 0


#: What the library raises on damaged data, beyond its own McapError (added in __iter__).
_DAMAGE = (_FieldTooLarge, ValueError, struct.error, UnicodeDecodeError, OverflowError, KeyError, EOFError)


@dataclass
class McapStream:
    """The messages of an MCAP file, stream or stdin (``"-"``), in file order, in constant memory.

    ``topics`` selects topics; ``schemas`` (topic -> schema name) selects them too and refuses another
    schema. ``truncated`` and ``stop_reason``: the file ended or turned unreadable after good records."""

    source: Any
    topics: set[str] | None = None
    name: str = ""
    schemas: dict[str, str] | None = None
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    truncated: bool = False
    complete: bool = False
    stop_reason: str = ""
    #: The topics read, each with the schema of its first message and the count of all.
    channels: dict[str, ChannelSummary] = field(default_factory=dict)
    _counts: dict[str, int] = field(default_factory=lambda: {"messages": 0, "input-bytes": 0}, repr=False)

    def __post_init__(self) -> None:
        if not self.name:
            self.name = "stdin" if str(self.source) == "-" else str(self.source)

    def _open(self) -> tuple[BinaryIO, bool]:
        if str(self.source) == "-":
            return sys.stdin.buffer, False
        if not isinstance(self.source, (str, os.PathLike)):
            return self.source, False
        path = Path(self.source)
        if not path.exists():
            raise InputError(f"{path}: no such file")
        if path.is_dir():
            raise InputError(f"{path}: is a directory, expected an MCAP file")
        try:
            return open(path, "rb"), True
        except OSError as exc:
            raise InputError(f"{path}: cannot read ({exc.strerror})") from None

    def __iter__(self) -> Iterator[McapMessage]:
        from mcap.exceptions import EndOfFile, InvalidMagic, McapError, RecordLengthLimitExceeded
        from mcap.records import Channel, Chunk, Footer, Message, Metadata, Schema
        from mcap.stream_reader import StreamReader

        stream, owned = self._open()
        declarations = _Declarations(self.name)
        reader = StreamReader(_CappedInput(stream), emit_chunks=True, validate_crcs=True, record_size_limit=MAX_RECORD_BYTES)
        records = reader.records
        try:
            while True:
                try:
                    record = next(records, None)
                    if record is None or isinstance(record, Footer):
                        self.complete = True
                        return
                    if isinstance(record, Chunk):
                        inner: Any = self._chunk_records(record)
                    else:
                        if isinstance(record, Message):
                            self._count("messages", 1, "the number of messages")
                        data = getattr(record, "data", None)
                        self._count("input-bytes", len(data) if isinstance(data, (bytes, memoryview)) else 64, "the data (after decompression)")
                        inner = [record]
                    for item in inner:
                        if isinstance(item, Message):
                            yield from self._message(item, declarations)
                        elif isinstance(item, Metadata):
                            declarations.charge(("metadata", item.name), len(item.name) + sum(len(k) + len(v) for k, v in item.metadata.items()))
                            self.metadata[item.name] = dict(item.metadata)
                        elif isinstance(item, (Schema, Channel)):
                            declarations.add(item)
                except RecordLengthLimitExceeded as exc:
                    raise RecordingError(
                        f"{self.name}: a record declares more than the {MAX_RECORD_BYTES // 2**20} MiB hbvs accepts ({_short(exc)})"
                    ) from None
                except (McapError, _Damaged, *_DAMAGE) as exc:
                    empty = not self.channels and not declarations.schemas and not declarations.channels
                    if isinstance(exc, InvalidMagic):
                        reason, refusal = "the file's closing magic is damaged", "not an MCAP file"
                    elif isinstance(exc, (EndOfFile, EOFError)):
                        # What a crashed writer leaves: keep everything up to here.
                        reason, refusal = "the file ends before its footer", "not an MCAP file, or empty"
                        empty = empty and not self.metadata
                    elif isinstance(exc, _Damaged):
                        reason, refusal = str(exc), f"not a readable MCAP file ({exc})"
                    else:
                        reason, refusal = f"damaged data ({_short(exc)})", f"not a readable MCAP file ({_short(exc)})"
                    if empty:
                        raise RecordingError(f"{self.name}: {refusal}") from None
                    self.truncated, self.stop_reason = True, reason
                    return
        except OSError as exc:
            raise InputError(f"{self.name}: cannot read ({exc.strerror or exc})") from None
        finally:
            if owned:
                stream.close()

    def _message(self, record: Any, declarations: _Declarations) -> Iterator[McapMessage]:
        channel, schema = declarations.channel_of(record.channel_id)
        if self.topics is not None and channel.topic not in self.topics:
            return
        schema_name = schema.name if schema else ""
        if self.schemas is not None:
            expected = self.schemas.get(channel.topic)
            if expected is None:
                return
            if schema_name != expected:
                raise RecordingError(f"{self.name}: topic {channel.topic} has schema {schema_name!r}, expected {expected!r}")
        if record.log_time > MAX_LOG_TIME_NS:
            raise RecordingError(
                f"{self.name}: a message on {channel.topic} is stamped {record.log_time} ns, later than hbvs handles "
                f"({MAX_LOG_TIME_NS} ns, in the year 2262)"
            )
        message = McapMessage(
            topic=channel.topic, schema_name=schema_name, schema_encoding=schema.encoding if schema else "",
            schema_data=bytes(schema.data) if schema else b"", message_encoding=channel.message_encoding,
            log_time=int(record.log_time), data=bytes(record.data),
        )
        seen = self.channels.get(message.topic)
        if seen is None:
            seen = self.channels[message.topic] = ChannelSummary(
                message.topic, message.schema_name, message.schema_encoding, message.message_encoding, 0,
                first_ns=message.log_time, last_ns=message.log_time,
            )
        seen.message_count = (seen.message_count or 0) + 1
        seen.first_ns = min(seen.first_ns, message.log_time)
        seen.last_ns = max(seen.last_ns, message.log_time)
        yield message

    def _chunk_records(self, chunk: Any) -> Iterator[Any]:
        """The records of a chunk, decompressed under :data:`MAX_CHUNK_BYTES`, CRC-checked, and
        parsed one at a time (a few KB of zstd can hold millions of empty messages)."""
        from mcap.data_stream import ReadDataStream
        from mcap.opcode import Opcode
        from mcap.records import Channel, Message, Schema

        declared = chunk.uncompressed_size
        if declared > MAX_CHUNK_BYTES:
            raise RecordingError(
                f"{self.name}: a chunk declares {declared} bytes uncompressed, more than the {MAX_CHUNK_BYTES // 2**20} MiB hbvs accepts"
            )
        import zstandard

        try:
            data = _decompress_capped(chunk.compression, chunk.data, declared, self.name)
        except (ValueError, RuntimeError, EOFError, OSError, struct.error, zstandard.ZstdError):  # lz4 raises RuntimeError
            raise _Damaged("a chunk cannot be decompressed") from None
        if len(data) != declared:
            raise _Damaged(f"a chunk holds {len(data)} bytes, not the {declared} it declares")
        if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
            raise _Damaged("a chunk fails its CRC check")
        self._count("input-bytes", len(data), "the data (after decompression)")
        stream = ReadDataStream(io.BytesIO(data))
        in_chunk, chunk_limit = 0, limits.current("chunk-messages")
        while stream.count < len(data):
            opcode, length = stream.read1(), stream.read8()
            if opcode == Opcode.MESSAGE:
                in_chunk += 1
                if in_chunk > chunk_limit:
                    raise limits.exceeded("chunk-messages", None, f"{self.name}: a chunk's number of messages")
                self._count("messages", 1, "the number of messages")
                yield Message.read(stream, length)
            elif opcode == Opcode.CHANNEL:
                yield Channel.read(stream)
            elif opcode == Opcode.SCHEMA:
                yield Schema.read(stream)
            elif length > len(data):
                raise _Damaged("a record inside a chunk is longer than the chunk")
            else:
                stream.read(length)

    def _count(self, limit: str, amount: int, what: str) -> None:
        self._counts[limit] += amount
        if self._counts[limit] > limits.current(limit):
            raise limits.exceeded(limit, None, f"{self.name}: {what}")


def _decompress_capped(compression: str, data: bytes | memoryview, declared: int, name: str) -> bytes:
    """Decompress a chunk into at most ``declared + 1`` bytes, whatever its frame headers claim."""
    if compression == "":
        return bytes(data)
    if compression == "zstd":
        import zstandard

        # A streaming read bounds the output; one-shot decompression trusts the frame header.
        with zstandard.ZstdDecompressor().stream_reader(io.BytesIO(data), read_across_frames=True) as reader:
            return _read_up_to(reader, declared + 1)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.LZ4FrameDecompressor().decompress(bytes(data), max_length=declared + 1)
    raise RecordingError(f"{name}: unsupported chunk compression {compression[:40]!r}")


def read_metadata(stream: McapStream, name: str) -> dict[str, Any]:
    """A metadata record with its JSON values decoded (values that are not JSON stay strings)."""
    decoded: dict[str, Any] = {}
    for key, value in stream.metadata.get(name, {}).items():
        check_json_limits(value, f"{stream.name}: metadata {name}.{key}")
        try:
            decoded[key] = json.loads(value, parse_int=_bounded_int)
        except (ValueError, RecursionError):
            decoded[key] = value
    return decoded


def read_summary(path: str | os.PathLike[str]) -> list[ChannelSummary] | None:
    """The channels of an MCAP file's summary section, or None when it has no usable one."""
    from mcap.exceptions import McapError
    from mcap.reader import SeekingReader

    try:
        with open(path, "rb") as stream:
            summary = SeekingReader(_CappedInput(stream), record_size_limit=MAX_RECORD_BYTES).get_summary()
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    except (McapError, *_DAMAGE):
        return None
    if summary is None or not summary.channels:
        return None
    declarations = _Declarations(str(path))
    for record in (*summary.schemas.values(), *summary.channels.values()):
        declarations.add(record)
    counts = dict(summary.statistics.channel_message_counts) if summary.statistics is not None else None
    listed = []
    for channel_id, channel in declarations.channels.items():
        schema = declarations.schemas.get(channel.schema_id)
        listed.append(ChannelSummary(
            topic=channel.topic, schema_name=schema.name if schema else "", schema_encoding=schema.encoding if schema else "",
            message_encoding=channel.message_encoding, message_count=counts.get(channel_id, 0) if counts is not None else None,
        ))
    return listed
