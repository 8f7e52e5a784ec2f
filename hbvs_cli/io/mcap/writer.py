"""Writing hbvs MCAP files atomically: ``foxglove.*`` messages in protobuf, ``hbvs.*`` in JSON."""

from __future__ import annotations

import json
import os
from contextlib import contextmanager
from functools import lru_cache
from typing import Any, Iterator

from ..schemas import HBVS_SCHEMAS
from .caps import PROFILE
from .json_codec import encode_json, json_ready


@lru_cache(maxsize=None)
def protobuf_schema(message_class: Any) -> bytes:
    """The FileDescriptorSet of a protobuf class, as mcap-protobuf-support stores it."""
    from mcap_protobuf.schema import build_file_descriptor_set

    return build_file_descriptor_set(message_class).SerializeToString()


class McapWriter:
    """Writes one hbvs MCAP file through the ``mcap`` library's ``Writer`` (zstd chunks): a protobuf
    message on a ``protobuf`` channel, a dict on a ``json`` one with its ``hbvs.*`` JSON schema."""

    def __init__(self, stream: Any, chunk_size: int = 1024 * 1024) -> None:
        from mcap.writer import CompressionType, Writer

        from ... import __version__

        self._stream = stream
        self._writer = Writer(stream, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        self._writer.start(profile=PROFILE, library=f"hbvs {__version__}")
        self._schemas: dict[str, int] = {}
        #: topic -> (channel id, schema name, schema encoding, schema data, message encoding)
        self.channels: dict[str, tuple[int, str, str, bytes, str]] = {}
        self._sequence = 0
        self._finished = False

    def _channel(self, topic: str, schema_name: str, message: Any) -> int:
        if topic in self.channels:
            return self.channels[topic][0]
        if isinstance(message, dict) or message is None:
            schema = json.dumps(HBVS_SCHEMAS[schema_name], separators=(",", ":")).encode()
            return self._declare(topic, schema_name, "jsonschema", schema, "json")
        assert type(message).DESCRIPTOR.full_name == schema_name, (topic, schema_name)
        return self._declare(topic, schema_name, "protobuf", protobuf_schema(type(message)), "protobuf")

    def _declare(self, topic: str, schema_name: str, encoding: str, schema: bytes, message_encoding: str) -> int:
        if topic not in self.channels:
            if schema_name not in self._schemas:
                self._schemas[schema_name] = self._writer.register_schema(name=schema_name, encoding=encoding, data=schema)
            channel_id = self._writer.register_channel(topic=topic, message_encoding=message_encoding, schema_id=self._schemas[schema_name])
            self.channels[topic] = (channel_id, schema_name, encoding, schema, message_encoding)
        return self.channels[topic][0]

    def write(self, topic: str, schema_name: str, log_time_ns: int, message: Any) -> bytes:
        """Write one message (a protobuf message, or a dict encoded as JSON); returns its bytes."""
        data = encode_json(message) if isinstance(message, dict) else message.SerializeToString(deterministic=True)
        self._add(self._channel(topic, schema_name, message), log_time_ns, data)
        return data

    def write_encoded(self, topic: str, schema_name: str, log_time_ns: int, data: bytes) -> None:
        """Write one ``hbvs.*`` message whose JSON bytes are already encoded."""
        self._add(self._channel(topic, schema_name, None), log_time_ns, data)

    def _add(self, channel_id: int, log_time_ns: int, data: bytes) -> None:
        self._writer.add_message(
            channel_id=channel_id, log_time=int(log_time_ns), publish_time=int(log_time_ns), data=data, sequence=self._sequence,
        )
        self._sequence += 1

    def metadata(self, name: str, values: dict[str, Any]) -> None:
        """A metadata record; values are stored as strings (dicts and lists as JSON)."""
        encoded = {str(k): v if isinstance(v, str) else json.dumps(json_ready(v), separators=(",", ":")) for k, v in values.items()}
        self._writer.add_metadata(name, encoded)

    def input_ended_early(self, name: str, allow: bool) -> None:
        """Set by :func:`open_output` (see :meth:`~hbvs_cli.io.output_target.OutputSink.input_ended_early`)."""

    def flush(self) -> None:
        """Finish the chunk in progress and push it to the stream (crash safety)."""
        self._writer.flush()

    def finish(self) -> None:
        """Write the summary and footer; the file is complete afterwards."""
        if not self._finished:
            self._writer.finish()
            self._stream.flush()
            self._finished = True


@contextmanager
def open_output(target: str | os.PathLike[str], chunk_size: int = 1024 * 1024,
                keep_on_error: bool = False) -> Iterator[McapWriter]:
    """An :class:`McapWriter` on :func:`~hbvs_cli.io.output_target.open_output_stream` (committed on success;
    ``keep_on_error``: finished and committed on a failure too, then the failure raised)."""
    from ..output_target import open_output_stream

    with open_output_stream(target, "output", keep_on_error=keep_on_error) as sink:
        writer = McapWriter(sink.stream, chunk_size=chunk_size)
        writer.input_ended_early = sink.input_ended_early
        try:
            yield writer
        except BaseException:
            if keep_on_error:
                writer.finish()
            raise
        writer.finish()
