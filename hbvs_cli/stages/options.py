"""Option syntaxes several stages share, and how a stage records its options."""

from __future__ import annotations

import math
from dataclasses import asdict
from pathlib import Path
from typing import Any

from ..errors import UsageError


def recorded_settings(options: Any) -> dict[str, Any]:
    """A stage's options as JSON-ready metadata, without the output name (the same inputs make the same bytes wherever they go)."""
    return {
        key: (str(value) if isinstance(value, Path) else value)
        for key, value in asdict(options).items()
        if key != "output"
    }


def parse_offset(text: str, option: str = "--offset") -> tuple[float, float, float]:
    """``DX,DY,DTHETA`` (m, m, deg) -> (m, m, rad)."""
    parts = text.split(",")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise UsageError(f"{option} must be DX,DY,DTHETA (m, m, deg), got {text!r}")
    return values[0], values[1], math.radians(values[2])


def parse_interval(text: str, option: str) -> tuple[float, float]:
    """``START:END`` (s) with 0 <= START < END."""
    try:
        start, end = (float(p) for p in text.split(":"))
    except ValueError:
        raise UsageError(f"{option} must be START:END in seconds, got {text!r}") from None
    if not (math.isfinite(start) and math.isfinite(end) and end > start >= 0):
        raise UsageError(f"{option} must be START:END with 0 <= START < END, got {text!r}")
    return start, end


def parse_time_and_factor(text: str, option: str) -> tuple[float, float]:
    """``T:FACTOR`` (s, positive factor)."""
    try:
        at, factor = (float(p) for p in text.split(":"))
    except ValueError:
        raise UsageError(f"{option} must be T:FACTOR (s, factor), got {text!r}") from None
    if not (math.isfinite(at) and at >= 0 and math.isfinite(factor) and factor > 0):
        raise UsageError(f"{option} must be T:FACTOR with T >= 0 and FACTOR > 0, got {text!r}")
    return at, factor


def parse_assignment(text: str, option: str) -> tuple[str, float]:
    """``NAME=VALUE`` -> (name, finite float)."""
    name, sep, value = text.partition("=")
    name = name.strip()
    try:
        number = float(value)
    except ValueError:
        number = math.nan
    if not sep or not name or not math.isfinite(number):
        raise UsageError(f"{option} must be NAME=VALUE with a finite number, got {text!r}")
    return name, number
