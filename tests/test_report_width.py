"""Every table a person reads, rendered at 80 columns (issue 46): no cell is cut (no "…"),
no line is wider than 80, and every number of the data is in the output whole.

The run report (one run, and the demo's two runs with its verdict), a fit's table (``hbvs
report fit.mcap``), the fit stage's own table and ``hbvs info``; the sweep summary's is in
tests/test_sweep.py (it needs the sweep that file runs).
"""

from __future__ import annotations

import io
import re

import pytest
from rich.console import Console

from hbvs_cli.io.run_file import read_run
from hbvs_cli.report.build import build_report

WIDTH = 80


def console_at(width: int, terminal: bool) -> tuple[Console, io.StringIO]:
    """A rich console ``width`` characters wide writing into a string (a terminal's boxes or plain)."""
    buffer = io.StringIO()
    return Console(file=buffer, width=width, force_terminal=terminal, color_system=None, highlight=False), buffer


def cell_texts(table) -> list[str]:
    """Every cell of a rich table as text, headers left out."""
    return [cell.plain if hasattr(cell, "plain") else str(cell) for column in table.columns for cell in column.cells]


def assert_whole(text: str, cells, width: int = WIDTH) -> int:
    """No ellipsis, no line wider than ``width``, each word of each cell a word of ``text``
    (a word wider than half the width, a path, may be folded over lines: its pieces follow
    each other); returns how many words were checked."""
    assert "…" not in text
    widest = max(len(line.rstrip()) for line in text.splitlines())
    assert widest <= width, widest
    words = set(text.split())
    joined = "".join(text.split())
    checked = 0
    for cell in cells:
        for word in str(cell).split():
            assert word in words or (len(word) > width // 2 and word in joined), word
            checked += 1
    return checked


@pytest.fixture(scope="module")
def demo_reports(default_image_runs):
    return [build_report(read_run(default_image_runs[law])) for law in ("lateral-gain", "paper")]


@pytest.mark.parametrize("terminal", [True, False])
def test_the_demo_report_and_its_verdict_fit_80_columns(demo_reports, terminal):
    from hbvs_cli.report.table import format_value, print_report_tables, report_tables

    console, buffer = console_at(WIDTH, terminal)
    print_report_tables(demo_reports, buffer, console=console)
    text = buffer.getvalue()
    wide, _ = console_at(10_000, terminal)
    cells = [cell for _, table in report_tables(demo_reports, wide) for cell in cell_texts(table)]
    assert assert_whole(text, cells) > 400
    # The numbers straight from the reports, not from the tables built for the check.
    for report in demo_reports:
        for value in (report.errors["e1"].rmse, report.pose_error["position_m"].final, report.depth.dhat_final,
                      report.commands.v_peak_mps, report.run.gains["gamma"]):
            assert format_value(value) in text.split()
    assert text.count("converged") >= 1 and "final |.|" in text


def test_one_run_report_fits_80_columns(demo_reports):
    from hbvs_cli.report.table import print_report_tables, report_tables

    console, buffer = console_at(WIDTH, True)
    print_report_tables(demo_reports[:1], buffer, console=console)
    wide, _ = console_at(10_000, True)
    cells = [cell for _, table in report_tables(demo_reports[:1], wide) for cell in cell_texts(table)]
    assert assert_whole(buffer.getvalue(), cells) > 100


def test_a_table_too_wide_is_dealt_out_to_parts_that_repeat_the_labels():
    """Seven columns of 14-character numbers do not fit 80: parts of whole columns, each
    with the row labels, in column order."""
    from hbvs_cli.report.table import fit_to_width, new_table

    values = [[f"{row * 1.0e-9 + column:.9e}" for column in range(7)] for row in range(3)]
    table = new_table(["quantity", *(f"run {c}" for c in range(7))], plain=False)
    for row, cells in enumerate(values):
        table.add_row(f"row label {row}", *cells)
    console, buffer = console_at(WIDTH, True)
    parts = fit_to_width(table, console)
    assert len(parts) > 1
    assert [cell_texts(part)[:3] for part in parts] == [["row label 0", "row label 1", "row label 2"]] * len(parts)
    shown = [column.header for part in parts for column in part.columns[1:]]
    assert shown == [f"run {c}" for c in range(7)]
    for part in parts:
        console.print(part)
    assert assert_whole(buffer.getvalue(), [cell for row in values for cell in row]) == 21


def test_the_fit_report_fits_80_columns(default_fit):
    from hbvs_cli.report.fit_plot import fit_summary, read_fit_signals
    from hbvs_cli.report.result import resolve_key
    from hbvs_cli.report.table import FIT_ROWS, format_value, print_fit_table

    summary = fit_summary(read_fit_signals(default_fit[0]))
    console, buffer = console_at(WIDTH, True)
    print_fit_table(summary, buffer, console=console)
    numbers = [format_value(resolve_key(summary, key)) for _, key in FIT_ROWS]
    assert assert_whole(buffer.getvalue(), numbers) == len(FIT_ROWS)


def test_the_fit_stage_table_fits_80_columns(short_teach, tmp_path, monkeypatch):
    """``hbvs fit`` prints its table on stderr: at 80 columns its values wrap between
    words, never inside a number."""
    from hbvs_cli.stages.console import Console as StageConsole
    from hbvs_cli.stages.fit import FitOptions, run_fit

    monkeypatch.setenv("COLUMNS", str(WIDTH))
    stream = io.StringIO()
    run_fit(FitOptions(input=str(short_teach), output=str(tmp_path / "fit.mcap")), StageConsole(stream=stream))
    text = stream.getvalue()
    # The table, from its title to its bottom rule (warnings after it are sentences on lines of their own).
    table = text[text.index("hbvs fit:"):text.index("\n", text.index("└")) + 1]
    model_numbers = re.findall(r"[-+]?\d+\.\d+", table)
    assert len(model_numbers) > 20
    assert assert_whole(table, []) == 0
    from hbvs_cli.io.fit_file import read_fit_file

    model = read_fit_file(tmp_path / "fit.mcap").model
    for number in (f"{model.dhat0:.3f}", f"{model.residual_px.rms:.3f}", f"{model.normal[1]:+.3f},"):
        assert number in table.split(), number


def test_info_fits_80_columns_and_rounds_for_display_only(default_image_runs):
    """``hbvs info``: lines of at most 80 characters, no word split, the rate of 30 Hz
    shown as ``rate=30`` (its JSON keeps every digit)."""
    from hbvs_cli.io.file_info import read_file_info
    from hbvs_cli.stages.info import info_document, print_info

    document = info_document(read_file_info(str(default_image_runs["paper"])))
    out = io.StringIO()
    print_info(document, out, width=WIDTH)
    text = out.getvalue()
    settings = document["settings"]
    assert isinstance(settings["rate"], float) and settings["rate"] != 30.0 and abs(settings["rate"] - 30.0) < 1e-6
    assert "rate=30" in text.split()
    numbers = [str(document["messages"]), f"{document['duration_s']:.3f}", *(str(t["messages"]) for t in document["topics"]),
               f"law={settings['law']}", f"seed={settings['seed']}"]
    assert assert_whole(text, numbers) == len(numbers)
    assert all(t["topic"] in text.split() for t in document["topics"])
