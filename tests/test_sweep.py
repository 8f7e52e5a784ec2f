"""``hbvs sweep`` end to end, on a real Dask LocalCluster of 2 worker processes over TCP.

A 16-run sweep (points perception, 0.2 px of noise, 4 laws x 2 lateral offsets x 2
repeats) on the sample fit: every row is present; every row is what ``hbvs repeat`` with the
printed options and ``hbvs report --json`` give (the run file byte for byte, the metrics
value for value); a sweep killed with SIGTERM keeps valid rows and, run again on one
worker instead of two, ends with the same table as the uninterrupted one.
"""

from __future__ import annotations

import csv
import io
import json
import shlex
import signal
import subprocess
import sys
import time
from contextlib import redirect_stdout

import numpy as np
import pytest

from conftest import SAMPLES, call_hbvs, run_hbvs

pytest.importorskip("distributed")
pytest.importorskip("pyarrow")

FIT = SAMPLES / "fit.mcap"
SPEC = """
seed = 15
repeats = 2
[fixed]
perception = "points"
pixel_noise = 0.2
[vary]
law = ["lateral-gain", "paper", "non-adaptive", "kanayama"]
offset_y = {from = -0.1, to = 0.1, steps = 2}
"""
RUNS = 16
#: Columns that depend on where and when a sweep ran, not on what it computed.
CIRCUMSTANTIAL = ("run_time_s", "run_file")


def sweep_command(spec, folder, *extra, workers=2):
    return [sys.executable, "-m", "hbvs_cli", "sweep", str(FIT), "--spec", str(spec), "-o", str(folder), "--workers", str(workers), "--quiet", *extra]


@pytest.fixture(scope="module")
def spec_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("spec") / "sweep.toml"
    path.write_text(SPEC)
    return path


@pytest.fixture(scope="module")
def uninterrupted(spec_file, tmp_path_factory):
    folder = tmp_path_factory.mktemp("sweep") / "results"
    result = subprocess.run(sweep_command(spec_file, folder, "--keep-runs", "all", "--json"), capture_output=True, timeout=600)
    assert result.returncode == 0, result.stderr.decode()
    return folder, json.loads(result.stdout)


def table(folder):
    import pyarrow.parquet as pq

    return pq.read_table(folder / "runs.parquet").to_pylist()


def test_every_row_is_present_in_parquet_and_csv(uninterrupted):
    folder, summary = uninterrupted
    rows = table(folder)
    assert [r["index"] for r in rows] == list(range(RUNS))
    assert all((r["status"], r["error"] is None) in (("ok", True), ("stopped", False)) for r in rows)
    # Every (law, offset) point twice, with distinct seeds.
    points = {(r["law"], r["offset_y"]) for r in rows}
    assert len(points) == 8 and len({r["seed"] for r in rows}) == RUNS
    with open(folder / "runs.csv", newline="") as handle:
        csv_rows = list(csv.DictReader(handle))
    assert [int(r["index"]) for r in csv_rows] == list(range(RUNS))
    for row, text in zip(rows, csv_rows):
        if row["final_position_m"] is not None:
            assert float(text["final_position_m"]) == pytest.approx(row["final_position_m"], rel=1e-12)
    # The summary counts them all; the figures were drawn.
    assert summary["runs"]["done"] == RUNS and summary["overall"]["runs"] == RUNS
    assert {entry["law"] for entry in summary["by_law"]} == {"lateral-gain", "paper", "non-adaptive", "kanayama"}
    assert sum(e["runs"] for e in summary["by_parameter"]["offset_y"]) == RUNS
    for name in ("convergence_map.png", "final_error_cdf.png", "final_error_vs_parameters.png"):
        assert (folder / name).stat().st_size > 10_000


def test_each_row_is_hbvs_repeat_with_the_printed_options_and_hbvs_report(uninterrupted, tmp_path):
    """Every run re-made alone from its printed command: the same bytes, the same metrics."""
    from hbvs_cli.cli.app import _run
    from hbvs_cli.io.sweep_table import METRICS
    from hbvs_cli.report.result import resolve_key

    folder, _ = uninterrupted
    for row in table(folder):
        words = shlex.split(row["command"])
        assert words[:2] == ["hbvs", "repeat"] and f"--seed={row['seed']}" in words
        remade = tmp_path / f"run-{row['index']}.mcap"
        args = words[1:-1] + [str(remade), "--quiet"]
        code = _run(args, debug=False)
        assert code == (5 if row["status"] == "stopped" else 0)
        assert remade.read_bytes() == (folder / "runs" / f"run-{row['index']:06d}.mcap").read_bytes()
        out = io.StringIO()
        with redirect_stdout(out):
            assert _run(["report", str(remade), "--json"], debug=False) == 0
        report = json.loads(out.getvalue())
        for column, key in METRICS.items():
            assert row[column] == resolve_key(report, key), (row["index"], column)


def test_a_row_re_made_by_the_hbvs_commands_in_a_shell(uninterrupted, tmp_path):
    """The same as a user at a shell: the printed command, then hbvs report --json."""
    from hbvs_cli.io.sweep_table import METRICS
    from hbvs_cli.report.result import resolve_key

    folder, _ = uninterrupted
    row = table(folder)[11]
    words = shlex.split(row["command"])
    remade = tmp_path / "remade.mcap"
    assert run_hbvs(*words[1:-1], str(remade), "-q").returncode == (5 if row["status"] == "stopped" else 0)
    assert remade.read_bytes() == (folder / "runs" / "run-000011.mcap").read_bytes()
    report = json.loads(run_hbvs("report", str(remade), "--json", check=True).stdout)
    assert {c: row[c] for c in METRICS} == {c: resolve_key(report, k) for c, k in METRICS.items()}


def test_killed_and_resumed_gives_the_same_table(uninterrupted, spec_file, tmp_path):
    import pyarrow.parquet as pq

    from hbvs_cli.io.sweep_table import read_rows

    folder, _ = uninterrupted
    resumed = tmp_path / "resumed"
    # One worker (a worker process less to start, twice): the rows do not depend on how many.
    process = subprocess.Popen(sweep_command(spec_file, resumed, "--keep-runs", "none", "--no-plots", workers=1),
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 300
    # The first part is written with the first finished run alone, however fast the cluster
    # starts (the CI's once started in under the 2 s flush interval, and the first part held
    # all 16 rows); 15 runs are left then.
    while not (resumed / "parts" / "part-000001.parquet").exists() and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    process.send_signal(signal.SIGTERM)
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == 143, stderr.decode()
    partial = read_rows(resumed).to_pylist()
    assert 0 < len(partial) < RUNS, "the sweep was not interrupted midway"
    assert pq.read_metadata(resumed / "parts" / "part-000001.parquet").num_rows == 1
    with open(resumed / "runs.csv", newline="") as handle:
        assert len(list(csv.DictReader(handle))) == len(partial)
    # The same command again: skips the done runs, finishes the rest.
    command = [word for word in sweep_command(spec_file, resumed, "--keep-runs", "none", "--no-plots", "--json", workers=1) if word != "--quiet"]
    result = subprocess.run(command, capture_output=True, timeout=600)
    assert result.returncode == 0, result.stderr.decode()
    assert f"; {len(partial)} already done" in result.stderr.decode()
    assert f"sweep: {RUNS - len(partial)} runs in" in result.stderr.decode()

    def comparable(rows):
        return [{k: v for k, v in r.items() if k not in CIRCUMSTANTIAL} for r in rows]

    assert comparable(table(resumed)) == comparable(table(folder))


def test_another_spec_is_refused_in_the_same_folder(uninterrupted, capsys):
    from hbvs_cli.cli.app import _run

    folder, _ = uninterrupted
    before = (folder / "runs.parquet").read_bytes()
    assert _run(["sweep", str(FIT), "--vary", "offset_y=0,0.1", "-o", str(folder), "-q"], debug=False) == 2
    error = capsys.readouterr().err
    assert "another sweep" in error and error.count("\n") == 1
    assert (folder / "runs.parquet").read_bytes() == before


def test_report_prints_the_summary_again(uninterrupted, capsys):
    from hbvs_cli.cli.app import _run

    folder, summary = uninterrupted
    # In this process: the JSON's printing through a real process is the uninterrupted sweep's.
    again = call_hbvs("report", str(folder), "--json")
    assert again.returncode == 0 and json.loads(again.stdout) == summary
    assert _run(["report", str(folder)], debug=False) == 0
    text = capsys.readouterr().out
    assert "by offset_y" in text and "kanayama" in text and "95 % CI (Wilson)" in text


def test_summary_rates_are_the_verdicts_of_the_rows(uninterrupted):
    from hbvs_cli.report.sweep_summary import wilson_interval

    folder, summary = uninterrupted
    rows = table(folder)
    for entry in summary["by_law"]:
        mine = [r for r in rows if r["law"] == entry["law"]]
        converged = sum(bool(r["converged"]) for r in mine)
        assert entry["converged"] == converged and entry["runs"] == len(mine)
        assert entry["rate_ci95"] == list(wilson_interval(converged, len(mine)))
        finals = np.array([r["final_position_m"] for r in mine], dtype=float)
        assert entry["final_position_m"]["median"] == pytest.approx(np.median(finals), rel=1e-12)
        assert entry["final_position_m"]["p95"] == pytest.approx(np.percentile(finals, 95), rel=1e-12)


def test_summary_tables_fit_80_columns_with_every_number_whole(uninterrupted):
    """At 80 columns the summary's eleven columns are dealt out to parts that repeat the law
    (and the parameter's value): no "…", no line past 80, each cell whole (issue 46)."""
    from rich.console import Console

    from hbvs_cli.report.sweep_summary import _stat_cells, print_summary

    folder, summary = uninterrupted
    for terminal in (True, False):
        buffer = io.StringIO()
        console = Console(file=buffer, width=80, force_terminal=terminal, color_system=None, highlight=False)
        print_summary(summary, buffer, console=console)
        text = buffer.getvalue()
        assert "…" not in text and max(len(line.rstrip()) for line in text.splitlines()) <= 80
        lines = text.splitlines()
        words = set(text.split())
        entries = [*summary["by_law"], *(row for rows in summary["by_parameter"].values() for row in rows)]
        for entry in entries:
            cells = _stat_cells(entry)
            assert all(word in words for cell in cells for word in cell.split()), cells
            # A row's cells are on the lines of its law: the interval and the medians whole.
            assert any(entry["law"] in line and cells[3] in line for line in lines)
        assert len(entries) == 4 + 8


def test_figures_label_units_rates_and_law_colours_without_overlaps(uninterrupted):
    """The sweep's figures: offset_y in m, the rate a fraction (no "%"), each law's line in
    its report colour, and the heading CDF's log tick labels apart (issue 46)."""
    import matplotlib.pyplot as plt
    from matplotlib.colors import to_hex

    from hbvs_cli.report.figure_style import LAW_COLORS
    from hbvs_cli.report.sweep_plots import FILES, sweep_figures
    from hbvs_cli.sweep.spec import PARAMETERS

    folder, _ = uninterrupted
    figures = sweep_figures(folder, {name: parameter.unit for name, parameter in PARAMETERS.items()})
    try:
        assert set(figures) == set(FILES)
        curve = figures["convergence_map.png"][0].axes[0]
        assert curve.get_xlabel() == "offset_y (m)" and "%" not in curve.get_ylabel() and "fraction" in curve.get_ylabel()
        assert figures["final_error_vs_parameters.png"][0].axes[0].get_xlabel() == "offset_y (m)"
        for name, (figure, _) in figures.items():
            figure.canvas.draw()
            renderer = figure.canvas.get_renderer()
            for ax in figure.axes:
                for line in ax.get_lines():
                    if line.get_label() in LAW_COLORS:
                        assert to_hex(line.get_color()) == LAW_COLORS[line.get_label()].lower(), (name, line.get_label())
                for axis in (ax.xaxis, ax.yaxis):
                    low, high = sorted(axis.get_view_interval())
                    # Major and minor labels: matplotlib's minor ones on a short log axis overlapped.
                    ticks = [*zip(axis.get_majorticklocs(), axis.get_majorticklabels()),
                             *zip(axis.get_minorticklocs(), axis.get_minorticklabels())]
                    boxes = [label.get_window_extent(renderer) for loc, label in ticks if label.get_text() and low <= loc <= high]
                    for i, a in enumerate(boxes):
                        assert all(a.x1 <= b.x0 + 0.5 or b.x1 <= a.x0 + 0.5 or a.y1 <= b.y0 + 0.5 or b.y1 <= a.y0 + 0.5
                                   for b in boxes[i + 1:]), (name, [t.get_text() for t in axis.get_majorticklabels()])
        cdf = figures["final_error_cdf.png"][0]
        heading = cdf.axes[1]
        assert heading.get_xscale() == "log" and len([t for t in heading.get_xticklabels() if t.get_text()]) >= 2
        assert {line.get_label() for line in heading.get_lines()} == {"lateral-gain", "paper", "non-adaptive", "kanayama"}
    finally:
        for figure, _ in figures.values():
            plt.close(figure)
