"""Reading and writing MCAP files safely: capped, streaming, atomic.

MCAP framing on the write side is the ``mcap`` library's; reading is done here, record by
record, because hbvs promises more than that library's readers give:

* **Streaming both ways**: every stage reads a file or stdin (``-``) front to back in
  constant memory, and writes a file or stdout. The mcap ``Writer`` calls ``tell()``, which
  a pipe does not have, so every output stream answers it by counting bytes
  (:class:`~hbvs_cli.io.output_target.GuardedStream`).
* **Atomic output**: a file is written as ``FILE.<pid>-<random>.partial`` and renamed over
  ``FILE`` only when it is finished (:mod:`hbvs_cli.io.output_target` decides how every
  output is written); a failed or interrupted command leaves any previous ``FILE``
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

The package's rooms: :mod:`.caps` (the caps and format constants), :mod:`.json_codec` (JSON
messages under caps), :mod:`.writer` (:class:`McapWriter`, :func:`open_output`),
:mod:`.reader` (:class:`McapStream`, :func:`read_metadata`) and :mod:`.summary`
(:func:`read_summary`). Every public name is re-exported here.
"""

from __future__ import annotations

from .caps import (
    MAGIC, MAX_CHANNELS, MAX_CHUNK_BYTES, MAX_DECLARED_BYTES, MAX_JSON_BYTES, MAX_JSON_DEPTH, MAX_JSON_ITEMS,
    MAX_LOG_TIME_NS, MAX_RECORD_BYTES, MAX_SCHEMAS, NANOSECONDS, PROFILE,
)
from .json_codec import check_json_limits, decode_json, encode_json, json_ready, seconds_to_ns, time_message
from .reader import McapMessage, McapStream, read_metadata
from .summary import ChannelSummary, read_summary
from .writer import McapWriter, open_output

__all__ = [
    "MAGIC", "MAX_CHANNELS", "MAX_CHUNK_BYTES", "MAX_DECLARED_BYTES", "MAX_JSON_BYTES", "MAX_JSON_DEPTH",
    "MAX_JSON_ITEMS", "MAX_LOG_TIME_NS", "MAX_RECORD_BYTES", "MAX_SCHEMAS", "NANOSECONDS", "PROFILE",
    "check_json_limits", "decode_json", "encode_json", "json_ready", "seconds_to_ns", "time_message",
    "McapMessage", "McapStream", "read_metadata", "ChannelSummary", "read_summary",
    "McapWriter", "open_output",
]
