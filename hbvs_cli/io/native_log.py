"""What native libraries print on descriptor 2, kept off the terminal (:func:`capture`) and quoted in
our one-line errors (:func:`said_since` a :func:`mark`)."""

from __future__ import annotations

import os
import re
import sys
import tempfile

#: The capture file is emptied once it holds more than this (native chatter is small).
MAX_CAPTURED_BYTES = 1 << 20
#: Longest native text quoted in a message.
MAX_QUOTED_CHARS = 160

_captured = False


def capture() -> bool:
    """Send descriptor 2 to a temporary file, ``sys.stderr`` keeping the real stderr; False (nothing
    changed) when descriptor 2 cannot be redirected."""
    global _captured
    try:
        sys.stderr.flush()
        copy = os.dup(2)
        terminal = os.fdopen(copy, "w", encoding=getattr(sys.stderr, "encoding", None) or "utf-8",
                             errors="backslashreplace", buffering=1)
        with tempfile.TemporaryFile() as sink:
            os.dup2(sink.fileno(), 2)
    except (OSError, ValueError, AttributeError):
        return False
    sys.stderr = terminal
    _captured = True
    return True


def mark() -> int:
    """Where native output written from now on starts (0 when nothing is captured)."""
    if not _captured:
        return 0
    try:
        size = os.fstat(2).st_size
        if size > MAX_CAPTURED_BYTES:
            os.ftruncate(2, 0)
            os.lseek(2, 0, os.SEEK_SET)
            return 0
        return size
    except OSError:
        return 0


def said_since(start: int) -> str:
    """The native text written since :func:`mark` returned ``start``, as one short line ("" for none)."""
    if not _captured:
        return ""
    try:
        end = os.fstat(2).st_size
        length = min(end - start, MAX_CAPTURED_BYTES)
        text = os.pread(2, length, start).decode("utf-8", "replace") if length > 0 else ""
    except OSError:
        return ""
    # OpenCV prefixes "[ERROR:0@0.104] global grfmt_tiff.cpp:117 TIFF_Error "; keep the words.
    lines = [re.sub(r"^\[[A-Z]+:[^\]]*\]\s+\S+\s+\S+:\d+\s+", "", line).strip() for line in text.splitlines()]
    said = "; ".join(line for line in lines if line)
    return said if len(said) <= MAX_QUOTED_CHARS else said[: MAX_QUOTED_CHARS - 3] + "..."


def opencv_error_text(exc: BaseException) -> str:
    """The useful part of an OpenCV error (``... error: (-212:Parsing error) ...``), on one line."""
    cause = exc.__cause__ if exc.__cause__ is not None else exc
    message = " ".join(str(cause).split())
    return message.split("error: ", 1)[1] if "error: " in message else message
