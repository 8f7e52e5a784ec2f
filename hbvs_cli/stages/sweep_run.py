"""One run of a sweep on a worker: ``hbvs repeat --sim`` then ``hbvs report``; its row is the
report's values at the keys of :data:`~hbvs_cli.io.sweep_table.METRICS`."""

from __future__ import annotations

import os
import shutil
import tempfile
import time
import traceback
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping

from ..io.sweep_table import METRICS, STATUS_FAILED, STATUS_OK, STATUS_STOPPED, failed_row
from ..sweep.spec import RunSettings

if TYPE_CHECKING:
    from ..report.result import RunReport


@dataclass(frozen=True)
class RunTask(RunSettings):
    """A run with what a worker needs; ``arguments``: ``RepeatOptions`` fields besides input and output."""

    fit_path: str
    arguments: dict[str, Any]
    command: str
    keep_path: str | None
    keep: str = "failed"


@lru_cache(maxsize=1)
def _fit(path: str) -> Any:
    """The fit file at ``path``, read once by this process (a worker) for all its runs."""
    from ..io.fit_file import read_fit_file

    return read_fit_file(path)


def check_arguments(fit: Any, fit_path: str, arguments: Mapping[str, Any]) -> None:
    """Raise what ``hbvs repeat`` would raise for a run with ``arguments`` before it starts."""
    from ..stages.repeat import RepeatOptions, check_simulation_settings, settings_for
    from ..stages.options import parse_interval

    options = RepeatOptions(input=fit_path, output="-", **arguments)
    check_simulation_settings(settings_for(options, fit.model), fit.model)
    for window in options.occlude:
        parse_interval(window, "--occlude")


def report_row(report: RunReport) -> dict[str, Any]:
    """The :data:`METRICS` of a report (None where it has no such value)."""
    from ..report.result import MissingKey, resolve_key

    document = report.to_dict()
    row: dict[str, Any] = {}
    for column, key in METRICS.items():
        try:
            row[column] = resolve_key(document, key)
        except MissingKey:
            row[column] = None
    return row


def keep_file(source: str, destination: str) -> None:
    """Put ``source`` at ``destination`` whole or not at all, also across file systems."""
    from ..io.output_target import replace_through_partial

    def copy(partial: Path) -> None:
        with open(source, "rb") as reader, open(partial, "xb") as writer:
            shutil.copyfileobj(reader, writer, 1 << 20)
            writer.flush()
            os.fsync(writer.fileno())

    Path(destination).parent.mkdir(parents=True, exist_ok=True)
    replace_through_partial(Path(destination), copy)


def execute_run(task: RunTask) -> dict[str, Any]:
    """Make one run and its report, and return its row; a run that fails does not raise: its row says why."""
    from ..errors import HbvsError, TargetLostError
    from ..io.run_file import read_run
    from ..report.build import build_report
    from .console import Console
    from .repeat import RepeatOptions, run_repeat

    started = time.perf_counter()
    folder = tempfile.mkdtemp(prefix="hbvs-sweep-")
    try:
        run_path = os.path.join(folder, "run.mcap")
        status, error, metrics = STATUS_OK, None, {}
        try:
            options = RepeatOptions(input=task.fit_path, output=run_path, **task.arguments)
            try:
                run_repeat(options, Console(quiet=True), fit=_fit(task.fit_path))
            except TargetLostError as exc:
                status, error = STATUS_STOPPED, str(exc).split(";")[0]
            metrics = report_row(build_report(read_run(run_path)))
        except HbvsError as exc:
            status, error = STATUS_FAILED, f"{type(exc).__name__}: {exc}"
        except Exception as exc:  # noqa: BLE001 - one bad run must not stop a sweep
            status, error = STATUS_FAILED, "".join(traceback.format_exception_only(type(exc), exc)).strip()
        kept = None
        keep = task.keep_path is not None and (task.keep == "all" or (task.keep == "failed" and status != STATUS_OK))
        if keep and os.path.exists(run_path):
            try:
                keep_file(run_path, task.keep_path)
                kept = task.keep_path
            except OSError as exc:
                error = (error + "; " if error else "") + f"run file not kept ({exc.strerror or exc})"
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return failed_row(task, error) | {"status": status, **metrics, "run_time_s": time.perf_counter() - started, "run_file": kept}
