"""Messages and progress bars on stderr (bars only on a terminal); stdout is for data."""

from __future__ import annotations

import json
import sys
from contextlib import contextmanager
from typing import Any, Callable, Iterator, TextIO

from ..stop_signals import raise_if_stopped


def print_document(document: Any, json_output: bool, as_text: Callable[[Any, TextIO], None]) -> None:
    """``document`` on stdout, flushed: JSON (two-space indents, no NaN) for ``--json``, else as ``as_text`` writes it."""
    if json_output:
        sys.stdout.write(json.dumps(document, indent=2, allow_nan=False) + "\n")
    else:
        as_text(document, sys.stdout)
    sys.stdout.flush()


class Console:
    """Where a stage reports to the user: ``stream`` (stderr); ``quiet`` prints only warnings."""

    def __init__(self, quiet: bool = False, stream: Any = None) -> None:
        from rich.console import Console as RichConsole

        self.quiet = quiet
        self.stream = stream if stream is not None else sys.stderr
        self.rich = RichConsole(file=self.stream, stderr=stream is None, highlight=False, soft_wrap=True)

    @property
    def width(self) -> int:
        """The width (characters) tables are fitted to."""
        return self.rich.width

    @property
    def interactive(self) -> bool:
        return not self.quiet and self.rich.is_terminal

    def info(self, message: str) -> None:
        if not self.quiet:
            self.rich.print(message, markup=False)

    def warn(self, message: str) -> None:
        self.rich.print(f"hbvs: warning: {message}", markup=False, style="yellow")

    def print(self, renderable: Any = "") -> None:
        """A rich renderable (a table) on stderr unless quiet, wrapped to the width (messages are soft-wrapped)."""
        if not self.quiet:
            self.rich.print(renderable, soft_wrap=False)

    @contextmanager
    def status_line(self) -> Iterator[Any]:
        """A line rewritten in place on a terminal (``repeat --live``): a function of its text, or None when not interactive."""
        if not self.interactive:
            yield None
            return
        from rich.live import Live
        from rich.text import Text

        with Live(Text(""), console=self.rich, refresh_per_second=4) as live:
            yield lambda text: live.update(Text(text, no_wrap=True, overflow="ellipsis"))

    @contextmanager
    def progress(self, description: str, total: float | None, note: str = "", **fields: Any) -> Iterator["ProgressTask"]:
        """A progress bar on stderr, silent when not interactive; ``note``: a column after the
        count, e.g. ``"{task.fields[failed]} failed"``, ``fields`` its first values."""
        if not self.interactive:
            yield ProgressTask(None, None)
            return
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

        columns = [TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), *([TextColumn(note)] if note else []),
                   TimeElapsedColumn(), TimeRemainingColumn()]
        with Progress(*columns, console=self.rich, transient=True) as progress:
            task = progress.add_task(description, total=total, **fields)
            yield ProgressTask(progress, task)


class ProgressTask:
    """Handle on one progress bar (or none); :meth:`advance` also raises a stop signal that native code swallowed."""

    def __init__(self, progress: Any, task: Any) -> None:
        self._progress = progress
        self._task = task

    def advance(self, amount: float = 1.0, **fields: Any) -> None:
        if self._progress is not None:
            self._progress.update(self._task, advance=amount, **fields)
        raise_if_stopped()
