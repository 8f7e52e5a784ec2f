"""``hbvs report`` for a paper and for CI (issue 18): the figures, and the report as a gate.

One 8 s taught s-curve and its fit; repeats with projected points (cheap): the default
law, the paper's law, a 7 s occlusion with 10 % dropped frames (not stopped, to measure the
loss), the same with the default 3 s lost timeout (stopped), and an open-loop replay.
"""

from __future__ import annotations

import io
import json
import shutil
import math
import re
from contextlib import contextmanager

import numpy as np
import pytest

from hbvs_cli.errors import TargetLostError
from hbvs_cli.io.run_file import read_run
from hbvs_cli.stages.console import Console, ProgressTask
from hbvs_cli.report.figure_style import PALETTE

from conftest import call_hbvs

#: The occlusion (s) and the drop rate of the fault runs.
OCCLUSION = (0.5, 7.5)
DROP_RATE = 0.1
RATE_HZ = 30.0


class RecordingConsole(Console):
    """A quiet console that remembers every progress bar's total."""

    def __init__(self) -> None:
        super().__init__(quiet=True)
        self.totals: list[float | None] = []

    @contextmanager
    def progress(self, description, total):
        self.totals.append(total)
        yield ProgressTask(None, None)


@pytest.fixture(scope="module")
def runs(tmp_path_factory, teach_8s) -> dict:
    from hbvs_cli.stages.fit import FitOptions, run_fit
    from hbvs_cli.stages.repeat import RepeatOptions, run_repeat

    tmp = tmp_path_factory.mktemp("gate")
    quiet = Console(quiet=True)
    paths = {name: tmp / f"{name}.mcap" for name in ("teach", "fit", "run", "paper", "faults", "stopped", "replay")}
    shutil.copyfile(teach_8s, paths["teach"])  # the session's 8 s teach (conftest)
    fit_console = RecordingConsole()
    run_fit(FitOptions(input=str(paths["teach"]), output=str(paths["fit"])), fit_console)
    fit = str(paths["fit"])
    occlude = [f"{OCCLUSION[0]}:{OCCLUSION[1]}"]
    summary_text = io.StringIO()
    summary = run_repeat(RepeatOptions(input=fit, output=str(paths["run"]), sim=True, perception="points"), Console(stream=summary_text))
    run_repeat(RepeatOptions(input=fit, output=str(paths["paper"]), sim=True, perception="points", law="paper"), quiet)
    run_repeat(RepeatOptions(input=fit, output=str(paths["faults"]), sim=True, perception="points", occlude=occlude,
                             drop_rate=DROP_RATE, lost_timeout=10.0), quiet)
    with pytest.raises(TargetLostError) as stopped:
        run_repeat(RepeatOptions(input=fit, output=str(paths["stopped"]), sim=True, perception="points", occlude=occlude,
                                 drop_rate=DROP_RATE), quiet)
    run_repeat(RepeatOptions(input=fit, output=str(paths["replay"]), replay=paths["teach"]), quiet)
    return {"paths": paths, "summary": summary, "summary_text": summary_text.getvalue(), "fit_totals": fit_console.totals,
            "stop_error": stopped.value}


def report_json(*args) -> tuple[dict, object]:
    result = call_hbvs("report", *map(str, args), "--json")
    return json.loads(result.stdout), result


# ----------------------------------------------------------------------------- dropped frames and losses
def test_dropped_frames_do_not_reset_the_lost_state(runs):
    path = runs["paths"]["faults"]
    run = read_run(path)
    t = run.state["t"]
    assert run.dropped is not None and run.dropped.sum() > 0
    inside = (t >= OCCLUSION[0] + 1.0 / RATE_HZ) & (t < OCCLUSION[1] - 1e-9)
    assert run.lost[inside].all()                                   # drops inside the occlusion stay lost
    assert (run.dropped & inside).sum() >= 10                       # and there were drops in there
    assert not run.lost[t >= OCCLUSION[1] + 1.0 / RATE_HZ].any()    # and it came back
    lost_events = [e for e in run.events if e[2].startswith("target lost")]
    back_events = [e for e in run.events if e[2].startswith("target back")]
    assert len(lost_events) == 1 and len(back_events) == 1          # not one per dropped frame
    assert back_events[0][0] == pytest.approx(OCCLUSION[1], abs=1.5 / RATE_HZ)
    drop_events = [e for e in run.events if e[2].startswith("camera frame dropped")]
    assert 0 < len(drop_events) <= run.dropped.sum()                # every stretch of drops is logged
    report, _ = report_json(path)
    target = report["target"]
    assert target["longest_loss_s"] == pytest.approx(OCCLUSION[1] - OCCLUSION[0], abs=1.01 / RATE_HZ)   # 7.0 s, not 1.2 s
    assert target["lost_frames"] == pytest.approx((OCCLUSION[1] - OCCLUSION[0]) * RATE_HZ, abs=1)
    assert target["dropped_frames"] == int(run.dropped.sum())
    assert target["dropped_fraction"] == pytest.approx(run.dropped.mean(), rel=1e-6)
    assert 0.05 < target["dropped_fraction"] < 0.15                 # --drop-rate 0.1


def test_a_long_occlusion_with_dropped_frames_still_stops_the_run(runs):
    error = runs["stop_error"]
    assert error.exit_code == 5
    run = read_run(runs["paths"]["stopped"])
    stop = [e for e in run.events if "run stopped" in e[2]]
    assert len(stop) == 1
    # Stopped 3 s (the default --lost-timeout) after the target went out of view.
    assert stop[0][0] == pytest.approx(OCCLUSION[0] + 3.0, abs=2.0 / RATE_HZ)
    report, _ = report_json(runs["paths"]["stopped"])
    assert report["target"]["longest_loss_s"] == pytest.approx(3.0, abs=2.0 / RATE_HZ)
    assert report["verdict"]["checks"]["finished"].startswith("fail: run stopped")


# ----------------------------------------------------------------------------- the gate
def test_require_converged_sets_the_exit_code(runs):
    run = runs["paths"]["run"]
    # The 8 s run is still settling at its end (0.26 cm, 0.43 deg; the fault run 0.68 cm,
    # 0.68 deg): tolerances the first meets and the second does not, so that only the gate
    # is tested here.
    loose = ["--tolerance", "position_m=0.05", "--tolerance", "heading_deg=0.5"]
    passed = call_hbvs("report", str(run), "--json", "--require-converged", *loose)
    assert passed.returncode == 0 and passed.stderr == b""
    assert json.loads(passed.stdout)["verdict"]["converged"] is True
    # The case: a tight tolerance turns the verdict to "no", and now the exit code too.
    tight = call_hbvs("report", str(run), "--json", "--require-converged", "--tolerance", "position_m=0.0001")
    assert tight.returncode == 1
    assert json.loads(tight.stdout)["verdict"]["converged"] is False              # the report is still printed
    lines = tight.stderr.decode().strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("hbvs: warning: not converged:") and "final position error" in lines[0]
    without = call_hbvs("report", str(run), "--json", "--tolerance", "position_m=0.0001")
    assert without.returncode == 0                                                 # only when asked
    several = call_hbvs("report", str(run), str(runs["paths"]["faults"]), "--require-converged", *loose)
    assert several.returncode == 1
    lines = several.stderr.decode().strip().splitlines()
    assert len(lines) == 1 and "faults.mcap" in lines[0]


def test_a_comparison_names_its_checks(runs):
    result = call_hbvs("report", str(runs["paths"]["run"]), str(runs["paths"]["replay"]))
    assert result.returncode == 0
    block = next(b for b in result.stdout.decode().split("\n\n") if b.startswith("verdict"))
    rows = {re.split(r"\s{2,}", line.strip())[0]: re.split(r"\s{2,}", line.strip())[1:] for line in block.splitlines()[1:]}
    assert not any(label.startswith("check ") for label in rows)
    assert rows["check"] == ["lateral-gain", "replay"]
    assert rows["closed loop"][0].startswith("pass:") and rows["closed loop"][1].startswith("fail: open-loop replay")
    assert rows["final position error"][0].startswith(("pass:", "fail:")) and rows["final position error"][1] == "n/a"
    assert rows["final e1"][0] == "n/a" and rows["final e1"][1].startswith(("pass:", "fail:"))
    assert rows["V fell (36)"][1].startswith("skip:")
    both, _ = report_json(runs["paths"]["run"], runs["paths"]["replay"])
    assert list(both["runs"][0]["verdict"]["checks"]) == ["closed_loop", "finished", "final_position", "final_heading", "lyapunov", "smoothness"]
    assert list(both["runs"][1]["verdict"]["checks"]) == ["closed_loop", "finished", "final_e1", "final_e2", "final_e3", "lyapunov", "smoothness"]


def _significant_digits(literal: str) -> int:
    """Digits of a decimal literal from the first non-zero one to the last non-zero one."""
    return len(re.split(r"[eE]", literal)[0].lstrip("-").replace(".", "").strip("0"))


def test_json_numbers_are_rounded(runs):
    result = call_hbvs("report", str(runs["paths"]["run"]), str(runs["paths"]["faults"]), "--json")
    text = result.stdout.decode()
    floats = re.findall(r"(?<![\w.])-?\d+\.\d+(?:[eE][-+]?\d+)?", text)
    assert len(floats) > 50
    assert max(_significant_digits(f) for f in floats) <= 7, [f for f in floats if _significant_digits(f) > 7][:5]
    report = json.loads(text)["runs"][0]
    assert report["run"]["rate_hz"] == 30.0                                         # not 30.0000003
    assert report["run"]["duration_s"] == pytest.approx((report["run"]["steps"] - 1) / 30.0, rel=1e-6)


def test_repeat_summary_final_is_the_report_final(runs):
    summary = runs["summary"]
    report, _ = report_json(runs["paths"]["run"])
    for name, (section, key) in {"position_m": ("pose_error", "position_m"), "heading_deg": ("pose_error", "heading_deg"),
                                 "e1": ("errors", "e1"), "e2": ("errors", "e2"), "e3_deg": ("errors", "e3")}.items():
        assert summary.final_errors[name] == pytest.approx(report[section][key]["final"], rel=2e-6), name
    text = runs["summary_text"]
    assert "final (mean over the last 5 %, as in hbvs report)" in text
    assert f"position {100 * report['pose_error']['position_m']['final']:.3g} cm" in text


def test_fit_progress_bar_knows_the_frame_count(runs):
    from hbvs_cli.stages.fit import recorded_frame_count

    assert runs["fit_totals"] == [240]                               # 8 s at 30 fps, from the MCAP summary
    assert recorded_frame_count(str(runs["paths"]["teach"])) == 240
    assert recorded_frame_count("-") is None
    truncated = runs["paths"]["teach"].with_name("cut.mcap")
    truncated.write_bytes(runs["paths"]["teach"].read_bytes()[:200_000])
    assert recorded_frame_count(str(truncated)) is None              # no summary: counted as they come


def test_fit_file_report_and_misuse(runs, tmp_path):
    fit = runs["paths"]["fit"]
    summary, result = report_json(fit)
    assert result.returncode == 0
    assert summary["frames_raw"] == summary["frames_smooth"] == 240
    # The spline follows the decomposed samples to a fraction of the pixel noise.
    assert summary["raw_minus_smooth"]["theta_d_deg"]["rms"] < 0.05
    assert summary["raw_minus_smooth"]["x_hd1"]["rms"] < 2e-4
    # Differentiating raw samples directly is much noisier than the spline's derivative.
    assert summary["x_hd1_dot"]["raw_difference_rms"] > 0.05 * summary["x_hd1_dot"]["min_abs"]
    run = read_run(runs["paths"]["run"])
    assert summary["x_hd1_dot"]["min_abs"] == pytest.approx(run.info["condition35"]["min_abs_xhd1_dot"], rel=1e-3)
    for bad in (["--require-converged"], ["--fail-above", "frames_raw=1"], [str(runs["paths"]["run"])]):
        misuse = call_hbvs("report", str(fit), *bad)
        assert misuse.returncode == 2 and misuse.stdout == b"", bad
        assert len(misuse.stderr.decode().strip().splitlines()) == 1


# ----------------------------------------------------------------------------- figures
def _figure(runs, names, labels=None, **style):
    from hbvs_cli.report.figure_style import FigureStyle
    from hbvs_cli.report.plots import plot_runs
    from hbvs_cli.report.build import build_report

    loaded = [read_run(runs["paths"][name]) for name in names]
    reports = [build_report(run, None, label) for run, label in zip(loaded, labels or [None] * len(loaded))]
    return plot_runs(loaded, reports, FigureStyle(**style)), loaded


def _axes(figure) -> dict:
    return {ax.get_label(): ax for ax in figure.axes if ax.get_label()}


def _horizontal_levels(ax) -> set[float]:
    """The y of every horizontal guide line (axhline) of an axes."""
    levels = set()
    for line in ax.get_lines():
        y = np.asarray(line.get_ydata(), dtype=float)
        if y.size == 2 and y[0] == y[1] and list(line.get_xdata()) == [0, 1]:
            levels.add(round(float(y[0]), 9))
    return levels


def test_run_figure_panels_titles_units_and_legend(runs):
    from hbvs_cli.report.plots import PANEL_NAMES

    figure, _ = _figure(runs, ("run", "paper", "faults"), labels=["lateral gain", "paper law", "faults"])
    axes = _axes(figure)
    assert set(PANEL_NAMES) - {"top"} <= set(axes) and {"top_scene", "top_paths"} <= set(axes)
    # Titles in words, with the equation number; axis labels with units.
    for name, words in {"e1": ("Longitudinal", "(19)"), "ebar2": ("Lateral", "(27)"), "e2": ("Lateral", "(19)"),
                        "e3": ("Rotation", "(19)"), "v": ("Linear velocity", "(29)"), "w": ("Angular velocity", "(30)"),
                        "dhat": ("Depth estimate", "(31)"), "V": ("Lyapunov function", "(36)"),
                        "position": ("Position error",), "heading": ("Heading error",)}.items():
        title = axes[name].get_title(loc="left")
        assert all(word in title for word in words), (name, title)
        assert axes[name].get_xlabel() == "time t (s)"
        assert re.search(r"\((cm|deg|m|m/s|rad/s|units of \$d\^\*\$|-)\)$", axes[name].get_ylabel()), axes[name].get_ylabel()
        assert axes[name].get_lines(), name
    assert axes["V"].get_ylabel() == "V / V(0) (-)" and axes["V"].get_yscale() == "log"
    assert axes["position"].get_yscale() == "log" and axes["heading"].get_yscale() == "log"
    legend = [text.get_text() for text in figure.legends[0].get_texts()]
    assert legend[:3] == ["lateral gain (not converged)", "paper law (not converged)", "faults (not converged)"]
    assert not any(".mcap" in text for text in legend)
    assert {"taught / true", "tolerance", "actuator limit", "target lost"} <= set(legend)
    # Paper size: 7 in wide (two columns), raster at 200 dpi, fonts of 7-9 pt.
    assert figure.get_size_inches()[0] == 7.0 and figure.dpi == 200
    assert 7.0 <= axes["e1"].title.get_fontsize() <= 9.0 and 7.0 <= axes["e1"].xaxis.label.get_fontsize() <= 9.0


def test_tolerance_lines_and_actuator_limits(runs):
    figure, _ = _figure(runs, ("run",))
    axes = _axes(figure)
    assert 1.0 in _horizontal_levels(axes["position"])                  # 1 cm
    assert 0.2 in _horizontal_levels(axes["heading"])                   # 0.2 deg
    assert {-0.2, 0.2} <= _horizontal_levels(axes["e3"])
    assert {-0.0025, 0.0025} <= _horizontal_levels(axes["e1"])
    assert {-0.5, 0.5} <= _horizontal_levels(axes["v"])                 # repeat's default limits
    assert {-0.6, 0.6} <= _horizontal_levels(axes["w"])
    assert 4.0 in {round(level, 3) for level in _horizontal_levels(axes["dhat"])}   # the true d*


def test_lost_stretches_are_shaded_and_break_the_lines_but_drops_do_not(runs):
    figure, (run,) = _figure(runs, ("faults",))
    axes = _axes(figure)
    for name in ("e1", "ebar2", "e3", "V"):
        ax = axes[name]
        spans = [patch.get_extents() for patch in ax.patches]
        assert len(ax.patches) == 1, name                                  # one shaded loss
        line = ax.get_lines()[0]
        t, y = np.asarray(line.get_xdata()), np.asarray(line.get_ydata())
        during = (t > OCCLUSION[0] + 0.05) & (t < OCCLUSION[1] - 0.05)
        assert not np.isfinite(y[during]).any(), name                   # nothing drawn across the loss
        gaps = np.flatnonzero(np.diff(np.isnan(y).astype(int)) == 1)
        assert gaps.size == 1, name                                      # broken once: drops are joined
        assert spans
    # Dropped frames outside the loss: the e1 line is continuous there (no NaN between samples).
    line = axes["e1"].get_lines()[0]
    t, y = np.asarray(line.get_xdata()), np.asarray(line.get_ydata())
    def outside(times):
        return (times < OCCLUSION[0] - 0.05) | (times > OCCLUSION[1] + 0.1)

    assert outside(t).sum() > 10 and np.isfinite(y[outside(t)]).all()
    assert run.dropped[outside(run.state["t"])].sum() >= 2               # there were drops to join


def test_top_view_shows_wall_target_heading_and_the_taught_path_on_top(runs):
    figure, (run,) = _figure(runs, ("run",))
    axes = _axes(figure)
    scene = axes["top_scene"]
    wall_x = run.info["top_view"]["wall_x"]
    assert wall_x == pytest.approx(4.0, abs=0.2)
    verticals = [line for line in scene.get_lines() if np.allclose(line.get_xdata(), wall_x)]
    assert len(verticals) >= 3                                           # wall, poster, target points
    assert any(len(line.get_xdata()) == 3 for line in verticals)       # the three dots
    from matplotlib.quiver import Quiver

    arrows = [c for c in scene.collections if isinstance(c, Quiver)]
    assert len(arrows) == 1 and arrows[0].N == math.ceil(run.state["t"][-1] / 2.0)   # one every 2 s
    for ax in (scene, axes["top_paths"]):
        lines = ax.get_lines()
        taught = [line for line in lines if line.get_color() == "black" and line.get_linestyle() != "-"]
        repeated = [line for line in lines if line.get_color() in PALETTE and line.get_linestyle() == "-"]
        assert taught and repeated
        assert min(line.get_zorder() for line in taught) > max(line.get_zorder() for line in repeated)


def test_a_dense_noisy_run_is_thinned_for_display():
    from hbvs_cli.report.plots import MAX_POINTS_PER_RUN, display_series

    rng = np.random.default_rng(18)
    t = np.arange(200 * 20) / 200.0                                     # 20 s at 200 Hz
    x = np.exp(-t / 3.0) + rng.normal(0.0, 0.05, t.size)
    lost = (t >= 8.0) & (t < 10.0)
    x[lost] = np.nan
    x[rng.random(t.size) < 0.1] = np.nan                                 # dropped frames: NaN, not lost
    shown_t, shown_x = display_series(t, x, lost)
    assert shown_t.size <= MAX_POINTS_PER_RUN < t.size
    gap = (shown_t > 8.05) & (shown_t < 9.95)
    assert gap.any() and not np.isfinite(shown_x[gap]).any()             # the loss stays a break
    assert np.isfinite(shown_x[~gap & ((shown_t < 7.95) | (shown_t > 10.05))]).all()   # drops are joined
    residual = shown_x - np.exp(-shown_t / 3.0)
    assert np.nanstd(residual) < 0.5 * 0.05                              # bin means: the noise is tamed
    sparse_t, sparse_x = display_series(t[::10], x[::10], lost[::10])    # a 20 Hz run is drawn as it is
    assert sparse_t.size == np.count_nonzero(np.isfinite(x[::10]) | lost[::10])
    # Overlaid, the dense run is drawn thinner and under the sparse one, whatever the order given.
    from types import SimpleNamespace

    from hbvs_cli.report.plots import _line_styles

    dense, sparse = (SimpleNamespace(steps=ts.size, state={"t": ts}) for ts in (t, t[::10]))
    styles = _line_styles([dense, sparse], ["C0", "C1"])
    assert styles["C0"]["zorder"] < styles["C1"]["zorder"] and styles["C0"]["lw"] < styles["C1"]["lw"]
    styles = _line_styles([sparse, dense], ["C0", "C1"])
    assert styles["C1"]["zorder"] < styles["C0"]["zorder"]


def test_figure_options_and_formats(runs, tmp_path):
    from hbvs_cli.report.figure_style import parse_size

    run = str(runs["paths"]["run"])
    png = tmp_path / "one-column.png"
    one_column = ("--size", "3.5x8", "--panels", "position,heading,v,w,top", "--dpi", "100")
    result = call_hbvs("report", run, "--plot", str(png), *one_column, "--json")
    assert result.returncode == 0, result.stderr.decode()
    data = png.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and tuple(int.from_bytes(data[o:o + 4], "big") for o in (16, 20)) == (350, 800)
    # Every panel in 3.5x8 would overlap its labels: refused, with the least height that fits.
    short = call_hbvs("report", run, "--plot", str(tmp_path / "short.png"), "--size", "3.5x8")
    assert short.returncode == 2 and b"give at least 3.5x14" in short.stderr and not (tmp_path / "short.png").exists()
    assert not short.stdout
    # Stacked in one column, the time panels share one time axis, labelled under the last.
    figure, _ = _figure(runs, ("run",), size_in=(3.5, 8.0), panels=("position", "heading", "v", "w", "top"))
    axes = _axes(figure)
    assert axes["w"].get_xlabel() == "time t (s)" and axes["position"].get_xlabel() == ""
    assert not any(label.get_visible() for label in axes["position"].get_xticklabels())
    # The format follows the suffix. Two panels (one with the Lyapunov title) show it: the
    # two-run figure with every panel is drawn by tests/test_report_stage.py's PNG test,
    # and here took 2.4 s of CPU per vector format against 0.7 s for these two.
    for suffix, magic in ((".pdf", b"%PDF"), (".svg", b"<?xml")):
        path = tmp_path / f"figure{suffix}"
        result = call_hbvs("report", run, str(runs["paths"]["paper"]), "--plot", str(path), "--label", "a", "--label", "b",
                           "--panels", "position,V")
        assert result.returncode == 0, result.stderr.decode()
        assert path.read_bytes()[:len(magic)] == magic
    assert b"Lyapunov function" in (tmp_path / "figure.svg").read_bytes()     # text stays text
    figure, _ = _figure(runs, ("run",), panels=("position", "heading", "top"))
    assert set(_axes(figure)) == {"position", "heading", "top", "top_scene", "top_paths"}
    for bad, message in ((["--plot", str(tmp_path / "x.png"), "--panels", "position,bogus"], "unknown panel"),
                         (["--plot", str(tmp_path / "x.png"), "--size", "huge"], "WIDTHxHEIGHT"),
                         (["--dpi", "300"], "give --plot"),
                         (["--label", "only-one", str(runs["paths"]["paper"])], "one per run")):
        result = call_hbvs("report", run, *bad)
        assert result.returncode == 2 and result.stdout == b"", bad
        lines = result.stderr.decode().strip().splitlines()
        assert len(lines) == 1 and message in lines[0], (bad, lines)
    assert parse_size("7x4.5") == (7.0, 4.5)
    help_text = call_hbvs("report", "--help").stdout.decode()
    assert ".pdf" in help_text and ".svg" in help_text and "--require-converged" in help_text


def test_fit_figure_panels(runs, tmp_path):
    from hbvs_cli.report.fit_plot import FIT_PANELS, plot_fit, read_fit_signals

    signals = read_fit_signals(runs["paths"]["fit"])
    figure = plot_fit(signals)
    axes = _axes(figure)
    assert tuple(name for name in axes) == FIT_PANELS
    for name in ("theta_d", "x_hd1", "x_hd2"):
        raw_points, smooth_line = axes[name].get_lines()[:2]
        assert len(raw_points.get_xdata()) == signals.raw["t"].size == 240
        assert axes[name].get_legend() is None          # one legend for the figure (test_figures_of_a_person)
    legend = [t.get_text() for t in figure.legends[0].get_texts()]
    assert legend[0].startswith("raw") and any("(25)" in text for text in legend)
    assert "Remark 1" in axes["theta_d"].get_title(loc="left") and "(35)" in axes["x_hd1_dot"].get_title(loc="left")
    assert axes["theta_d"].get_ylabel().endswith("(deg)") and axes["x_hd1_dot"].get_ylabel().endswith("(1/s)")
    path = tmp_path / "fit.png"
    result = call_hbvs("report", str(runs["paths"]["fit"]), "--plot", str(path), "--panels", "theta_d,x_hd1_dot")
    assert result.returncode == 0, result.stderr.decode()
    assert path.stat().st_size > 10_000


# ------------------------------------------------------------- what a person sees (issue 46)
def _overlap_px2(a, b) -> float:
    """Area (px^2) two window extents share."""
    width = min(a.x1, b.x1) - max(a.x0, b.x0)
    height = min(a.y1, b.y1) - max(a.y0, b.y0)
    return max(width, 0.0) * max(height, 0.0)


def _tick_label_boxes(figure) -> list[list]:
    """Per axis of each axes: the window extents of the tick labels drawn (in view, not empty)."""
    figure.canvas.draw()
    renderer = figure.canvas.get_renderer()
    groups = []
    for ax in figure.axes:
        for axis, (low, high) in ((ax.xaxis, sorted(ax.get_xlim())), (ax.yaxis, sorted(ax.get_ylim()))):
            labels = zip(axis.get_majorticklocs(), axis.get_majorticklabels())
            groups.append([label.get_window_extent(renderer) for loc, label in labels
                           if label.get_visible() and label.get_text() and low <= loc <= high])
    return groups


def assert_nothing_covered(figure) -> int:
    """No legend covers an axes, no two titles or tick labels of one axis overlap; returns
    how many boxes were compared."""
    groups = _tick_label_boxes(figure)
    renderer = figure.canvas.get_renderer()
    compared = 0
    for boxes in groups:
        for i, a in enumerate(boxes):
            for b in boxes[i + 1:]:
                assert _overlap_px2(a, b) < 1.0, (a, b)
                compared += 1
    panels = [ax.get_window_extent(renderer) for ax in figure.axes if ax.get_visible() and ax.axison]
    titles = [ax.title.get_window_extent(renderer) for ax in figure.axes if ax.get_title(loc="left") or ax.get_title()]
    legends = [legend.get_window_extent(renderer) for legend in figure.legends]
    legends += [ax.get_legend().get_window_extent(renderer) for ax in figure.axes if ax.get_legend() is not None]
    for legend in legends:
        for box in panels + titles:
            assert _overlap_px2(legend, box) < 1.0, (legend, box)
            compared += 1
    for i, a in enumerate(titles):
        for b in titles[i + 1:]:
            assert _overlap_px2(a, b) < 1.0, (a, b)
            compared += 1
    return compared


def test_a_replay_beside_closed_loop_runs_keeps_the_titles_and_the_legend_says_it(runs):
    """Each panel keeps its own title beside a replay (no "(no data: replay.mcap)"); the
    replay's legend entry says it has no ground truth."""
    alone, _ = _figure(runs, ("run",))
    both, _ = _figure(runs, ("run", "replay"))

    def titles(figure):
        return {name: ax.get_title(loc="left") for name, ax in _axes(figure).items()}

    assert titles(both) == titles(alone) and not any("no data" in title for title in titles(both).values())
    legend = [text.get_text() for text in both.legends[0].get_texts()]
    assert legend[0] == "lateral-gain (not converged)" and legend[1] == "replay (open-loop replay; no ground truth)"
    assert assert_nothing_covered(both) > 100


def test_each_line_style_has_one_meaning_in_the_legend(runs):
    """Dotted is a tolerance, dash-dot the taught command: the v and w panels draw no dotted
    line, the error panels no dash-dot one, and the legend names each style once."""
    from matplotlib.lines import Line2D

    figure, _ = _figure(runs, ("run", "paper"))
    axes = _axes(figure)
    legend = figure.legends[0]
    styles = {}
    for text, handle in zip(legend.get_texts(), legend.legend_handles):
        if isinstance(handle, Line2D) and handle.get_linestyle() != "-":
            styles.setdefault(handle.get_linestyle(), []).append(text.get_text())
    assert styles[":"] == ["tolerance"] and styles["-."] == ["taught command (25)"]
    for name in ("v", "w"):
        drawn = [line.get_linestyle() for line in axes[name].get_lines()]
        assert ":" not in drawn and drawn.count("-.") == 2                  # one taught command per run
    for name in ("e1", "ebar2", "e2", "e3", "position", "heading"):
        drawn = [line.get_linestyle() for line in axes[name].get_lines()]
        assert ":" in drawn and "-." not in drawn


def test_y_labels_use_the_symbols_of_the_titles(runs):
    figure, _ = _figure(runs, ("run",))
    axes = _axes(figure)
    for name, symbol in {"e1": "$e_1$", "ebar2": r"$\bar{e}_2$", "e2": "$e_2$", "e3": "$e_3$", "v": "$v_c$",
                         "w": r"$\omega_c$"}.items():
        assert symbol in axes[name].get_title(loc="left") and axes[name].get_ylabel().startswith(symbol + " (")
    for ax in figure.axes:
        # Outside the mathtext ($...$) no ASCII spelling of a symbol is left.
        words = re.sub(r"\$[^$]*\$", "", ax.get_ylabel())
        assert not re.search(r"\b(ebar2|w_c|v_c|e[123])\b", words), ax.get_ylabel()


def test_each_law_has_its_colour_in_every_figure(runs):
    """The paper's law is drawn in its colour whether it comes first or second."""
    from hbvs_cli.report.figure_style import LAW_COLORS, law_colors
    from matplotlib.colors import to_hex

    for names, laws in ((("run", "paper"), ("lateral-gain", "paper")), (("paper", "run"), ("paper", "lateral-gain"))):
        figure, _ = _figure(runs, names)
        drawn = [to_hex(line.get_color()) for line in _axes(figure)["e1"].get_lines()[:2]]
        assert drawn == [LAW_COLORS[law].lower() for law in laws]
    # Two runs of one law: the second takes a colour no law has.
    first, second = law_colors(["lateral-gain", "lateral-gain"])
    assert first == LAW_COLORS["lateral-gain"] and second not in LAW_COLORS.values()


def test_the_fit_figure_legend_covers_no_panel(runs):
    from hbvs_cli.report.fit_plot import plot_fit, read_fit_signals

    figure = plot_fit(read_fit_signals(runs["paths"]["fit"]))
    assert len(figure.legends) == 1 and all(ax.get_legend() is None for ax in figure.axes)
    assert assert_nothing_covered(figure) > 50
    for ax in figure.axes:
        assert re.search(r"\(.+\)$", ax.get_ylabel()), ax.get_ylabel()


def test_the_loop_keeps_the_lost_state_and_the_rejected_count_through_drops():
    """Scripted frames through the closed loop: a drop inside a loss is lost and stopped; a
    drop while tracking (or after one rejected frame) holds the last command."""
    from hbvs_cli.core.controller import AdaptiveTrackingController, ControllerGains
    from hbvs_cli.core.estimation import Observation, PlanarPoseEstimator
    from hbvs_cli.core.path import sampled_profile
    from hbvs_cli.sim.world import default_world
    from oracles import TaughtPathTrajectory, observe_normalized, run_closed_loop

    world = default_world("dots")
    profile = sampled_profile(lambda t: (np.full_like(t, 0.1), 0.045 * np.cos(2 * np.pi * t / 20.0)), 2.0, 30.0)
    start = np.array([0.0, -0.05, 0.0])
    m_ref, normal, d_star = world.reference_geometry(start)
    estimator = PlanarPoseEstimator(world.camera, m_ref, normal)
    script = ["ok", "ok", "occluded", "dropped", "dropped", "occluded", "ok", "dropped", "ok", "outlier", "dropped", "ok"]

    def sense(pose, t):
        status = script[int(round(t * 30.0))]
        return observe_normalized(estimator, world.normalized_points(pose)) if status == "ok" else Observation(None, status=status)

    records = list(run_closed_loop(sense, TaughtPathTrajectory(profile, start, start, d_star),
                                   AdaptiveTrackingController(ControllerGains(), d_star), start, 1.0 / 30.0, len(script) / 30.0))
    assert [r.lost for r in records] == [False, False, True, True, True, True, False, False, False, True, True, False]
    assert [r.dropped for r in records] == [s == "dropped" for s in script]
    for k in (2, 3, 4, 5):
        assert (records[k].v_c, records[k].w_c) == (0.0, 0.0)                        # stopped while lost
    assert (records[7].v_c, records[7].w_c) == (records[6].v_c, records[6].w_c) != (0.0, 0.0)   # held
    assert (records[10].v_c, records[10].w_c) == (records[8].v_c, records[8].w_c) != (0.0, 0.0)  # outlier, drop: held
