"""Reading the small text files users give hbvs (CSV paths, TOML configs), safely."""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError


def read_small_text(path: str | Path, max_bytes: int, what: str) -> str:
    """The UTF-8 text of a file of at most ``max_bytes`` (checked before reading: a huge file or a device
    cannot exhaust memory); ``what`` names the expected file in the one-line :class:`InputError`."""
    path = Path(path)
    try:
        if path.is_dir():
            raise InputError(f"{path}: is a directory, expected {what}")
        if path.stat().st_size > max_bytes:
            raise InputError(f"{path}: larger than {max_bytes // 2**20} MiB, not {what}")
        with open(path, "rb") as handle:
            data = handle.read(max_bytes + 1)
        if len(data) > max_bytes:
            raise InputError(f"{path}: larger than {max_bytes // 2**20} MiB, not {what}")
        return data.decode("utf-8-sig")
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text (UTF-8) file; expected {what}") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None


def short_repr(value: object) -> str:
    """A value for a one-line message, cut to a readable length."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."
