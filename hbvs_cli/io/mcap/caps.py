"""Caps on what one MCAP file may declare or hold, and the constants of the format as hbvs writes it."""

from __future__ import annotations

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
#: Largest JSON message decoded (a fit model holds the taught path's arrays in base64).
MAX_JSON_BYTES = 64 * 2**20
#: Most values (counted as commas, colons and brackets) in one JSON document. Each becomes
#: a Python object of tens of bytes, so this bounds memory where the byte cap cannot.
MAX_JSON_ITEMS = 2**21
#: Deepest nesting of JSON arrays and objects decoded; hbvs writes at most six levels.
MAX_JSON_DEPTH = 64
#: Latest message log time hbvs accepts: times are kept as signed 64-bit nanoseconds
#: (MCAP allows unsigned ones, up to 2^64 - 1).
MAX_LOG_TIME_NS = 2**63 - 1
#: Profile string in the MCAP header of every file hbvs writes.
PROFILE = ""

NANOSECONDS = 1_000_000_000

#: The eight bytes that open (and close) every MCAP file.
MAGIC = b"\x89MCAP0\r\n"
