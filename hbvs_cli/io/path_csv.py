"""Teach-pendant command files: CSV with the columns ``t,v,w`` (s, m/s, rad/s), in any order, each row
held until the next row's time, the last one for the median row interval."""

from __future__ import annotations

import csv
import io
from array import array
from pathlib import Path

import numpy as np

from ..core.path import CommandProfile
from ..errors import HbvsError, InputError
from .text_files import read_small_text, short_repr

#: Largest CSV accepted (bytes): a day of commands at 100 Hz is ~200 MB; paths are small.
MAX_CSV_BYTES = 64 * 2**20
REQUIRED_COLUMNS = ("t", "v", "w")


def load_command_profile(path: str | Path) -> CommandProfile:
    """Read a teach-pendant CSV into a :class:`CommandProfile`."""
    name = str(path)
    reader = csv.reader(io.StringIO(read_small_text(path, MAX_CSV_BYTES, "a CSV file with columns t,v,w")))
    try:
        header = next(reader)
    except StopIteration:
        raise InputError(f"{name}: empty file; expected a header t,v,w") from None
    except csv.Error as exc:
        raise InputError(f"{name}: not a CSV file ({exc})") from None
    columns = [h.strip().lower() for h in header]
    missing = [c for c in REQUIRED_COLUMNS if c not in columns]
    if missing:
        raise InputError(f"{name}: the header must name the columns t,v,w (missing: {', '.join(missing)}; found: {short_repr(','.join(columns))})")
    index = [columns.index(c) for c in REQUIRED_COLUMNS]
    # Packed doubles: ten million short rows as Python lists would take gigabytes.
    values = [array("d") for _ in REQUIRED_COLUMNS]
    lines = array("q")
    try:
        for line_number, row in enumerate(reader, start=2):
            if not row or all(not cell.strip() for cell in row):
                continue
            try:
                numbers = [float(row[i]) for i in index]
            except (ValueError, IndexError):
                raise InputError(f"{name}:{line_number}: expected three numbers t,v,w, got {short_repr(','.join(row))}") from None
            for column, number in zip(values, numbers):
                column.append(number)
            lines.append(line_number)
    except csv.Error as exc:
        raise InputError(f"{name}: malformed CSV ({exc})") from None
    if len(lines) < 2:
        raise InputError(f"{name}: needs at least two command rows")
    t, v, w = (np.frombuffer(column, dtype=float).copy() for column in values)
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(v)) and np.all(np.isfinite(w))):
        raise InputError(f"{name}: contains NaN or infinity")
    steps = np.diff(t)
    if np.any(steps <= 0.0):
        bad = int(np.flatnonzero(steps <= 0.0)[0])
        raise InputError(f"{name}:{lines[bad + 1]}: time must increase strictly (t={t[bad + 1]:g} s after t={t[bad]:g} s)")
    t_end = float(t[-1]) + float(np.median(steps))  # Python floats overflow to inf quietly
    if not np.isfinite(t_end):
        raise InputError(f"{name}: the times are too large")
    try:
        return CommandProfile(t=t, v=v, w=w, t_end=t_end)
    except HbvsError as exc:
        raise InputError(f"{name}: {exc}") from None
