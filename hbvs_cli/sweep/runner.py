"""One run of a sweep, as a Dask worker (or a serial loop) executes it.

A run is ``hbvs repeat --sim`` (:func:`hbvs_cli.stages.repeat.run_repeat`, the same closed
loop, writing the same run file) followed by ``hbvs report --json``
(:func:`hbvs_cli.report.build.build_report` on :func:`hbvs_cli.io.run_file.read_run`),
and its row is a set of that report's values picked by dotted key (:data:`METRICS`). No
part of the loop or of the metrics is copied here, so whatever those stages compute, the
sweep's rows say.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

#: Row column -> the dotted key of ``hbvs report --json`` it holds.
METRICS: dict[str, str] = {
    "converged": "verdict.converged",
    "final_position_m": "pose_error.position_m.final",
    "final_heading_deg": "pose_error.heading_deg.final",
    "settling_time_position_s": "pose_error.position_m.settling_time_s",
    "settling_time_heading_s": "pose_error.heading_deg.settling_time_s",
    "rmse_position_m": "pose_error.position_m.rmse",
    "rmse_heading_deg": "pose_error.heading_deg.rmse",
    "final_e1": "errors.e1.final",
    "final_e2": "errors.e2.final",
    "final_ebar2": "errors.ebar2.final",
    "final_e3_deg": "errors.e3.final",
    "v_ratio": "lyapunov.ratio",
    "v_increase_fraction": "lyapunov.increase_fraction",
    "dhat_initial_m": "depth.dhat_initial",
    "dhat_final_m": "depth.dhat_final",
    "d_true_m": "depth.d_true",
    "dhat_relative_error": "depth.relative_error",
    "lost_fraction": "target.lost_fraction",
    "saturated_fraction": "commands.saturated_fraction",
    "v_peak_mps": "commands.v_peak_mps",
    "w_peak_radps": "commands.w_peak_radps",
    "dv_dt_rms_mps2": "commands.dv_dt_rms_mps2",
    "dw_dt_rms_radps2": "commands.dw_dt_rms_radps2",
    "at_limit_fraction": "commands.at_limit_fraction",
    "dropped_fraction": "target.dropped_fraction",
    "duration_s": "run.duration_s",
    "steps": "run.steps",
    "truncated": "run.truncated",
}
#: Metric columns that are booleans or whole numbers (the rest are floats).
BOOLEAN_METRICS = ("converged", "truncated")
INTEGER_METRICS = ("steps",)

#: What became of a run: reported; reported after ``repeat`` stopped it for a lost
#: target (it did not converge); or failed before a report existed (``error`` says why).
STATUS_OK, STATUS_STOPPED, STATUS_FAILED = "ok", "stopped", "failed"
KEEP_CHOICES = ("failed", "all", "none")


@dataclass(frozen=True)
class RunTask:
    """Everything a worker needs for one run (small: it travels to the worker).

    Attributes
    ----------
    fit_path : str
        The fit file, as the printed command names it (absolute).
    index, point, repeat, seed : int
    values : dict
        The run's parameter values (swept and fixed).
    arguments : dict
        The ``RepeatOptions`` fields of the run besides input and output.
    command : str
        The ``hbvs repeat`` command that re-makes the run.
    keep_path : str or None
        Where to keep the run file (``--keep-runs``); None keeps none.
    keep : str
        ``failed``, ``all`` or ``none``.
    """

    fit_path: str
    index: int
    point: int
    repeat: int
    seed: int
    values: dict[str, Any]
    arguments: dict[str, Any]
    command: str
    keep_path: str | None
    keep: str = "failed"


#: Fit files read by this process (a worker reads each fit once for all its runs).
_FITS: dict[str, Any] = {}


def _fit(path: str) -> Any:
    from ..io.fit_file import read_fit_file

    if path not in _FITS:
        _FITS.clear()
        _FITS[path] = read_fit_file(path)
    return _FITS[path]


def check_arguments(fit: Any, fit_path: str, arguments: Mapping[str, Any]) -> None:
    """Raise what ``hbvs repeat`` would raise for a run with ``arguments`` before it starts
    (its own checks, so a value it refuses the sweep refuses with the same message)."""
    from ..stages.repeat import RepeatOptions, check_simulation_settings, settings_for
    from ..stages.options import parse_interval

    options = RepeatOptions(input=fit_path, output="-", **arguments)
    check_simulation_settings(settings_for(options, fit.model), fit.model)
    for window in options.occlude:
        parse_interval(window, "--occlude")


def report_row(report: Mapping[str, Any]) -> dict[str, Any]:
    """The :data:`METRICS` of a report (None where the report has no such value)."""
    from ..report.build import MissingKey, resolve_key

    row: dict[str, Any] = {}
    for column, key in METRICS.items():
        try:
            value = resolve_key(report, key)
        except MissingKey:
            value = None
        row[column] = value
    return row


def empty_metrics() -> dict[str, Any]:
    return {column: None for column in METRICS}


def keep_file(source: str, destination: str) -> None:
    """Put the run file ``source`` at ``destination`` whole or not at all, also across file
    systems (the workers' temporary folder and the results folder): copied to a partial
    file beside ``destination``, fsynced, renamed; a failure (a full disk) removes it."""
    from ..io.output_target import partial_name_of

    final = Path(destination)
    final.parent.mkdir(parents=True, exist_ok=True)
    partial = partial_name_of(final)
    try:
        with open(source, "rb") as reader, open(partial, "xb") as writer:
            shutil.copyfileobj(reader, writer, 1 << 20)
            writer.flush()
            os.fsync(writer.fileno())
        os.replace(partial, final)
    except BaseException:
        partial.unlink(missing_ok=True)
        raise


def execute_run(task: RunTask) -> dict[str, Any]:
    """Make one run and its report; never raises for a run that fails (the row says why).

    Returns
    -------
    dict
        The row: ``index, point, repeat, seed``, the parameter values, ``status``,
        ``error``, the :data:`METRICS`, ``run_time_s`` (s, this run's own wall time),
        ``run_file`` (kept file or None) and ``command``.
    """
    from ..errors import HbvsError, TargetLostError
    from ..io.run_file import read_run
    from ..stages.console import Console
    from ..stages.repeat import RepeatOptions, run_repeat
    from ..report.build import build_report

    started = time.perf_counter()
    folder = tempfile.mkdtemp(prefix="hbvs-sweep-")
    try:
        run_path = os.path.join(folder, "run.mcap")
        status, error, metrics = STATUS_OK, None, empty_metrics()
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
    return {
        "index": task.index, "point": task.point, "repeat": task.repeat, "seed": task.seed,
        **task.values, "status": status, "error": error, **metrics,
        "run_time_s": time.perf_counter() - started, "run_file": kept, "command": task.command,
    }
