"""An option declared once, as a field of a stage's options dataclass (:func:`option`); the typer signature, the
``--config`` keys and the sweep's parameters come from it. Values are checked as the options are made (:class:`Options`)."""

from __future__ import annotations

import math
import types
from dataclasses import dataclass, field, fields
from functools import cache
from typing import Any, Callable, Mapping, Union, get_args, get_origin, get_type_hints

from ..errors import UsageError

_DETAILS = "hbvs_option"  # the key of a field's metadata that holds its Setting's details


@dataclass(frozen=True)
class Setting:
    """One option of a stage: ``default`` what the options hold when it is not given (None: "not given"); ``fallback``
    the value when neither the option nor the ``config`` key of a ``--config`` file gives one; ``shown`` the default in
    ``--help``'s words; ``bounds`` ``min`` and ``max``; ``choices`` the words a text option takes (or a function)."""

    name: str
    type: type
    help: str
    default: Any = None
    fallback: Any = None
    shown: str | None = None
    config: str | None = None
    flags: tuple[str, ...] = ()
    panel: str | None = None
    argument: bool = False
    required: bool = False
    repeatable: bool = False
    bounds: Mapping[str, float] = field(default_factory=dict)
    metavar: str | None = None
    choices: tuple[str, ...] | Callable[[], tuple[str, ...]] = ()

    @property
    def option_names(self) -> tuple[str, ...]:
        return self.flags or ("--" + self.name.replace("_", "-"),)

    @property
    def shown_default(self) -> str | None:
        """The default as ``--help`` shows it (None: nothing to show)."""
        if self.shown is not None:
            return self.shown
        value = self.fallback if self.default is None else self.default
        if value is None or value is False or self.argument or self.repeatable:
            return None
        return shown(value)

    def allowed(self) -> tuple[str, ...]:
        """The words this option takes (empty: any)."""
        return self.choices() if callable(self.choices) else self.choices

    def violation(self, value: Any, label: str | None = None) -> str | None:
        """Why ``value`` breaks :meth:`allowed` or :attr:`bounds`, in the command line's words (``label``: its name), or None."""
        option = label or self.option_names[-1]
        if isinstance(value, str) and self.allowed() and value not in self.allowed():
            return f"{option} must be one of {', '.join(self.allowed())}, got {value!r}"
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return None
        low, high = self.bounds.get("min", -math.inf), self.bounds.get("max", math.inf)
        problem = ("a number, got nan" if value != value else f"greater than or equal to {shown(low)}" if not value >= low
                   else f"less than or equal to {shown(high)}" if not value <= high else None)  # NaN fails every bound
        return f"Invalid value for '{option}': Input should be {problem}" if problem else None

    def resolve(self, given: Any, config: Mapping[str, Any], fallback: Any = None) -> Any:
        """The option if given, else the config's value, else ``fallback`` or this setting's own."""
        if given is not None:
            return given
        if self.config is not None and self.config in config:
            return config[self.config]
        return self.fallback if fallback is None else fallback


def shown(value: Any) -> str:
    """A default or bound as ``--help`` writes it."""
    return f"{value:g}" if isinstance(value, float) else str(value)


def option(help: str, default: Any = None, *, argument: bool = False, required: bool = False, repeatable: bool = False,
           **details: Any) -> Any:
    """A field of an options dataclass declared as an option (the keywords of :class:`Setting`)."""
    metadata = {_DETAILS: dict(help=help, default=default, argument=argument, required=required, repeatable=repeatable,
                               **details)}
    if repeatable:
        return field(default_factory=list, metadata=metadata)
    return field(metadata=metadata) if argument or required else field(default=default, metadata=metadata)


def _value_type(annotation: Any) -> type:
    """``float`` of ``float``, ``float | None`` and ``list[float]``."""
    if get_origin(annotation) in (list, Union, types.UnionType):
        return next(kind for kind in get_args(annotation) if kind is not type(None))
    return annotation


@cache
def settings_of(cls: type) -> tuple[Setting, ...]:
    """The options of an options dataclass, in the order of its fields (the arguments first)."""
    hints = get_type_hints(cls)
    return tuple(Setting(item.name, _value_type(hints[item.name]), **item.metadata[_DETAILS]) for item in fields(cls))


class Options:
    """The base of the options dataclasses: values checked against choices and bounds as they are made (UsageError)."""

    def __post_init__(self) -> None:
        for setting in settings_of(type(self)):
            problem = setting.violation(getattr(self, setting.name))
            if problem is not None:
                raise UsageError(problem)


def options_from_command_line(cls: type, values: Mapping[str, Any]) -> Any:
    """The options dataclass from the values typer parsed (an absent repeatable option is None there)."""
    lists = {s.name for s in settings_of(cls) if s.repeatable}
    return cls(**{key: (list(value or []) if isinstance(value, (list, tuple)) or value is None and key in lists else value)
                  for key, value in values.items() if key in {s.name for s in settings_of(cls)}})
