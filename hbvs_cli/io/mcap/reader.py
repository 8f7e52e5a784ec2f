"""Reading MCAP files record by record under caps, streaming, with truncated files read up to their last complete record."""

from __future__ import annotations

import io
import json
import os
import struct
import sys
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, Iterator

from ...errors import InputError, RecordingError
from .caps import MAX_CHANNELS, MAX_CHUNK_BYTES, MAX_DECLARED_BYTES, MAX_LOG_TIME_NS, MAX_RECORD_BYTES, MAX_SCHEMAS
from .json_codec import _bounded_int, _short, check_json_limits, decode_json


class _FieldTooLarge(Exception):
    """A record asked to read a field larger than any record hbvs accepts."""


class _CappedInput:
    """The input the mcap library reads from, refusing any single read above the cap.

    The library's record parsers read inner fields with the lengths the file declares
    (a chunk's data, a metadata map, a string), so a record could declare 100 bytes and
    then ask for a terabyte. Every read goes through here and is refused beyond
    :data:`MAX_RECORD_BYTES`; short reads from pipes are completed.
    """

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
        self.schemas: dict[int, Any] = {}
        self.channels: dict[int, Any] = {}
        self._sizes: dict[tuple[str, Any], int] = {}
        self._bytes = 0

    @property
    def empty(self) -> bool:
        return not self.schemas and not self.channels

    def charge(self, key: tuple[str, Any], size: int) -> None:
        """Account ``size`` bytes to ``key`` (replacing what it held before)."""
        self._bytes += size - self._sizes.get(key, 0)
        self._sizes[key] = size
        if self._bytes > MAX_DECLARED_BYTES:
            raise RecordingError(
                f"{self.name}: its schemas, channels and metadata exceed the {MAX_DECLARED_BYTES // 2**20} MiB "
                "hbvs accepts; not a recording hbvs can read"
            )

    def add_schema(self, schema: Any) -> None:
        size = len(schema.name) + len(schema.encoding) + len(schema.data)
        self._store(self.schemas, schema.id, schema, "schema", size, MAX_SCHEMAS, "schemas")

    def add_channel(self, channel: Any) -> None:
        size = len(channel.topic) + len(channel.message_encoding) + sum(len(k) + len(v) for k, v in channel.metadata.items())
        self._store(self.channels, channel.id, channel, "channel", size, MAX_CHANNELS, "channels")

    def _store(self, table: dict[int, Any], key: int, value: Any, kind: str, size: int, limit: int, what: str) -> None:
        if key not in table and len(table) >= limit:
            raise RecordingError(f"{self.name}: declares more than {limit} {what}; not a recording hbvs can read")
        self.charge((kind, key), size)
        table[key] = value

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
        """An ``hbvs.*`` message decoded as a JSON object under :func:`decode_json`'s caps;
        :class:`RecordingError` if it is not one."""
        if self.message_encoding != "json":
            raise RecordingError(f"{source}: message on {self.topic} is {self.message_encoding[:40]!r}, expected JSON")
        value = decode_json(self.data, f"{source}: message on {self.topic}")
        if not isinstance(value, dict):
            raise RecordingError(f"{source}: message on {self.topic} is not a JSON object")
        return value

    def foxglove(self, source: str = "") -> Any:
        """A ``foxglove.*`` message parsed with its ``foxglove-schemas-protobuf`` class;
        :class:`RecordingError` if it is not protobuf or does not parse."""
        from google.protobuf.message import DecodeError

        message_class = _foxglove_class(self.schema_name)
        if self.message_encoding != "protobuf" or message_class is None:
            raise RecordingError(
                f"{source}: message on {self.topic} is {self.message_encoding[:40]!r} {self.schema_name[:60]!r}, "
                "expected a protobuf foxglove message"
            )
        try:
            return message_class.FromString(self.data)
        except (DecodeError, ValueError, RuntimeError):
            raise RecordingError(f"{source}: malformed {self.schema_name} message on {self.topic}") from None


def _foxglove_class(schema_name: str) -> Any:
    """The protobuf class of a ``foxglove.<Name>`` schema, or None."""
    import importlib

    package, _, name = schema_name.partition(".")
    if package != "foxglove" or not name.isidentifier():
        return None
    try:
        return getattr(importlib.import_module(f"foxglove_schemas_protobuf.{name}_pb2"), name)
    except (ImportError, AttributeError):
        return None


@dataclass
class McapStream:
    """Iterate over the messages of an MCAP file or stream, in file order, safely.

    Parameters
    ----------
    source : str, path or binary stream
        ``"-"`` reads stdin.
    topics : set of str, optional
        Only these topics are yielded (others are still parsed, as they share chunks).
    schemas : dict of str to str, optional
        Topic to the schema name its messages must have. Only these topics are yielded
        (with ``topics``, only those in both), and a message under another schema is refused.
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
        chunk compression; a message whose schema is not the one ``schemas`` expects.
    """

    source: Any
    topics: set[str] | None = None
    name: str = ""
    schemas: dict[str, str] | None = None
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    truncated: bool = False
    messages: int = 0
    complete: bool = False
    stop_reason: str = ""
    _messages_read: int = field(default=0, repr=False)
    _bytes_read: int = field(default=0, repr=False)

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
        from mcap.exceptions import EndOfFile, InvalidMagic, McapError, RecordLengthLimitExceeded
        from mcap.records import Channel, Chunk, Footer, Message, Metadata, Schema
        from mcap.stream_reader import StreamReader, breakup_chunk

        stream, owned = self._open()
        declarations = _Declarations(self.name)
        # The mcap library parses the records; chunks are left to us (emit_chunks) so that
        # they are decompressed under the cap before the library splits them.
        reader = StreamReader(
            _CappedInput(stream), skip_magic=False, emit_chunks=True, validate_crcs=True,
            record_size_limit=MAX_RECORD_BYTES,
        )
        records = reader.records
        damage = (McapError, _FieldTooLarge, ValueError, struct.error, UnicodeDecodeError, OverflowError, KeyError)
        try:
            while True:
                try:
                    record = next(records)
                    if isinstance(record, Message):
                        self._count_message()
                    if not isinstance(record, Chunk):
                        self._count_bytes(_record_size(record))
                    inner = self._chunk_records(record, breakup_chunk) if isinstance(record, Chunk) else [record]
                    for item in inner:
                        if isinstance(item, Message):
                            yield from self._message(item, declarations)
                        elif isinstance(item, Schema):
                            declarations.add_schema(item)
                        elif isinstance(item, Channel):
                            declarations.add_channel(item)
                    if isinstance(record, Metadata):
                        declarations.charge(("metadata", record.name), len(record.name) + sum(len(k) + len(v) for k, v in record.metadata.items()))
                        self.metadata[record.name] = dict(record.metadata)
                    elif isinstance(record, Footer):
                        self.complete = True
                        return
                except StopIteration:
                    self.complete = True
                    return
                except RecordLengthLimitExceeded as exc:
                    raise RecordingError(
                        f"{self.name}: a record declares more than the {MAX_RECORD_BYTES // 2**20} MiB hbvs accepts ({_short(exc)})"
                    ) from None
                except InvalidMagic:
                    if self.messages == 0 and declarations.empty:
                        raise RecordingError(f"{self.name}: not an MCAP file") from None
                    self._stop("the file's closing magic is damaged")
                    return
                except (EndOfFile, EOFError):
                    if self.messages == 0 and declarations.empty and not self.metadata:
                        raise RecordingError(f"{self.name}: not an MCAP file, or empty") from None
                    # What a crashed writer leaves: keep everything up to here.
                    self._stop("the file ends before its footer")
                    return
                except _Damaged as exc:
                    if self.messages == 0 and declarations.empty:
                        raise RecordingError(f"{self.name}: not a readable MCAP file ({exc})") from None
                    self._stop(str(exc))
                    return
                except damage as exc:
                    if self.messages == 0 and declarations.empty:
                        raise RecordingError(f"{self.name}: not a readable MCAP file ({_short(exc)})") from None
                    # Damage after good data: keep what was read, as for a crashed writer.
                    self._stop(f"damaged data ({_short(exc)})")
                    return
        except OSError as exc:
            raise InputError(f"{self.name}: cannot read ({exc.strerror or exc})") from None
        finally:
            if owned:
                stream.close()

    def _stop(self, reason: str) -> None:
        self.truncated = True
        self.stop_reason = reason

    def _message(self, record: Any, declarations: _Declarations) -> Iterator[McapMessage]:
        channel, schema = declarations.channel_of(record.channel_id)
        if self.topics is not None and channel.topic not in self.topics:
            return
        if self.schemas is not None:
            expected = self.schemas.get(channel.topic)
            if expected is None:
                return
            found = schema.name if schema else ""
            if found != expected:
                raise RecordingError(f"{self.name}: topic {channel.topic} has schema {found!r}, expected {expected!r}")
        if record.log_time > MAX_LOG_TIME_NS:
            raise RecordingError(
                f"{self.name}: a message on {channel.topic} is stamped {record.log_time} ns, later than hbvs handles "
                f"({MAX_LOG_TIME_NS} ns, in the year 2262)"
            )
        self.messages += 1
        yield McapMessage(
            topic=channel.topic,
            schema_name=schema.name if schema else "",
            schema_encoding=schema.encoding if schema else "",
            schema_data=bytes(schema.data) if schema else b"",
            message_encoding=channel.message_encoding,
            log_time=int(record.log_time),
            data=bytes(record.data),
        )

    def _chunk_records(self, chunk: Any, breakup_chunk: Any) -> Iterator[Any]:
        """The records of a chunk, decompressed under the size cap, CRC-checked, then split
        one at a time (:meth:`_chunk_items`)."""
        declared = chunk.uncompressed_size
        if declared > MAX_CHUNK_BYTES:
            raise RecordingError(
                f"{self.name}: a chunk declares {declared} bytes uncompressed, "
                f"more than the {MAX_CHUNK_BYTES // 2**20} MiB hbvs accepts"
            )
        try:
            data = _decompress_capped(chunk.compression, chunk.data, declared, self.name)
        except _DECOMPRESSION_ERRORS:
            raise _Damaged("a chunk cannot be decompressed") from None
        if len(data) != declared:
            raise _Damaged(f"a chunk holds {len(data)} bytes, not the {declared} it declares")
        if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
            raise _Damaged("a chunk fails its CRC check")
        self._count_bytes(len(data))
        return self._chunk_items(data)

    def _chunk_items(self, data: bytes) -> Iterator[Any]:
        """The schema, channel and message records of a decompressed chunk, parsed one at a
        time by the mcap library's record parsers (its ``breakup_chunk`` builds them all as
        one list, which a small chunk of millions of empty messages turns into gigabytes), and counted
        against the ``chunk-messages`` and ``messages`` limits."""
        from mcap.data_stream import ReadDataStream
        from mcap.opcode import Opcode
        from mcap.records import Channel, Message, Schema

        from .. import limits

        stream = ReadDataStream(io.BytesIO(data))
        length_of_data = len(data)
        in_chunk = 0
        chunk_limit = limits.current("chunk-messages")
        while stream.count < length_of_data:
            opcode = stream.read1()
            length = stream.read8()
            if opcode == Opcode.MESSAGE:
                in_chunk += 1
                if in_chunk > chunk_limit:
                    raise limits.exceeded("chunk-messages", None, f"{self.name}: a chunk's number of messages")
                self._count_message()
                yield Message.read(stream, length)
            elif opcode == Opcode.CHANNEL:
                yield Channel.read(stream)
            elif opcode == Opcode.SCHEMA:
                yield Schema.read(stream)
            else:
                if length > length_of_data:
                    raise _Damaged("a record inside a chunk is longer than the chunk")
                stream.read(length)

    def _count_message(self) -> None:
        from .. import limits

        self._messages_read += 1
        if self._messages_read > limits.current("messages"):
            raise limits.exceeded("messages", None, f"{self.name}: the number of messages")

    def _count_bytes(self, size: int) -> None:
        from .. import limits

        self._bytes_read += size
        if self._bytes_read > limits.current("input-bytes"):
            raise limits.exceeded("input-bytes", None, f"{self.name}: the data (after decompression)")


def _record_size(record: Any) -> int:
    """Bytes a record outside a chunk holds (its data, or 64 for one without): for the
    ``input-bytes`` limit."""
    data = getattr(record, "data", None)
    return len(data) if isinstance(data, (bytes, bytearray, memoryview)) else 64


class _Damaged(Exception):
    """The data stops making sense here; what was read before it is kept."""


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
