"""A typer command's parameters made from a stage's settings table (:mod:`hbvs_cli.settings`):
the ``__signature__`` of a ``**values`` function, which typer reads."""

from __future__ import annotations

import inspect
from typing import Annotated, Any, Callable, List, Optional

import typer

from ..settings.option import Setting


def typer_parameter(setting: Setting) -> inspect.Parameter:
    """The annotated parameter typer makes ``setting``'s option (or argument) from."""
    kind: Any = setting.type
    if setting.argument:
        kind = List[kind] if setting.repeatable else kind
        return inspect.Parameter(setting.name, inspect.Parameter.POSITIONAL_OR_KEYWORD,
                                 annotation=Annotated[kind, typer.Argument(help=setting.help)])
    # An option that holds None until given (a config file may set it) words its default itself.
    shown = setting.shown_default if setting.default is None else None
    option = typer.Option(
        *setting.option_names, help=setting.help + (f" Default {shown}." if shown is not None else ""),
        rich_help_panel=setting.panel, show_default=setting.default is not None, metavar=setting.metavar, **dict(setting.bounds),
    )
    if setting.repeatable:
        kind = Optional[List[kind]]
    elif setting.default is None and not setting.required:
        kind = Optional[kind]
    return inspect.Parameter(setting.name, inspect.Parameter.KEYWORD_ONLY, annotation=Annotated[kind, option],
                             default=inspect.Parameter.empty if setting.required else setting.default)


def with_settings(function: Callable[..., Any], settings: tuple[Setting, ...],
                  *extra: inspect.Parameter) -> Callable[..., Any]:
    """The ``**values`` command ``function``, given the parameters of ``settings`` (then ``extra``)."""
    parameters = [typer_parameter(s) for s in sorted(settings, key=lambda s: not s.argument)]
    parameters += [p.replace(kind=inspect.Parameter.KEYWORD_ONLY) for p in extra]
    function.__signature__ = inspect.Signature(parameters, return_annotation=None)  # type: ignore[attr-defined]
    return function
