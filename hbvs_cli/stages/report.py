"""``hbvs report``: how well did the repeat follow the taught path, and did it converge?
Every option is checked before anything is printed; stdout carries only the table or the JSON."""

from __future__ import annotations

import io
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, Sequence

from ..errors import UsageError
from ..settings.commands import ReportOptions
from .console import Console, print_document
from .options import parse_assignment

if TYPE_CHECKING:
    from ..report.result import RunReport


def metric_value(report: RunReport, key: str) -> float:
    """The number at a dotted key of a report; UsageError when it is missing, a group, or null."""
    from ..report.result import MissingKey

    try:
        value = report.value(key)
    except MissingKey as missing:
        choices = ", ".join(missing.choices) or "none (it is a value)"
        raise UsageError(
            f"--fail-above {key}: {missing.where} has no key {missing.part!r} in {report.run.name} (keys: {choices})"
        ) from None
    if isinstance(value, Mapping):
        raise UsageError(f"--fail-above {key}: names a group, not a number; use one of {', '.join(f'{key}.{k}' for k in value)}")
    if value is None:
        raise UsageError(
            f"--fail-above {key}: the value is null for {report.run.name} (unknown for this run, e.g. V without "
            "ground truth, or a settling time that never settled), so the bound cannot be checked"
        )
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise UsageError(f"--fail-above {key}: {value!r} is not a number")
    return float(value)


def exceeded_bounds(reports: Sequence[RunReport], bounds: Sequence[tuple[str, float]]) -> list[str]:
    """One message per (run, ``--fail-above`` (key, bound)) whose metric exceeds the bound; call it before printing."""
    checked = [(report, key, bound, metric_value(report, key)) for report in reports for key, bound in bounds]
    return [f"{report.run.name}: {key} = {value:.6g} exceeds the bound {bound:g}"
            for report, key, bound, value in checked if value > bound]


def check_labels(labels: Sequence[str], runs: Sequence[str]) -> None:
    if labels and len(labels) != len(runs):
        raise UsageError(f"--label: give one per run, in order ({len(runs)} run(s), {len(labels)} label(s))")
    if any(not label.strip() for label in labels):
        raise UsageError("--label: a label cannot be empty")


def read_runs(sources: Sequence[str]) -> list[Any]:
    """Every run (:class:`~hbvs_cli.io.run_file.RunData`); a fit file as its :class:`~hbvs_cli.report.fit_plot.FitSignals`."""
    from ..io.run_file import NotARunFile, read_run
    from ..report.fit_plot import read_fit_signals

    if not sources:
        raise UsageError("give at least one run file (or - for stdin)")
    if list(sources).count("-") > 1:
        raise UsageError("- (stdin) can be given only once")
    loaded: list[Any] = []
    for text in sources:
        name = "stdin" if text == "-" else text
        # stdin is kept in memory: a fit file is read twice.
        source = io.BytesIO(sys.stdin.buffer.read()) if text == "-" else text
        try:
            loaded.append(read_run(source, name=name))
        except NotARunFile as other:
            if other.kind != "fit":
                raise
            if isinstance(source, io.BytesIO):
                source.seek(0)
            loaded.append(read_fit_signals(source, name))
    return loaded


def run_fit_report(fit: Any, options: ReportOptions, console: Console) -> int:
    """``hbvs report fit.mcap``: the fit's numbers and, with ``--plot``, its figure."""
    from ..report.figure_style import figure_style, save_figure
    from ..report.fit_plot import FIT_PANELS, fit_summary, plot_fit
    from ..report.table import print_fit_table

    for given, flag in ((options.fail_above, "--fail-above"), (options.require_converged, "--require-converged"),
                        (options.export_tum, "--export-tum"), (options.tolerance, "--tolerance"), (options.labels, "--label")):
        if given:
            raise UsageError(f"{flag} applies to run files; {fit.name} is a fit file")
    style = figure_style(options.dpi, options.size, options.panels, FIT_PANELS) if options.plot is not None else None
    summary = fit_summary(fit)
    print_document(summary, options.json_output, print_fit_table)
    if options.plot is not None:
        save_figure(plot_fit(fit, style), options.plot, style.dpi)
        console.info(f"report: fit figure written to {options.plot}")
    return 0


def run_report(options: ReportOptions, console: Console) -> int:
    """Run ``hbvs report``: 0, or 1 when a ``--fail-above`` or ``--require-converged`` check failed."""
    from ..report.figure_style import check_plot_path, figure_style
    from ..report.fit_plot import FIT_PANELS, FitSignals
    from ..report.plots import PANEL_NAMES, check_figure_size, save_plot
    from ..report.build import build_report, resolve_tolerances
    from ..report.table import print_report_tables
    from ..report.tum import check_exportable, tum_paths, write_tum
    from ..io.output_target import refuse_overwriting_inputs

    if len(options.runs) == 1 and Path(options.runs[0]).is_dir():
        return _report_sweep(options, console)
    tolerances = resolve_tolerances(dict(parse_assignment(item, "--tolerance") for item in options.tolerance))
    bounds = [parse_assignment(item, "--fail-above") for item in options.fail_above]
    inputs = [("run", text) for text in options.runs]
    check_labels(options.labels, options.runs)
    if options.plot is not None:
        check_plot_path(options.plot)
        refuse_overwriting_inputs([("--plot", options.plot)], inputs)
        # Checked against either figure's panels now, against the right one's below.
        figure_style(options.dpi, options.size, options.panels, PANEL_NAMES + FIT_PANELS)
    elif options.dpi is not None or options.size is not None or options.panels is not None:
        raise UsageError("--dpi, --size and --panels shape the figure: give --plot FILE too")
    runs = read_runs(options.runs)
    fits = [item for item in runs if isinstance(item, FitSignals)]
    if fits:
        if len(runs) > 1:
            raise UsageError("give run files, or one fit file (for the fit figure), not both or several fits")
        return run_fit_report(fits[0], options, console)
    if options.plot is not None:
        style = figure_style(options.dpi, options.size, options.panels, PANEL_NAMES)
        check_figure_size(runs, style)
    reports = [build_report(run, tolerances, label) for run, label in zip(runs, options.labels or [None] * len(runs))]
    excesses = exceeded_bounds(reports, bounds)
    if options.export_tum is not None:
        check_exportable(runs, options.export_tum)
        tum_files = [("--export-tum", path) for run in runs for path in tum_paths(run, options.export_tum)]
        refuse_overwriting_inputs([("--plot", options.plot), *tum_files], inputs)
    # The tables, or the JSON: one run's report, several runs' as {"runs": [...]}.
    documents = [report.to_dict() for report in reports] if options.json_output else []
    print_document(documents[0] if len(documents) == 1 else {"runs": documents}, options.json_output,
                   lambda _, out: print_report_tables(reports, out))
    if options.plot is not None:
        save_plot(runs, reports, options.plot, style, tolerances)
        console.info(f"report: figure written to {options.plot}")
    if options.export_tum is not None:
        for run in runs:
            taught, repeated = write_tum(run, options.export_tum)
            console.info(f"report: TUM trajectories written to {taught} and {repeated}")
    for message in excesses:
        console.warn(f"threshold exceeded: {message}")
    unconverged = [f"{report.run.name}: {'; '.join(report.verdict.failures())}"
                   for report in reports if options.require_converged and not report.verdict.converged]
    for message in unconverged:
        console.warn(f"not converged: {message}")
    return 1 if excesses or unconverged else 0


def _report_sweep(options: ReportOptions, console: Console) -> int:
    """``hbvs report RESULTS/``: the summary of a sweep's table."""
    from ..report.sweep_summary import print_summary, summarize

    if options.plot or options.fail_above or options.export_tum or options.tolerance:
        raise UsageError("a sweep's results folder takes only --json (its figures are in the folder)")
    try:
        import pyarrow  # noqa: F401
    except ImportError:
        raise UsageError("reading a sweep's table needs pyarrow: pip install 'hbvs[sweep]'") from None
    check_labels(options.labels, options.runs)
    summary = summarize(Path(options.runs[0]), options.labels[0] if options.labels else None)
    print_document(summary, options.json_output, print_summary)
    if options.require_converged:
        runs = summary["runs"]
        converged = summary["overall"]["converged"]
        # Every planned run must have converged (a sweep with none fails).
        if runs["planned"] == 0 or converged < runs["planned"]:
            console.warn(f"not converged: {runs['planned'] - converged} of {runs['planned']} runs of the sweep "
                         f"({runs['failed']} failed, {runs['stopped']} stopped, {runs['planned'] - runs['done']} not run)")
            return 1
    return 0
