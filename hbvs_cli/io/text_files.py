"""Reading the small text files users give hbvs (CSV paths, TOML configs), safely."""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError


def read_small_file(path: str | Path, max_bytes: int, what: str, error: type[InputError] = InputError) -> bytes:
    """The bytes of a file of at most ``max_bytes`` (checked before reading, and while reading: a huge file, a
    growing one or a device cannot exhaust memory); ``what`` names the expected file in the one-line ``error``."""
    path = Path(path)
    too_large = f"{path}: too large for {what} (more than {max_bytes // 2**20} MiB)"
    try:
        if path.is_dir():
            raise error(f"{path}: is a directory, expected {what}")
        if path.stat().st_size > max_bytes:
            raise error(too_large)
        with open(path, "rb") as handle:
            data = handle.read(max_bytes + 1)  # one byte past the cap: stat() means nothing for pipes
    except FileNotFoundError:
        raise error(f"{path}: no such file") from None
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror or exc})") from None
    if len(data) > max_bytes:
        raise error(too_large)
    return data


def read_small_text(path: str | Path, max_bytes: int, what: str) -> str:
    """The UTF-8 text of :func:`read_small_file`."""
    try:
        return read_small_file(path, max_bytes, what).decode("utf-8-sig")
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text (UTF-8) file; expected {what}") from None


def short_repr(value: object, length: int = 60) -> str:
    """A value for a one-line message, cut to ``length`` characters."""
    text = repr(value)
    return text if len(text) <= length else text[:length - 3] + "..."
