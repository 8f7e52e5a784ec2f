"""Option syntaxes several stages share, and how a stage records its options."""

from __future__ import annotations

import math
from dataclasses import asdict
from pathlib import Path
from typing import Any, Callable

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
    try:
        values = [float(p) for p in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise UsageError(f"{option} must be DX,DY,DTHETA (m, m, deg), got {text!r}")
    return values[0], values[1], math.radians(values[2])


def parse_pair(text: str, option: str, form: str, units: str, rule: str, holds: Callable[[float, float], bool]) -> tuple[float, float]:
    """``A:B``: two finite numbers for which ``holds(a, b)``; else a UsageError naming ``form``, ``units`` and ``rule``."""
    try:
        first, second = (float(p) for p in text.split(":"))
    except ValueError:
        raise UsageError(f"{option} must be {form} {units}, got {text!r}") from None
    if not (math.isfinite(first) and math.isfinite(second) and holds(first, second)):
        raise UsageError(f"{option} must be {form} with {rule}, got {text!r}")
    return first, second


def parse_interval(text: str, option: str) -> tuple[float, float]:
    """``START:END`` (s) with 0 <= START < END."""
    return parse_pair(text, option, "START:END", "in seconds", "0 <= START < END", lambda start, end: end > start >= 0)


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
