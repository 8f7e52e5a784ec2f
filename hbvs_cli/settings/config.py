"""``--config FILE.toml``: controller gains, actuator limits and run settings (tables and keys: :data:`SCHEMA`;
defaults: :mod:`hbvs_cli.settings.commands`, listed in ``samples/gains.toml``). Command-line options win."""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any

from ..errors import InputError, UsageError
from ..core.control_settings import GAIN_NAMES
from ..io.text_files import read_small_text, short_repr
from .commands import REPEAT_SETTINGS

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

MAX_CONFIG_BYTES = 1 * 2**20

#: The keys of each table (top level: ""), in order.
TABLES: dict[str, tuple[str, ...]] = {
    "": ("law", "dhat0", "speed", "filter"), "gains": GAIN_NAMES, "limits": ("max_v", "max_w", "max_accel", "base_lag", "latency"),
    "run": ("lost_timeout", "rate", "perception", "pixel_noise", "offset"),
}
#: The repeat option each key sets.
_SETTINGS = {setting.config: setting for setting in REPEAT_SETTINGS if setting.config is not None}
#: Allowed keys per table and their types (each the type of the repeat option it sets).
SCHEMA: dict[str, dict[str, type]] = {table: {key: _SETTINGS[key].type for key in keys} for table, keys in TABLES.items()}


def load_config(path: str | Path) -> dict[str, Any]:
    """A TOML config as flat ``{key: value}`` (e.g. ``k_v``, ``max_v``), every key, type, choice and bound checked."""
    path = Path(path)
    text = read_small_text(path, MAX_CONFIG_BYTES, "a TOML file")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: malformed TOML ({exc})") from None
    except RecursionError:  # tomllib parses nested arrays and inline tables recursively
        raise InputError(f"{path}: malformed TOML (nested too deeply)") from None
    except ValueError as exc:  # an integer literal past Python's conversion limit
        raise InputError(f"{path}: malformed TOML ({str(exc)[:80]})") from None
    flat: dict[str, Any] = {}
    for key, value in data.items():
        if isinstance(value, dict):
            if key not in SCHEMA or key == "":
                raise InputError(f"{path}: unknown table [{key}] (known: gains, limits, run)")
            for inner, inner_value in value.items():
                flat[inner] = _checked(path, key, inner, inner_value)
        else:
            flat[key] = _checked(path, "", key, value)
    for key, value in flat.items():
        problem = _SETTINGS[key].violation(value)
        if problem is not None:
            raise UsageError(f"{path}: {problem}")
    return flat


def _checked(path: Path, table: str, key: str, value: Any) -> Any:
    where = f"[{table}] {key}" if table else key
    expected = SCHEMA[table].get(key)
    if expected is None:
        known = ", ".join(SCHEMA[table])
        raise InputError(f"{path}: unknown key {short_repr(where)} (known here: {known})")
    if expected is str:
        if not isinstance(value, str):
            raise InputError(f"{path}: {where} must be a string, got {short_repr(value)}")
        return value
    if isinstance(value, bool) or not isinstance(value, int if expected is int else (int, float)):
        raise InputError(f"{path}: {where} must be {'a whole number' if expected is int else 'a number'}, got {short_repr(value)}")
    try:
        # TOML integers are 64-bit, which tomllib does not check; an integer literal may be beyond float range.
        if expected is int and not -(2**63) <= value < 2**63:
            raise OverflowError
        value = expected(value)
    except OverflowError:
        raise InputError(f"{path}: {where} is out of range") from None
    if math.isnan(value):
        raise InputError(f"{path}: {where} is NaN")
    return value
