"""Limits on every size that turns into memory or time, checked before anything is allocated;
the error names the limit and how to raise it (``hbvs --limit steps=5e6 ...``)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from ..errors import HbvsError, InputError, LimitExceededError, UsageError


@dataclass(frozen=True)
class Limit:
    """One limit: its name (as ``--limit NAME=N`` takes it), default, unit and what it bounds."""

    name: str
    default: int
    unit: str
    bounds: str


LIMITS: dict[str, Limit] = {
    limit.name: limit
    for limit in (
        Limit("steps", 1_000_000, "steps", "control steps of one repeat --sim run, frames of a simulated teach"),
        Limit("messages", 2**22, "messages", "messages read from one MCAP file or stream"),
        Limit("chunk-messages", 2**18, "messages", "messages in one MCAP chunk"),
        Limit("input-bytes", 64 * 2**30, "bytes", "bytes read from one MCAP file or stream, after decompression"),
        Limit("decompressed-bytes", 2**30, "bytes", "bytes one file of a file-compressed ROS 2 bag expands to (in TMPDIR)"),
        Limit("sweep-runs", 1_000_000, "runs", "runs of one hbvs sweep, checked before the plan is built"),
    )
}

_values: dict[str, int] = {name: limit.default for name, limit in LIMITS.items()}


def current(name: str) -> int:
    """The value of limit ``name`` in this process."""
    return _values[name]


def set_limits(items: list[str]) -> None:
    """Apply ``--limit NAME=N`` options (N may be written 5e6); :class:`UsageError` when malformed."""
    for item in items:
        name, sep, text = item.partition("=")
        name = name.strip().lower()
        if not sep or name not in LIMITS:
            raise UsageError(f"--limit {item!r}: expected NAME=N with NAME one of {', '.join(LIMITS)}")
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        # 5e6 is a whole number written short; 1.5 is not one (it used to become 1).
        if not (math.isfinite(value) and value >= 1 and value <= 2**62 and value.is_integer()):
            raise UsageError(f"--limit {name}: expected a positive whole number, got {text!r}")
        _values[name] = int(value)


def exceeded(name: str, amount: float | None, what: str) -> LimitExceededError:
    """The error for ``what`` going beyond limit ``name`` (``amount``: how far, when known)."""
    limit = LIMITS[name]
    needed = ""
    if amount is not None:
        needed = f" ({amount:.4g} {limit.unit})" if isinstance(amount, float) else f" ({amount} {limit.unit})"
    return LimitExceededError(
        f"{what}{needed} exceeds the {name} limit of {_values[name]} {limit.unit}; "
        f"raise it with: hbvs --limit {name}=N ..."
    )


def check(name: str, amount: float, what: str) -> None:
    """Raise :func:`exceeded` when ``amount`` (NaN and infinity included) is above limit ``name``."""
    if not (amount <= _values[name]):
        raise exceeded(name, amount, what)


def step_count(duration_s: float, rate_hz: float, what: str) -> int:
    """The number of steps of ``duration_s`` seconds at ``rate_hz``, checked against ``steps``."""
    if not (math.isfinite(duration_s) and duration_s >= 0):
        raise UsageError(f"{what}: the duration must be a finite number of seconds, got {duration_s}")
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise UsageError(f"{what}: the rate must be a finite positive number of Hz, got {rate_hz}")
    steps = duration_s * rate_hz
    check("steps", steps, what)
    return int(round(steps))


#: Nodes a YAML document may have once its aliases are expanded ("billion laughs"); a bag's
#: metadata.yaml has a few thousand.
MAX_YAML_NODES = 200_000


def _expanded_nodes(root: Any, budget: int) -> int:
    """Nodes of a composed YAML node with every alias expanded, counted without expanding (each
    node once); stops above ``budget`` (a node that contains itself is unbounded). Recursion is
    safe: PyYAML's composer took more stack per level to build the nodes."""
    import yaml

    sizes: dict[int, int] = {}
    active: set[int] = set()

    def size(node: Any) -> int:
        key = id(node)
        if key in active:
            return budget + 1  # an alias to itself: infinite once expanded
        if key not in sizes:
            active.add(key)
            children = node.value if isinstance(node, yaml.SequenceNode) else (
                [item for pair in node.value for item in pair] if isinstance(node, yaml.MappingNode) else [])
            total = 1
            for child in children:
                total = min(budget + 1, total + size(child))
            active.discard(key)
            sizes[key] = total
        return sizes[key]

    return size(root)


def load_yaml_documents(text: str, name: str, max_nodes: int = MAX_YAML_NODES, error: type[HbvsError] = InputError) -> list[Any]:
    """Every document of a YAML text (safe types only); ``error`` when its aliases expand to
    more than ``max_nodes`` nodes, before anything is built; yaml.YAMLError when malformed."""

    import yaml

    loader = yaml.SafeLoader(text)
    try:
        documents = []
        while loader.check_node():
            node = loader.get_node()
            if node is None:
                continue
            if _expanded_nodes(node, max_nodes) > max_nodes:
                where = ""
                if isinstance(node, yaml.MappingNode):
                    keys = [k for k, v in node.value if _expanded_nodes(v, max_nodes) > max_nodes // 2]
                    if keys and isinstance(keys[0], yaml.ScalarNode):
                        where = f" in {str(keys[0].value)[:40]}"
                raise error(
                    f"{name}: its YAML aliases{where} expand to more than {max_nodes} values (an alias bomb?); hbvs reads it no further"
                )
            documents.append(loader.construct_document(node))
        return documents
    finally:
        loader.dispose()
