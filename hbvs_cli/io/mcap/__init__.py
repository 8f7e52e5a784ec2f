"""MCAP files, safely: streamed both ways (a file or ``-``), written atomically, read under caps
with truncated files kept up to their last complete record."""

from __future__ import annotations

from .caps import MAGIC, MAX_CHANNELS, MAX_CHUNK_BYTES, MAX_JSON_DEPTH, MAX_JSON_ITEMS, MAX_RECORD_BYTES, MAX_SCHEMAS
from .json_codec import decode_json, encode_json, json_ready, seconds_to_ns, time_message
from .reader import ChannelSummary, McapMessage, McapStream, read_metadata, read_summary
from .writer import McapWriter, open_output

__all__ = [
    "MAGIC", "MAX_CHANNELS", "MAX_CHUNK_BYTES", "MAX_JSON_DEPTH", "MAX_JSON_ITEMS", "MAX_RECORD_BYTES", "MAX_SCHEMAS",
    "decode_json", "encode_json", "json_ready", "seconds_to_ns", "time_message", "McapMessage", "McapStream",
    "read_metadata", "ChannelSummary", "read_summary", "McapWriter", "open_output",
]
