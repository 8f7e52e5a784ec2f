"""JSON messages: encoding (deterministic, NaN-free) and decoding under caps on size, values and nesting."""

from __future__ import annotations

import json
import math
import re
from typing import Any

from ...errors import RecordingError
from .caps import MAX_JSON_BYTES, MAX_JSON_DEPTH, MAX_JSON_ITEMS, NANOSECONDS


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


#: Every byte but the brackets, commas and colons that give JSON its structure.
_NOT_JSON_STRUCTURE = bytes(sorted(set(range(256)) - set(b"[]{},:")))
#: A JSON string literal (escapes included), to blank out before counting brackets.
_JSON_STRING = re.compile(rb'"[^"\\]*(?:\\.[^"\\]*)*"', re.DOTALL)


def check_json_limits(data: bytes | str, what: str) -> None:
    """:class:`RecordingError` for JSON above :data:`MAX_JSON_BYTES`, :data:`MAX_JSON_ITEMS` values or
    :data:`MAX_JSON_DEPTH` levels, which could exhaust memory or the stack (nesting measured only when
    there are enough brackets to exceed its cap)."""
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
    # An integer beyond float range would raise OverflowError far from the file that held it.
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
