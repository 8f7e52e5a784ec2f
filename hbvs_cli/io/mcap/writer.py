"""Writing hbvs MCAP files: JSON messages on registered schemas, atomically (see :func:`open_output`)."""

from __future__ import annotations

import json
import os
from contextlib import contextmanager
from typing import IO, Any, Iterator

from ..schemas import SCHEMAS
from .caps import PROFILE
from .json_codec import encode_json, json_ready


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

        from ... import __version__

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

    def declare_channel(self, topic: str, schema_name: str, schema_encoding: str, schema_data: bytes, message_encoding: str) -> None:
        """Register a channel whose messages are not JSON (e.g. protobuf images), once per topic.

        Later :meth:`write_encoded` calls on ``topic`` use it; the caller encodes the messages.
        """
        if topic in self._channels:
            return
        key = f"{schema_name}\0{schema_encoding}"
        if key not in self._schemas:
            self._schemas[key] = self._writer.register_schema(name=schema_name, encoding=schema_encoding, data=schema_data)
        self._channels[topic] = self._writer.register_channel(
            topic=topic, message_encoding=message_encoding, schema_id=self._schemas[key]
        )

    def write(self, topic: str, schema_name: str, log_time_ns: int, message: dict[str, Any]) -> None:
        """Write one message, JSON-encoded."""
        self.write_encoded(topic, schema_name, log_time_ns, encode_json(message))

    def write_encoded(self, topic: str, schema_name: str, log_time_ns: int, data: bytes) -> None:
        """Write one message whose bytes are already encoded (JSON copied from input, or in
        the encoding of a channel given to :meth:`declare_channel`)."""
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

    def input_ended_early(self, name: str, allow: bool) -> None:
        """An input of this output ended before its end record: see
        :meth:`hbvs_cli.io.output_target.OutputSink.input_ended_early` (set by :func:`open_output`)."""

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
def open_output(target: str | os.PathLike[str], chunk_size: int = 1024 * 1024, stdout: IO[bytes] | None = None) -> Iterator[McapWriter]:
    """An :class:`McapWriter` on an output opened by :func:`~hbvs_cli.io.output_target.open_output_stream`.

    A file is written under a partial name unique to the process and renamed into place
    when complete (a symbolic link's target is replaced); a device or FIFO is written in
    place; ``-`` is stdout. If the body raises (an error, KeyboardInterrupt, or the
    exception the CLI raises on SIGTERM), the partial file is removed and an existing
    output is left as it was. Only a hard crash, which runs no code, leaves the partial
    file behind. A stage whose input ended early calls ``writer.input_ended_early``.
    """
    from ..output_target import open_output_stream

    with open_output_stream(target, "output", stdout=stdout) as sink:
        writer = McapWriter(sink.stream, chunk_size=chunk_size)
        writer.input_ended_early = sink.input_ended_early
        yield writer
        writer.finish()
