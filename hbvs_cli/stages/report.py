"""``hbvs report``: how well did the repeat follow the taught path, and did it converge?

Reads one or more run files (``-`` reads stdin, at most once), builds each run's report
(:func:`hbvs_cli.tools.report_data.build_report`), prints the table or the JSON on stdout
(and nothing else there), writes the figure and the TUM files when asked, and finally
checks the ``--fail-above`` bounds. Every option is checked before anything is printed, so
a mistyped key fails with exit code 2 and no half-written output.
"""

from __future__ import annotations

import io
import json
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

from ..errors import UsageError
from .console import Console
from .options import parse_assignment


@dataclass(frozen=True)
class ReportOptions:
    """Everything ``hbvs report`` was asked to do (see ``hbvs report --help``)."""

    runs: list[str]
    json_output: bool = False
    plot: Path | None = None
    fail_above: list[str] = field(default_factory=list)
    export_tum: Path | None = None
    tolerance: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class Bound:
    """One ``--fail-above KEY=VALUE``: fail when the metric at dotted ``key`` exceeds ``value``."""

    key: str
    value: float


# ----------------------------------------------------------------------------- options
def parse_tolerances(items: Sequence[str]) -> dict[str, float]:
    """``--tolerance NAME=VALUE`` options -> the full tolerance table (defaults for the rest)."""
    from ..tools.report_data import resolve_tolerances

    return resolve_tolerances(dict(parse_assignment(item, "--tolerance") for item in items))


def parse_bounds(items: Sequence[str]) -> list[Bound]:
    """``--fail-above KEY=VALUE`` options -> :class:`Bound` list (keys checked later, per run)."""
    return [Bound(*parse_assignment(item, "--fail-above")) for item in items]


def metric_value(report: Mapping[str, Any], key: str) -> float:
    """The number at a dotted key of a report (``pose_error.position_m.final``).

    Raises
    ------
    UsageError
        The key does not exist in this report, names a group rather than a number, or its
        value is null for this run (e.g. ``lyapunov.final`` of a replay).
    """
    from ..tools.report_data import MissingKey, resolve_key

    try:
        value = resolve_key(report, key)
    except MissingKey as missing:
        choices = ", ".join(missing.choices) or "none (it is a value)"
        raise UsageError(
            f"--fail-above {key}: {missing.where} has no key {missing.part!r} in {report['run']['name']} (keys: {choices})"
        ) from None
    if isinstance(value, Mapping):
        raise UsageError(f"--fail-above {key}: names a group, not a number; use one of {', '.join(f'{key}.{k}' for k in value)}")
    if value is None:
        raise UsageError(
            f"--fail-above {key}: the value is null for {report['run']['name']} (unknown for this run, e.g. V without "
            "ground truth, or a settling time that never settled), so the bound cannot be checked"
        )
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise UsageError(f"--fail-above {key}: {value!r} is not a number")
    return float(value)


def exceeded_bounds(reports: Sequence[Mapping[str, Any]], bounds: Sequence[Bound]) -> list[str]:
    """One message per (run, bound) whose metric exceeds the bound.

    Raises :class:`UsageError` for a bad key (see :func:`metric_value`), so call it before
    printing anything.
    """
    messages = []
    for report in reports:
        for bound in bounds:
            value = metric_value(report, bound.key)
            if value > bound.value:
                messages.append(f"{report['run']['name']}: {bound.key} = {value:.6g} exceeds the bound {bound.value:g}")
    return messages


# ----------------------------------------------------------------------------- reading
def _source(text: str, keep_stdin: bool) -> Any:
    """What :func:`read_run` reads: a path, ``-``, or stdin buffered (to read it twice)."""
    if text == "-" and keep_stdin:
        return io.BytesIO(sys.stdin.buffer.read())
    return text


def read_runs(sources: Sequence[str], need_height: bool) -> list[tuple[Any, float | None]]:
    """Every run, with its camera height (m) when ``need_height`` (for TUM files).

    Raises
    ------
    UsageError
        No run, or ``-`` given more than once (stdin can be read only once).
    """
    from ..io.run_file import read_run
    from ..tools.tum import camera_height_m

    if not sources:
        raise UsageError("give at least one run file (or - for stdin)")
    if list(sources).count("-") > 1:
        raise UsageError("- (stdin) can be given only once")
    loaded = []
    for text in sources:
        name = "stdin" if text == "-" else text
        source = _source(text, need_height)
        run = read_run(source, name=name)
        height = None
        if need_height and run.true_pose is not None:
            if isinstance(source, io.BytesIO):
                source.seek(0)
            height = camera_height_m(source, name)
        loaded.append((run, height))
    return loaded


# ----------------------------------------------------------------------------- output
def print_reports(reports: Sequence[Mapping[str, Any]], json_output: bool) -> None:
    """The table, or the JSON (one run: its report; several: ``{"runs": [...]}``), on stdout."""
    if json_output:
        document = reports[0] if len(reports) == 1 else {"runs": list(reports)}
        sys.stdout.write(json.dumps(document, indent=2, allow_nan=False) + "\n")
    else:
        from ..tools.report_table import print_report_tables

        print_report_tables(reports, sys.stdout)
    sys.stdout.flush()


def run_report(options: ReportOptions, console: Console) -> int:
    """Run ``hbvs report``.

    Returns
    -------
    int
        0, or 1 when a ``--fail-above`` bound was exceeded (one line on stderr per excess).

    Raises
    ------
    UsageError
        A malformed option, a ``--fail-above`` key missing or null in a report, or
        ``--export-tum`` for a run without ground truth (exit code 2).
    InputError, RecordingError
        A missing or unreadable file, or not a run file (exit code 3).
    """
    from ..tools.report_data import build_report

    if len(options.runs) == 1 and Path(options.runs[0]).is_dir():
        return _report_sweep(options)
    tolerances = parse_tolerances(options.tolerance)
    bounds = parse_bounds(options.fail_above)
    if options.plot is not None:
        from ..tools.plots import check_plot_path

        check_plot_path(options.plot)
    loaded = read_runs(options.runs, need_height=options.export_tum is not None)
    runs = [run for run, _ in loaded]
    reports = [build_report(run, tolerances) for run in runs]
    excesses = exceeded_bounds(reports, bounds)
    if options.export_tum is not None:
        from ..tools.tum import check_exportable

        check_exportable(runs, options.export_tum)
    print_reports(reports, options.json_output)
    if options.plot is not None:
        from ..tools.plots import save_plot

        save_plot(runs, reports, options.plot)
        console.info(f"report: figure written to {options.plot}")
    if options.export_tum is not None:
        from ..tools.tum import write_tum

        for run, height in loaded:
            taught, repeated = write_tum(run, options.export_tum, height if height is not None else 0.0)
            console.info(f"report: TUM trajectories written to {taught} and {repeated}")
    for message in excesses:
        console.warn(f"threshold exceeded: {message}")
    return 1 if excesses else 0


def _report_sweep(options: ReportOptions) -> int:
    """``hbvs report RESULTS/``: the summary of a sweep's table (as ``hbvs sweep`` printed it)."""
    from ..tools.sweep_summary import print_summary, print_summary_json, summarize

    if options.plot or options.fail_above or options.export_tum or options.tolerance:
        raise UsageError("a sweep's results folder takes only --json (its figures are in the folder)")
    try:
        import pyarrow  # noqa: F401
    except ImportError:
        raise UsageError("reading a sweep's table needs pyarrow: pip install 'hbvs[sweep]'") from None
    summary = summarize(Path(options.runs[0]))
    if options.json_output:
        print_summary_json(summary, sys.stdout)
    else:
        print_summary(summary, sys.stdout)
    sys.stdout.flush()
    return 0
