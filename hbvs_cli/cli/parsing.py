"""How the command line reads and explains itself: value labels in help, one-line usage
errors, ``--debug`` anywhere, and the unquoted-glob hint."""

from __future__ import annotations

from itertools import takewhile
from pathlib import Path
from typing import Any, get_args, get_origin

from typer.core import TyperArgument, TyperGroup

#: Labels of option values by the Python type behind them (click's words).
_LABELS = {int: "INTEGER", float: "NUMBER", str: "TEXT", Path: "PATH"}
#: Longest usage message shown (an expanded glob can make click list thousands of names).
_MAX_MESSAGE = 300


def value_label(param: Any) -> str:
    """What the help shows after an option: nothing for a flag, else its kind of value."""
    if getattr(param, "is_flag", False) or getattr(param, "count", False):
        return ""
    descriptor = getattr(param, "type_descriptor", None)
    annotation = getattr(descriptor, "annotation", str)
    if get_origin(annotation) in (list, tuple):
        annotation = (get_args(annotation) or (str,))[0]
    if getattr(descriptor, "is_path", False):
        annotation = Path
    return _LABELS.get(annotation, "VALUE")


class _Argument(TyperArgument):
    """An argument shown as ``NAME`` (``[NAME]`` when optional) in the usage line."""

    def _usage_display_name(self) -> str:
        name = self.display_name_raw
        return name if self.required else f"[{name}]"

    def display_type_rich(self, ctx: Any) -> str | None:
        return value_label(self)


def label_parameters(params: list[Any]) -> None:
    """Give every option a value label and every argument an upper-case name."""
    for param in params:
        if isinstance(param, TyperArgument):
            param.metavar = param.name.upper() + ("..." if param.nargs != 1 else "")
            if type(param) is TyperArgument:
                # Typer writes a required argument as {name} in the usage line.
                param.__class__ = _Argument
        elif param.metavar is None:
            param.metavar = value_label(param)


class HbvsGroup(TyperGroup):
    """The ``hbvs`` command group: labels the parameters of itself and of every command."""

    def __init__(self, **attrs: Any) -> None:
        super().__init__(**attrs)
        label_parameters(self.params)
        for command in self.commands.values():
            label_parameters(command.params)

    # The -h/--help option is made on first use, not with the other parameters.
    def get_help_option(self, ctx: Any) -> Any:
        option = super().get_help_option(ctx)
        if option is not None:
            label_parameters([option])
        return option

    def get_command(self, ctx: Any, cmd_name: str) -> Any:
        command = super().get_command(ctx, cmd_name)
        if command is not None and (option := command.get_help_option(ctx)) is not None:
            label_parameters([option])
        return command


def split_debug(args: list[str]) -> tuple[list[str], bool]:
    """The arguments without ``--debug`` (wherever it stands before ``--``), and whether it was there."""
    end = args.index("--") if "--" in args else len(args)
    kept = [a for a in args[:end] if a != "--debug"] + args[end:]
    return kept, len(kept) != len(args)


def one_line_usage_error(exc: Any) -> str:
    """A click usage error as one line: the problem and where to find help."""
    message = " ".join(exc.format_message().split())
    if len(message) > _MAX_MESSAGE:
        message = message[:_MAX_MESSAGE] + "..."
    ctx = getattr(exc, "ctx", None)
    where = f" (see '{ctx.command_path} -h')" if ctx is not None else " (see 'hbvs -h')"
    return f"hbvs: error: {message}{where}"


def unquoted_glob_hint(args: list[str]) -> str | None:
    """The message for ``teach --images dir/*.png`` that the shell expanded, or None."""
    if "teach" not in args:
        return None
    for index, arg in enumerate(args):
        if arg == "--images":
            names = _names_after(args[index + 1:])
        elif arg.startswith("--images="):
            names = [arg.split("=", 1)[1], *_names_after(args[index + 1:])]
        else:
            continue
        if len(names) >= 2:
            return (
                f"hbvs: error: --images got {len(names)} file names: the shell expanded the pattern "
                f"before hbvs saw it; quote it, e.g. --images '{_pattern_of(names)}'"
            )
    return None


def _names_after(args: list[str]) -> list[str]:
    return list(takewhile(lambda arg: not arg.startswith("-"), args))


def _pattern_of(names: list[str]) -> str:
    """A glob that matches the expanded names: their common folder, * and their extension."""
    folders = {str(Path(n).parent) for n in names}
    suffixes = {Path(n).suffix for n in names}
    folder = folders.pop() if len(folders) == 1 else "FOLDER"
    suffix = suffixes.pop() if len(suffixes) == 1 else ".*"
    return str(Path(folder) / f"*{suffix}")
