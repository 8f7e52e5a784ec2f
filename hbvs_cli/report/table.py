"""The human-readable report: rich tables on stdout, one column per run, the JSON values to 4
significant digits. Colour on a terminal; elsewhere plain unwrapped text that diffs and greps."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Sequence, TextIO

from ..core.control_settings import GAIN_UNITS
from ..core.metrics import STATISTICS
from .build import CHECK_NAMES, IMAGE_ERRORS, POSE_ERRORS
from .result import ErrorSummary, RunReport, Timing, resolve_key

#: A table row: its label (with the unit) and how to read its value from a report.
Row = tuple[str, Callable[[RunReport], Any]]

#: Width of the plain-text output: wide enough never to wrap a row of a comparison.
PLAIN_WIDTH = 1000
#: What a missing (null) value shows.
MISSING = "n/a"

#: Each error signal's short name and unit.
ERROR_SIGNALS = {
    "e1": ("e1", "d*"), "e2": ("e2", "d*"), "ebar2": ("ebar2", "d*"), "e3": ("e3", "deg"),
    "position_m": ("position", "m"), "heading_deg": ("heading", "deg"),
}
#: Short name of each statistic: ``final`` is a mean of absolute values beside signed
#: statistics, so its name says so.
STATISTIC_NAMES = {name: name for name in STATISTICS} | {"final": "final |.|", "settling_time_s": "settling"}

#: Rows of the metrics table.
METRIC_ROWS: tuple[Row, ...] = (
    ("V initial", lambda r: r.lyapunov.initial), ("V final", lambda r: r.lyapunov.final),
    ("V final / V(0)", lambda r: r.lyapunov.ratio), ("V increase (fraction of steps)", lambda r: r.lyapunov.increase_fraction),
    ("dhat0 (m)", lambda r: r.depth.dhat0), ("dhat final (m)", lambda r: r.depth.dhat_final),
    ("d* true (m)", lambda r: _per_segment(r, r.depth.d_true, "d_true")),
    ("dhat relative error (-)", lambda r: _per_segment(r, r.depth.relative_error, "relative_error")),
    ("dhat within 10 % after (s)", lambda r: r.depth.learning_time_s),
    ("dhat drift at the end (1/s)", lambda r: r.depth.end_rate_per_s),
    ("dhat still moving at the end", lambda r: r.depth.still_moving),
    ("v peak (m/s)", lambda r: r.commands.v_peak_mps), ("v rms (m/s)", lambda r: r.commands.v_rms_mps),
    ("w peak (rad/s)", lambda r: r.commands.w_peak_radps), ("w rms (rad/s)", lambda r: r.commands.w_rms_radps),
    ("saturated (fraction of steps)", lambda r: r.commands.saturated_fraction),
    ("at a limit (fraction of steps)", lambda r: r.commands.at_limit_fraction),
    ("v total variation (m/s per s)", lambda r: r.commands.v_tv_per_s),
    ("w total variation (rad/s per s)", lambda r: r.commands.w_tv_per_s),
    ("RMS dv/dt (m/s^2)", lambda r: r.commands.dv_dt_rms_mps2), ("RMS dw/dt (rad/s^2)", lambda r: r.commands.dw_dt_rms_radps2),
    ("taught RMS dv/dt (m/s^2)", lambda r: r.commands.taught.dv_dt_rms_mps2),
    ("taught RMS dw/dt (rad/s^2)", lambda r: r.commands.taught.dw_dt_rms_radps2),
    ("target lost (frames)", lambda r: r.target.lost_frames), ("target lost (fraction of steps)", lambda r: r.target.lost_fraction),
    ("longest loss (s)", lambda r: r.target.longest_loss_s), ("dropped frames", lambda r: r.target.dropped_frames),
    ("dropped (fraction of steps)", lambda r: r.target.dropped_fraction),
    ("min |x_hd1_dot| run (1/s)", lambda r: r.condition35.min_abs_xhd1_dot),
    ("min |x_hd1_dot| fit (1/s)", lambda r: r.condition35.fit_min_abs_xhd1_dot),
)

#: Rows of a live run's loop timing, shown when a run has them: ``latency_p50_ms`` is "latency p50 (ms)".
TIMING_ROWS: tuple[Row, ...] = tuple(
    (name.removesuffix("_ms").replace("_", " ") + (" (ms)" if name.endswith("_ms") else ""),
     lambda r, name=name: r.timing and getattr(r.timing, name))
    for name in (field.name for field in fields(Timing))
)

#: Row label of each verdict check (``verdict.checks``).
CHECK_LABELS = {
    "closed_loop": "closed loop", "finished": "finished", "final_position": "final position error",
    "final_heading": "final heading error", "final_e1": "final e1", "final_e2": "final e2", "final_e3": "final e3",
    "lyapunov": "V fell (36)", "smoothness": "commands smooth",
}

#: Rows of the run table after the gains.
RUN_ROWS: tuple[Row, ...] = (
    ("law", lambda r: r.run.law), ("mode", lambda r: r.run.source.mode),
    ("fit file", lambda r: r.run.source.fit_file), ("duration (s)", lambda r: r.run.duration_s),
    ("steps", lambda r: r.run.steps), ("rate (Hz)", lambda r: r.run.rate_hz),
    ("truncated", lambda r: r.run.truncated),
)


def format_value(value: Any) -> str:
    """A JSON value as a table cell: numbers to 4 significant digits, null as ``n/a``."""
    if value is None:
        return MISSING
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def _per_segment(report: RunReport, whole: Any, name: str) -> Any:
    """``whole``, the run's value, or a route's ``name`` of each segment (its own d*_i), in order."""
    return whole if report.route is None else ", ".join(format_value(getattr(segment, name)) for segment in report.route)


def run_labels(reports: Sequence[RunReport]) -> list[str]:
    """How tables and legends name the runs: their labels, a shared one followed by the file name."""
    labels = [report.run.label or "run" for report in reports]
    return [
        f"{label} ({Path(report.run.name).name})" if labels.count(label) > 1 else label
        for label, report in zip(labels, reports)
    ]


def new_table(headers: Sequence[str], plain: bool) -> Any:
    """An empty table: left-aligned labels, right-aligned values."""
    from rich import box
    from rich.table import Table

    table = Table(
        box=None if plain else box.SIMPLE_HEAD, pad_edge=not plain, show_edge=not plain,
        header_style=None if plain else "bold",
    )
    for index, header in enumerate(headers):
        table.add_column(header, justify="left" if index == 0 else "right")
    return table


def _plain_text(cell: Any) -> str:
    return cell.plain if hasattr(cell, "plain") else str(cell)


def _table_like(table: Any, columns: Sequence[Any], title: Any = None) -> Any:
    """A table styled like ``table`` holding ``columns`` (their headers, cells and widths), under ``title``."""
    from rich.table import Table

    part = Table(title=title, box=table.box, pad_edge=table.pad_edge, show_edge=table.show_edge, header_style=table.header_style)
    for column in columns:
        part.add_column(column.header, justify=column.justify, min_width=column.min_width, width=column.width,
                        no_wrap=column.no_wrap, overflow=column.overflow)
    for cells in zip(*(list(column.cells) for column in columns)):
        part.add_row(*cells)
    return part


#: Row labels of a table too wide for the terminal wrap to no fewer characters than this
#: (or their longest word).
LABEL_MIN_WIDTH = 24


def _table_overhead(columns: int) -> int:
    """Characters a table of ``columns`` columns spends beside its cells: each column's
    padding (1 each side) and the rules between and around them (at most)."""
    return 3 * columns + 1


def fit_to_width(table: Any, console: Any, keys: int = 1) -> list[Any]:
    """``table`` as tables no wider than ``console`` (docs/report.md, "Output"): ``[table]`` if it fits,
    else each value column as wide as its widest cell (a text wider than the room beside the labels folds),
    the first ``keys`` label columns wrapped down to :data:`LABEL_MIN_WIDTH`, the value columns dealt out."""
    from rich.cells import cell_len

    width = console.width

    def texts(column: Any) -> list[str]:
        return [_plain_text(column.header), *(_plain_text(cell) for cell in column.cells)]

    def longest(pieces: Iterable[str]) -> int:
        return max((cell_len(piece) for piece in pieces), default=1)

    if sum(longest(texts(column)) for column in table.columns) + _table_overhead(len(table.columns)) <= width:
        return [table]
    labels, values = table.columns[:keys], table.columns[keys:]
    for column in labels:
        words = longest(word for text in texts(column) for word in text.split())
        column.min_width = min(longest(texts(column)), max(words, LABEL_MIN_WIDTH))
    label_width = sum(column.min_width for column in labels)
    room = width - label_width - _table_overhead(keys + 1)
    for column in values:
        cells = longest(_plain_text(cell) for cell in column.cells)
        header_words = longest(_plain_text(column.header).split())
        column.width, column.overflow = max(1, min(room, max(cells, header_words))), "fold"
    parts: list[list[Any]] = []
    for column in values:
        if parts and label_width + sum(c.width for c in parts[-1]) + column.width + _table_overhead(keys + len(parts[-1]) + 1) <= width:
            parts[-1].append(column)
        else:
            parts.append([column])
    return [_table_like(table, [*labels, *part], table.title if not number else None) for number, part in enumerate(parts)]


def print_table(console: Any, table: Any, keys: int = 1) -> None:
    """Print ``table`` on ``console`` in as many parts as its width needs (:func:`fit_to_width`)."""
    for index, part in enumerate(fit_to_width(table, console, keys)):
        if index:
            console.print()
        console.print(part)


def _rows_table(rows: Iterable[Row], reports: Sequence[RunReport], plain: bool) -> Any:
    table = new_table(["quantity", *run_labels(reports)], plain)
    for label, value in rows:
        table.add_row(label, *(format_value(value(r)) for r in reports))
    return table


def _run_rows(reports: Sequence[RunReport]) -> list[Row]:
    gains = dict.fromkeys(name for report in reports for name in report.run.gains)
    gain_rows = [(f"gain {name} ({GAIN_UNITS.get(name, '-')})", lambda r, name=name: r.run.gains.get(name)) for name in gains]
    return [("file", lambda r: r.run.name), ("label", lambda r: r.run.label), *RUN_ROWS, *gain_rows]


def _error_matrix(section: Mapping[str, ErrorSummary], names: Sequence[str], plain: bool) -> Any:
    """One run's errors: a row per signal, a column per statistic."""
    headers = [STATISTIC_NAMES[s] + (" (s)" if s == "settling_time_s" else "") for s in STATISTICS]
    table = new_table(["error", *headers], plain)
    for name in names:
        short, unit = ERROR_SIGNALS[name]
        table.add_row(f"{short} ({unit})", *(format_value(getattr(section[name], s)) for s in STATISTICS))
    return table


def _error_rows(section: str, names: Sequence[str]) -> list[Row]:
    """Several runs' errors: a row per (signal, statistic); None where a report lacks the section."""
    return [
        (f"{ERROR_SIGNALS[name][0]} {STATISTIC_NAMES[s]} ({'s' if s == 'settling_time_s' else ERROR_SIGNALS[name][1]})",
         lambda r, name=name, s=s: None if getattr(r, section) is None else getattr(getattr(r, section)[name], s))
        for name in names for s in STATISTICS
    ]


def _error_tables(reports: Sequence[RunReport], console: Any) -> list[tuple[str, Any]]:
    """The image and pose error tables: a matrix for one run if it fits the width, else rows."""
    from rich.measure import Measurement

    plain = not console.is_terminal
    sections = [("errors", IMAGE_ERRORS, "image errors (19), (27): e1, e2, ebar2 in units of d*, e3 in degrees; final |.|: mean of |.| over the last 5 %")]
    if any(r.pose_error is not None for r in reports):
        sections.append(("pose_error", POSE_ERRORS, "pose error against the taught path at the same time (ground truth)"))
    tables = []
    for key, names, title in sections:
        table = _error_matrix(getattr(reports[0], key), names, plain) if len(reports) == 1 else None
        if table is None or Measurement.get(console, console.options.update_width(PLAIN_WIDTH), table).maximum > console.width:
            table = _rows_table(_error_rows(key, names), reports, plain)
        tables.append((title, table))
    return tables


def _verdict_table(reports: Sequence[RunReport], plain: bool) -> Any:
    """``converged`` then one row per check; failed checks in red on a terminal."""
    from rich.text import Text

    table = new_table(["check", *run_labels(reports)], plain)
    # The checks are sentences: left-aligned and wrapped (a word wider than its column folds, never "…").
    for column in table.columns[1:]:
        column.justify, column.no_wrap, column.overflow = "left", False, "fold"

    def styled(text: str, good: bool) -> Text:
        return Text(text, style="green" if good else "red")

    table.add_row("converged", *(styled(format_value(r.verdict.converged), r.verdict.converged) for r in reports))
    for name in CHECK_NAMES:
        cells = [r.verdict.checks.get(name, MISSING) for r in reports]
        if any(cell != MISSING for cell in cells):
            table.add_row(CHECK_LABELS[name], *(styled(c, not c.startswith("fail")) for c in cells))
    return table


def report_tables(reports: Sequence[RunReport], console: Any) -> list[tuple[str, Any]]:
    """Every table of the report with its title, in print order (plain unless ``console`` is a terminal)."""
    plain = not console.is_terminal
    return [
        ("run", _rows_table(_run_rows(reports), reports, plain)),
        *_error_tables(reports, console),
        ("Lyapunov function (36), depth, commands, target, condition (35)", _rows_table(METRIC_ROWS, reports, plain)),
        *([("live loop: frame-to-command latency, frames dropped or late", _rows_table(TIMING_ROWS, reports, plain))]
          if any(report.timing is not None for report in reports) else []),
        *[(f"route of {label}: each segment from its switch, V (36) against its d*_i", _route_table(report.route, plain))
          for label, report in zip(run_labels(reports), reports) if report.route is not None],
        ("verdict (convergence rule: docs/report.md)", _verdict_table(reports, plain)),
    ]


def _route_table(segments: Sequence[Any], plain: bool) -> Any:
    """One row per segment of a route's run: target, switch time, V at its start and end, d*_i and dhat at its end (relative error)."""
    table = new_table(("segment", "target", "from (s)", "V start", "V end", "d* (m)", "dhat (m)", "rel. error"), plain)
    for number, segment in enumerate(segments):
        table.add_row(str(number + 1), f"{segment.target} {segment.target_kind}", *(format_value(value) for value in (
            segment.t_start, segment.V_start, segment.V_end, segment.d_true, segment.dhat_end, segment.relative_error)))
    return table


def report_console(stream: TextIO) -> Any:
    """A rich console on ``stream``: colour on a terminal, else plain and never wrapped."""
    from rich.console import Console

    settings: dict[str, Any] = {"file": stream, "highlight": False, "markup": False, "emoji": False}
    console = Console(**settings)
    return console if console.is_terminal else Console(**settings, color_system=None, width=PLAIN_WIDTH)


def print_title(console: Any, text: str) -> None:
    """A title on a line of its own (a rich table title wraps to the table's width)."""
    from rich.text import Text

    console.print(Text(text, style="bold cyan" if console.is_terminal else ""))


def print_report_tables(reports: Sequence[RunReport], stream: TextIO, console: Any = None) -> None:
    """Print the report on ``stream`` (stdout), or on ``console`` (a rich Console) when given."""
    console = console or report_console(stream)
    tables = report_tables(reports, console)
    for index, (title, table) in enumerate(tables):
        if index:
            console.print()
        print_title(console, title)
        if index < len(tables) - 1:
            print_table(console, table)
        else:
            # The verdict's sentences wrap to the reader's terminal even through a pipe.
            console.print(table, width=None if console.is_terminal else min(console.width, reading_width()))


def reading_width() -> int:
    """Columns of the terminal the user reads in: $COLUMNS, else stderr's terminal, else 100."""
    import os

    columns = os.environ.get("COLUMNS", "")
    if columns.isdigit() and int(columns) > 0:
        return int(columns)
    try:
        return os.get_terminal_size(2).columns
    except OSError:
        return 100


#: Rows of the fit table: label with unit, dotted key of :func:`~hbvs_cli.report.fit_plot.fit_summary`.
FIT_ROWS: tuple[tuple[str, str], ...] = (
    ("frames with a raw sample", "frames_raw"),
    ("frames on the spline", "frames_smooth"),
    ("theta_d raw - smooth, rms (deg)", "raw_minus_smooth.theta_d_deg.rms"),
    ("theta_d raw - smooth, max |.| (deg)", "raw_minus_smooth.theta_d_deg.max_abs"),
    ("x_hd1 raw - smooth, rms (d*)", "raw_minus_smooth.x_hd1.rms"),
    ("x_hd1 raw - smooth, max |.| (d*)", "raw_minus_smooth.x_hd1.max_abs"),
    ("x_hd2 raw - (25), rms (d*)", "raw_minus_smooth.x_hd2.rms"),
    ("x_hd2 raw - (25), max |.| (d*)", "raw_minus_smooth.x_hd2.max_abs"),
    ("min |x_hd1_dot| (1/s), condition (35)", "x_hd1_dot.min_abs"),
    ("max |x_hd1_dot| (1/s)", "x_hd1_dot.max_abs"),
    ("raw finite difference - x_hd1_dot, rms (1/s)", "x_hd1_dot.raw_difference_rms"),
)


def print_fit_table(summary: Mapping[str, Any], stream: TextIO, console: Any = None) -> None:
    """The numbers of a fit file (``hbvs report fit.mcap``) as one table on ``stream`` (or ``console``)."""
    console = console or report_console(stream)
    table = new_table(["quantity", Path(str(summary["file"])).name], not console.is_terminal)
    for label, key in FIT_ROWS:
        table.add_row(label, format_value(resolve_key(summary, key)))
    print_title(console, "desired trajectory (Remark 1): raw homography decomposition against the splines")
    print_table(console, table)
