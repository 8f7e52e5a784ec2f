"""The storage side of a ROS 2 bag: its topics and its messages, decoded on demand, under hbvs's size caps.

:class:`RosbagsBag` reads a bag folder with ``rosbags``' ``AnyReader``; :class:`McapFileBag` reads
``.mcap`` file(s) without ``metadata.yaml`` (ROS 2 bags, Foxglove protobuf recordings such as hbvs's own)."""

from __future__ import annotations

import contextlib
import io
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import yaml

from ...errors import HbvsError, InputError, RecordingError
from .. import limits
from ..mcap import MAGIC, MAX_RECORD_BYTES, ChannelSummary, McapMessage, McapStream, read_summary
from .frame_source import _natural_key

#: Largest message definition and metadata.yaml read (real ones are ~10 KB).
MAX_SCHEMA_BYTES = 1 << 20
MAX_METADATA_BYTES = 1 << 20


@dataclass
class BagMessage:
    """One message: topic, log time (ns), size, how to decode it, and for :class:`McapFileBag`
    the raw MCAP message (Foxglove schemas are decoded from it)."""

    topic: str
    log_time: int
    size: int
    decode: Callable[[str], Any]
    mcap: McapMessage | None = None


def _add_topic(topics: dict[str, ChannelSummary], topic: ChannelSummary) -> None:
    """Add ``topic``, or its count to the one of its name (unknown in one file: unknown in all)."""
    known = topics.setdefault(topic.topic, topic)
    if known is not topic:
        count = topic.message_count
        known.message_count = None if known.message_count is None or count is None else known.message_count + count


def open_bag(path: Path, name: str) -> RosbagsBag | McapFileBag:
    """The reader for a bag folder (or its ``metadata.yaml``) or ``.mcap`` file(s)."""
    if path.name == "metadata.yaml" and path.is_file():
        path = path.parent
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
            return RosbagsBag(path, name)
        try:
            found = [p for p in path.iterdir() if p.suffix == ".mcap" and p.is_file()]
            has_sqlite = any(p.suffix == ".db3" for p in path.iterdir())
        except OSError as exc:
            raise InputError(f"{name}: cannot list the folder ({exc.strerror or exc})") from None
        if not found:
            if has_sqlite:
                raise InputError(
                    f"{name}: a ROS 2 bag in SQLite storage (.db3) needs its metadata.yaml beside it "
                    "(rosbag2 writes one; restore it with `ros2 bag reindex`)"
                )
            raise InputError(f"{name}: no .mcap file and no metadata.yaml in this folder; expected a ROS 2 bag")
        return McapFileBag(sorted(found, key=lambda p: _natural_key(p.name)), name)
    if not path.exists():
        raise InputError(f"{name}: no such file or directory")
    if path.suffix in (".db3", ".zstd", ".lz4") and (path.parent / "metadata.yaml").is_file():
        return RosbagsBag(path.parent, name)
    if path.suffix == ".db3":
        raise InputError(f"{name}: a SQLite bag file is read with its folder and metadata.yaml; give the bag folder")
    try:
        with path.open("rb") as stream:
            magic = stream.read(len(MAGIC))
    except OSError as exc:
        raise InputError(f"{name}: cannot read the file ({exc.strerror or exc})") from None
    if magic != MAGIC:
        raise InputError(f"{name}: not an MCAP file (expected a ROS 2 bag folder or its .mcap file)")
    return McapFileBag([path], name)


@contextlib.contextmanager
def _rosbags_errors(name: str) -> Iterator[None]:
    """What rosbags raises on a bag it cannot read, as one InputError naming the bag."""
    try:
        yield
    except HbvsError:
        raise
    except MemoryError:
        raise InputError(f"{name}: cannot read the bag (it asks for more memory than there is)") from None
    except Exception as exc:
        detail = " ".join(str(exc).split()) or type(exc).__name__
        raise InputError(f"{name}: cannot read the bag ({detail[:300]})") from None


def bag_information(folder: Path, name: str) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` of metadata.yaml, read under a size cap, :class:`InputError` unless
    the counts and names rosbags and hbvs use have the right types; empty when malformed (rosbags then says
    what is wrong with it when it opens the bag)."""
    metadata = folder / "metadata.yaml"
    try:
        size = metadata.stat().st_size
    except OSError as exc:
        raise InputError(f"{name}: cannot read metadata.yaml ({exc.strerror or exc})") from None
    if size > MAX_METADATA_BYTES:
        raise InputError(f"{name}: metadata.yaml is {size} bytes, more than the {MAX_METADATA_BYTES} hbvs reads")
    try:
        # Aliases expanded under a limit, before rosbags reads it.
        documents = limits.load_yaml_documents(metadata.read_text(encoding="utf-8"), f"{name}: metadata.yaml")
        information = documents[0]["rosbag2_bagfile_information"] if documents else None
    except (OSError, UnicodeDecodeError, yaml.YAMLError, RecursionError, KeyError, TypeError):
        return {}
    if not isinstance(information, dict):
        return {}

    def counts(where: str, value: Any) -> None:
        if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 0):
            raise InputError(f"{name}: metadata.yaml: {where} must be a whole number >= 0, got {_shown(value)}")

    counts("message_count", information.get("message_count"))
    for key in ("topics_with_message_count", "files", "relative_file_paths"):
        if information.get(key) is not None and not isinstance(information.get(key), list):
            raise InputError(f"{name}: metadata.yaml: {key} must be a list, got {_shown(information.get(key))}")
    for key in ("topics_with_message_count", "files"):
        for entry in information.get(key) or []:
            counts(f"{key}[].message_count", entry.get("message_count") if isinstance(entry, dict) else "?")
    distro = information.get("ros_distro")
    if distro is not None and not (isinstance(distro, str) and len(distro) <= 64):
        raise InputError(f"{name}: metadata.yaml: ros_distro must be a distribution's name, got {_shown(distro)}")
    return information


def _shown(value: Any) -> str:
    """A value of a file in a message: its type and at most 40 characters (never the whole)."""
    if isinstance(value, (str, int, float)) and not isinstance(value, bool):
        text = repr(value)
        return text if len(text) <= 40 else text[:40] + "..."
    return f"a {type(value).__name__}"


class _CappedZstd:
    """The ``zstd`` module as rosbags' reader uses it, a message capped at ``MAX_RECORD_BYTES`` and a file
    at the ``decompressed-bytes`` limit (rosbags decompresses whatever size they expand to)."""

    def __init__(self, module: Any) -> None:
        self._module = module

    def __getattr__(self, name: str) -> Any:
        return getattr(self._module, name)

    def decompress(self, data: bytes) -> bytes:
        decompressor = self._module.ZstdDecompressor()
        output = decompressor.decompress(data, max_length=MAX_RECORD_BYTES + 1)
        if len(output) > MAX_RECORD_BYTES:
            raise InputError(f"a compressed message expands to more than the {MAX_RECORD_BYTES // 2**20} MiB hbvs reads")
        return output

    def open(self, file: Any, mode: str = "rb", *args: Any, **kwargs: Any) -> Any:
        return _CappedReader(self._module.open(file, mode, *args, **kwargs))


class _CappedReader(io.RawIOBase):
    """A decompressing file that raises once more than ``decompressed-bytes`` came out (``read`` is
    RawIOBase's, through :meth:`readinto`)."""

    def __init__(self, inner: Any) -> None:
        super().__init__()
        self._inner = inner
        self._read = 0

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: Any) -> int:
        count = self._inner.readinto(buffer)
        self._read += count or 0
        if self._read > limits.current("decompressed-bytes"):
            raise limits.exceeded("decompressed-bytes", None, "a file of the file-compressed bag, decompressed,")
        return count

    def close(self) -> None:
        self._inner.close()
        super().close()


class RosbagsBag:
    """A ROS 2 bag folder read with ``rosbags``' ``AnyReader``, open until :meth:`close`."""

    def __init__(self, folder: Path, name: str) -> None:
        from rosbags.highlevel import AnyReader
        from rosbags.rosbag2 import reader
        from rosbags.typesys import Stores, get_typestore

        self.name = name
        information = bag_information(folder, name)
        if not isinstance(reader.zstd, _CappedZstd):  # rosbags' reader gets the capped zstd once per process
            reader.zstd = _CappedZstd(reader.zstd)
        # Bags without message definitions: the types of metadata.yaml's distro (Humble by default).
        distro = "ros2_" + str(information.get("ros_distro") or "humble").strip().lower()
        store = Stores(distro) if distro in {store.value for store in Stores} else Stores.LATEST
        with _rosbags_errors(name):
            self._reader = AnyReader([folder], default_typestore=get_typestore(store))
            self._reader.open()
        self._open = True
        #: The bag's files, for the recording's metadata.
        self.files = sorted(p for p in folder.iterdir() if p.is_file())
        self.topics: dict[str, ChannelSummary] = {}
        for connection in self._reader.connections:
            if len(connection.msgdef.data if connection.msgdef is not None else "") > MAX_SCHEMA_BYTES:
                raise InputError(f"{name}: the message definition of {connection.topic} is more than hbvs parses")
            _add_topic(self.topics, ChannelSummary(connection.topic, connection.msgtype, "", "cdr", connection.msgcount))
        files = information.get("relative_file_paths")
        self.storage = {
            "reader": "rosbags",
            "storage": str(information.get("storage_identifier", "")),
            "files": len(files) if isinstance(files, list) else None,
            "compression": " ".join(
                str(information.get(key) or "") for key in ("compression_mode", "compression_format")
            ).strip() or "none",
            "ros_distro": str(information.get("ros_distro", "")),
        }

    def messages(self, topics: set[str]) -> Iterator[BagMessage]:
        """The messages of ``topics`` in log-time order."""
        if not self._open:
            with _rosbags_errors(self.name):
                self._reader.open()
            self._open = True
        connections = [c for c in self._reader.connections if c.topic in topics]
        counted = limits.current("messages")
        with _rosbags_errors(self.name):
            for read, (connection, log_time, raw) in enumerate(self._reader.messages(connections=connections), start=1):
                if read > counted:
                    raise limits.exceeded("messages", None, f"{self.name}: the number of messages")
                if len(raw) > MAX_RECORD_BYTES:
                    raise InputError(
                        f"{self.name}: a {connection.topic} message of {len(raw)} bytes, more than the "
                        f"{MAX_RECORD_BYTES // 2**20} MiB hbvs reads"
                    )
                decode = partial(self._decode, raw, connection.msgtype)
                yield BagMessage(connection.topic, int(log_time), len(raw), decode)

    def _decode(self, raw: bytes, msgtype: str, what: str) -> Any:
        try:
            return self._reader.deserialize(raw, msgtype)
        except Exception as exc:  # a damaged CDR payload
            detail = " ".join(str(exc).split()) or type(exc).__name__
            raise InputError(f"{what}: cannot decode the {msgtype} message ({detail[:200]})") from None

    def close(self) -> None:
        if self._open:
            self._open = False
            self._reader.close()


@contextlib.contextmanager
def mcap_bag_errors(name: str) -> Iterator[None]:
    """What the MCAP reader or the CDR decoder raises on a damaged file, as one InputError."""
    try:
        yield
    except RecordingError as exc:
        detail = str(exc).removeprefix(f"{name}: ")
        raise InputError(f"{name}: cannot read the bag, the MCAP file is damaged or truncated ({detail})") from None
    except HbvsError:
        raise
    except Exception as exc:
        detail = " ".join(str(exc).split())
        kind = type(exc).__name__
        detail = kind if not detail or detail == kind else f"{kind}: {detail[:200]}"
        raise InputError(f"{name}: cannot read the bag, the MCAP file is damaged or truncated ({detail})") from exc


def _require_complete(stream: McapStream, name: str) -> None:
    """Refuse a bag file that ends early or turns unreadable (worded by :func:`mcap_bag_errors`)."""
    if stream.truncated:
        raise RecordingError(f"{name}: {stream.stop_reason}")


class McapFileBag:
    """``.mcap`` file(s) read with hbvs's capped MCAP reader and mcap-ros2-support's CDR decoders
    (one per distinct schema, built on first use)."""

    def __init__(self, files: Sequence[Path], name: str) -> None:
        from mcap_ros2.decoder import DecoderFactory

        self.name = name
        self.files = list(files)
        self._factory = DecoderFactory()
        self._decoders: dict[tuple[str, str, str, bytes], Callable[[bytes], Any]] = {}
        #: Topics of every file, from the summary section (or one streaming pass without).
        self.topics: dict[str, ChannelSummary] = {}
        for file in self.files:
            with mcap_bag_errors(str(file)):
                listed = read_summary(file)
                if listed is None:  # no summary: one pass over the file counts its messages
                    stream = McapStream(file, name=str(file))
                    deque(stream, maxlen=0)
                    _require_complete(stream, str(file))
                    listed = list(stream.channels.values())
            for channel in listed:
                parts = channel.schema_name.split("/")
                if len(parts) == 2:  # ``pkg/Type`` (ROS 1 style, as some converters write) to ``pkg/msg/Type``
                    channel.schema_name = f"{parts[0]}/msg/{parts[1]}"
                _add_topic(self.topics, channel)
        self.storage = {"reader": "hbvs mcap", "storage": "mcap", "files": len(self.files), "compression": "chunk"}

    def messages(self, topics: set[str]) -> Iterator[BagMessage]:
        """The messages of ``topics``, file after file, in the order each file stores them."""
        for file in self.files:
            stream = McapStream(file, topics=topics, name=str(file))
            messages = iter(stream)
            try:
                with mcap_bag_errors(str(file)):
                    for message in messages:
                        decode = partial(self._decode, message, str(file))
                        yield BagMessage(message.topic, message.log_time, len(message.data), decode, message)
                    _require_complete(stream, str(file))
            finally:
                messages.close()

    def _decode(self, message: McapMessage, file: str, what: str) -> Any:
        key = (message.message_encoding, message.schema_name, message.schema_encoding, message.schema_data)
        with mcap_bag_errors(file):
            decoder = self._decoders.get(key)
            if decoder is None:
                from mcap.records import Schema

                if len(message.schema_data) > MAX_SCHEMA_BYTES:
                    raise InputError(f"{what}: its message definition is {len(message.schema_data)} bytes, more than hbvs parses")
                # The factory caches decoders by schema id: every distinct schema gets its own.
                schema = Schema(
                    id=len(self._decoders) + 1, name=message.schema_name, encoding=message.schema_encoding,
                    data=message.schema_data,
                )
                # The ROS parser prints on stderr what its exception says already.
                with contextlib.redirect_stderr(io.StringIO()):
                    decoder = self._factory.decoder_for(message.message_encoding, schema)
                if decoder is None:
                    raise InputError(
                        f"{what}: encoded as {message.message_encoding!r} with a {message.schema_encoding!r} schema; "
                        "hbvs decodes ROS 2 messages (cdr with ros2msg schemas)"
                    )
                self._decoders[key] = decoder
            return decoder(message.data)

    def close(self) -> None:
        """Nothing stays open between reads."""
