"""Reading and writing MCAP files safely: capped, streaming, atomic.

MCAP framing is the ``mcap`` library's; this module adds what hbvs promises on top:

* **Streaming both ways**: every stage reads a file or stdin (``-``) front to back in
  constant memory, and writes a file or stdout. The mcap ``Writer`` calls ``tell()``, which
  a pipe does not have, so stdout is wrapped in :class:`CountingStream`.
* **Atomic output**: a file is written as ``FILE.partial`` and renamed over ``FILE`` only
  when it is finished; a failed or interrupted command leaves any previous ``FILE``
  untouched. After a crash, the ``.partial`` file holds every chunk flushed so far and is
  itself readable (nothing recorded is lost).
* **Hostile input**: declared record sizes and decompressed chunk sizes are capped before
  anything is allocated, chunks are decompressed here with that cap, and nothing is ever
  unpickled or evaluated: messages are JSON (or CDR decoded by mcap-ros2-support).
* **Truncated files** (a crashed recorder: no summary, no footer, half a chunk) are read up
  to the last complete record; :attr:`McapStream.truncated` tells the caller.
"""

from __future__ import annotations

import json
import math
import io
import os
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

    On success the file is complete and renamed into place; if the body raises, the
    partial file is removed (except after a crash, which cannot run this code) and an
    existing output is left as it was.
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
    try:
        with handle:
            writer = McapWriter(handle, chunk_size=chunk_size)
            yield writer
            writer.finish()
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(temporary, path)
    except BaseException:
        try:
            temporary.unlink()
        except OSError:
            pass
        raise


# ----------------------------------------------------------------------------- reading
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
        """The message decoded as a JSON object; :class:`RecordingError` if it is not."""
        if self.message_encoding != "json":
            raise RecordingError(f"{source}: message on {self.topic} is {self.message_encoding!r}, expected JSON")
        try:
            value = json.loads(self.data)
        except (ValueError, UnicodeDecodeError) as exc:
            raise RecordingError(f"{source}: malformed JSON message on {self.topic} ({exc})") from None
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
        The stream ended before the MCAP footer (a crashed writer); everything up to the
        last complete record was yielded.
    messages : int
        Messages yielded.
    """

    source: Any
    topics: set[str] | None = None
    name: str = ""
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    truncated: bool = False
    messages: int = 0
    complete: bool = False

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
        from mcap.exceptions import EndOfFile, InvalidMagic, McapError
        from mcap.records import Channel, Chunk, Footer, Message, Metadata, Schema
        from mcap.stream_reader import StreamReader

        stream, owned = self._open()
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        try:
            reader = StreamReader(stream, skip_magic=False, emit_chunks=True, validate_crcs=True, record_size_limit=MAX_RECORD_BYTES)
            records = reader.records
            while True:
                try:
                    record = next(records)
                except StopIteration:
                    self.complete = True
                    return
                except InvalidMagic:
                    if self.messages == 0 and not channels:
                        raise RecordingError(f"{self.name}: not an MCAP file") from None
                    self.truncated = True
                    return
                except (EndOfFile, EOFError):
                    if self.messages == 0 and not channels and not schemas:
                        raise RecordingError(f"{self.name}: not an MCAP file, or empty") from None
                    self.truncated = True
                    return
                except (McapError, ValueError, struct.error, UnicodeDecodeError, zlib.error, OverflowError) as exc:
                    if self.messages == 0 and not channels and not schemas:
                        raise RecordingError(f"{self.name}: not a readable MCAP file ({_short(exc)})") from None
                    # Damage after good data: keep what was read, as for a crashed writer.
                    self.truncated = True
                    return
                if isinstance(record, Chunk):
                    inner = self._chunk_records(record)
                    if inner is None:
                        self.truncated = True
                        return
                    for item in inner:
                        yield from self._handle(item, schemas, channels)
                elif isinstance(record, Metadata):
                    self.metadata[record.name] = dict(record.metadata)
                elif isinstance(record, Footer):
                    self.complete = True
                    return
                else:
                    yield from self._handle(record, schemas, channels)
        finally:
            if owned:
                stream.close()

    def _handle(self, record: Any, schemas: dict[int, Any], channels: dict[int, Any]) -> Iterator[McapMessage]:
        from mcap.records import Channel, Message, Schema

        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Message):
            channel = channels.get(record.channel_id)
            if channel is None:
                raise RecordingError(f"{self.name}: a message refers to channel {record.channel_id}, which was never declared")
            if self.topics is not None and channel.topic not in self.topics:
                return
            schema = schemas.get(channel.schema_id)
            if channel.schema_id != 0 and schema is None:
                raise RecordingError(f"{self.name}: channel {channel.topic} refers to an undeclared schema")
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

    def _chunk_records(self, chunk: Any) -> list[Any] | None:
        """Records of a chunk, decompressed under the size cap; None if the chunk is damaged."""
        from mcap.exceptions import McapError
        from mcap.records import Chunk
        from mcap.stream_reader import breakup_chunk

        if chunk.uncompressed_size > MAX_CHUNK_BYTES:
            raise RecordingError(
                f"{self.name}: a chunk declares {chunk.uncompressed_size} bytes uncompressed, "
                f"more than the {MAX_CHUNK_BYTES // 2**20} MiB hbvs accepts"
            )
        try:
            data = _decompress_capped(chunk.compression, chunk.data, chunk.uncompressed_size, self.name)
        except _DECOMPRESSION_ERRORS:
            return None
        if data is None or len(data) != chunk.uncompressed_size:
            return None
        if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
            return None
        plain = Chunk(
            compression="", data=data, message_start_time=chunk.message_start_time,
            message_end_time=chunk.message_end_time, uncompressed_crc=0, uncompressed_size=len(data),
        )
        try:
            return breakup_chunk(plain, validate_crc=False)
        except (McapError, ValueError, struct.error, UnicodeDecodeError, EOFError):
            return None


#: What damaged compressed data raises: zstandard.ZstdError and lz4's RuntimeError among them.
_DECOMPRESSION_ERRORS: tuple[type[BaseException], ...] = (ValueError, RuntimeError, EOFError, OSError, struct.error)
try:  # pragma: no cover - zstandard is a dependency of mcap
    import zstandard as _zstandard

    _DECOMPRESSION_ERRORS += (_zstandard.ZstdError,)
except ImportError:  # pragma: no cover
    pass


def _decompress_capped(compression: str, data: bytes, declared: int, name: str) -> bytes | None:
    """Decompress a chunk, producing at most ``declared + 1`` bytes whatever its headers claim."""
    limit = declared + 1
    if compression == "":
        return bytes(data)
    if compression == "zstd":
        import zstandard

        # A streaming read bounds the output; one-shot decompression would trust the
        # frame header's content size (a hostile file could claim gigabytes).
        with zstandard.ZstdDecompressor().stream_reader(io.BytesIO(data), read_across_frames=True) as reader:
            return reader.read(limit)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=limit)
    raise RecordingError(f"{name}: unsupported chunk compression {compression!r}")


def _short(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    return text.splitlines()[0][:120]


def read_metadata(stream: McapStream, name: str) -> dict[str, Any]:
    """A metadata record with its JSON values decoded (strings stay strings)."""
    raw = stream.metadata.get(name)
    if raw is None:
        return {}
    decoded: dict[str, Any] = {}
    for key, value in raw.items():
        try:
            decoded[key] = json.loads(value)
        except ValueError:
            decoded[key] = value
    return decoded
