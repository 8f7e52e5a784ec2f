"""``hbvs report`` on real runs of ``hbvs repeat``: JSON, table, thresholds, plot, TUM (issue: report)."""

from __future__ import annotations

import io
import json
import shutil
import math
import re
import struct
from pathlib import Path

import numpy as np
import pytest

from hbvs_cli.core.metrics import STATISTICS
from hbvs_cli.errors import TargetLostError, UsageError
from hbvs_cli.io.run_file import read_run
from hbvs_cli.stages.console import Console
from hbvs_cli.report.build import build_report

from conftest import call_hbvs
from oracles import REPORT_KEYS

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def runs(tmp_path_factory, teach_8s) -> dict[str, Path]:
    """An 8 s taught s-curve, its fit, and four repeats: both laws, a replay, a stopped run."""
    from hbvs_cli.stages.fit import FitOptions, run_fit
    from hbvs_cli.stages.repeat import RepeatOptions, run_repeat

    tmp = tmp_path_factory.mktemp("report")
    quiet = Console(quiet=True)
    paths = {name: tmp / f"{name}.mcap" for name in ("teach", "fit", "run", "paper", "replay", "stopped")}
    shutil.copyfile(teach_8s, paths["teach"])  # the session's 8 s teach (conftest)
    run_fit(FitOptions(input=str(paths["teach"]), output=str(paths["fit"])), quiet)
    fit = str(paths["fit"])
    run_repeat(RepeatOptions(input=fit, output=str(paths["run"]), sim=True, perception="images"), quiet)
    run_repeat(RepeatOptions(input=fit, output=str(paths["paper"]), sim=True, perception="images", law="paper"), quiet)
    run_repeat(RepeatOptions(input=fit, output=str(paths["replay"]), replay=paths["teach"]), quiet)
    with pytest.raises(TargetLostError):
        run_repeat(RepeatOptions(input=fit, output=str(paths["stopped"]), sim=True, perception="images",
                                 occlude=["1:4"], lost_timeout=0.5), quiet)
    return paths


def report_json(*args, input: bytes | None = None) -> dict:
    """``hbvs report ARGS --json``, parsed (in this process, reading ``input`` as its stdin)."""
    words = ["report", *map(str, args), "--json"]
    result = call_hbvs(*words, input=input)
    assert result.returncode == 0, result.stderr.decode()
    return json.loads(result.stdout)


def parse_tables(text: str) -> dict[str, list[list[str]]]:
    """Plain-text tables: title line, header line, rows; cells split on 2+ spaces."""
    tables: dict[str, list[list[str]]] = {}
    for block in text.strip().split("\n\n"):
        title, *lines = block.splitlines()
        tables[title] = [re.split(r"\s{2,}", line.strip()) for line in lines]
    return tables


def as_number(cell: str) -> float | None:
    return None if cell == "n/a" else float(cell)


def close_to_shown(shown: float | None, value: float | None) -> bool:
    """A cell (4 significant digits) agrees with the JSON value."""
    if shown is None or value is None:
        return shown is None and value is None
    return math.isclose(shown, value, rel_tol=6e-4, abs_tol=1e-300)


# ----------------------------------------------------------------------------- JSON
def test_json_has_the_documented_structure(runs):
    report = report_json(runs["run"])
    assert tuple(report) == REPORT_KEYS
    assert set(report["run"]) == {"name", "label", "duration_s", "steps", "rate_hz", "law", "gains", "source", "truncated"}
    assert report["run"]["label"] == "lateral-gain"
    assert report["run"]["law"] == "lateral-gain" and report["run"]["source"] == {"mode": "sim", "fit_file": str(runs["fit"])}
    assert report["run"]["rate_hz"] == 30.0                  # rounded: not 30.0000003
    assert report["run"]["duration_s"] == pytest.approx((report["run"]["steps"] - 1) / 30.0, rel=1e-6)
    assert set(report["run"]["gains"]) == {"k_v", "k_w", "gamma", "k_2"}
    for section, names in (("errors", ("e1", "e2", "ebar2", "e3")), ("pose_error", ("position_m", "heading_deg"))):
        assert tuple(report[section]) == names
        for name in names:
            assert tuple(report[section][name]) == STATISTICS
    assert set(report["lyapunov"]) == {"initial", "final", "ratio", "increase_fraction"}
    assert set(report["depth"]) == {"dhat0", "dhat_final", "d_true", "relative_error", "learning_reference",
                                    "learning_time_s", "end_rate_per_s", "still_moving", "warning"}
    assert set(report["commands"]) == {"v_peak_mps", "v_rms_mps", "w_peak_radps", "w_rms_radps", "saturated_fraction",
                                       "v_tv_per_s", "w_tv_per_s", "dv_dt_rms_mps2", "dw_dt_rms_radps2", "at_limit_fraction",
                                       "limits", "taught"}
    assert set(report["target"]) == {"lost_frames", "lost_fraction", "longest_loss_s", "dropped_frames", "dropped_fraction"}
    assert set(report["condition35"]) == {"min_abs_xhd1_dot", "fit_min_abs_xhd1_dot"}
    assert set(report["verdict"]) == {"converged", "checks", "reasons"}
    assert list(report["verdict"]["checks"]) == ["closed_loop", "finished", "final_position", "final_heading", "lyapunov", "smoothness"]
    assert list(report["verdict"]["checks"].values()) == report["verdict"]["reasons"]


def test_json_values_agree_with_the_run(runs):
    run = read_run(runs["run"])
    report = report_json(runs["run"])
    # The simulated start offset (repeat's default) is the initial pose error.
    from hbvs_cli.stages.options import parse_offset
    from hbvs_cli.settings.commands import DEFAULT_OFFSET

    dx, dy, dtheta = parse_offset(DEFAULT_OFFSET)
    # (to the report's 7 significant digits)
    assert report["pose_error"]["position_m"]["initial"] == pytest.approx(math.hypot(dx, dy), rel=1e-6)
    assert report["pose_error"]["heading_deg"]["initial"] == pytest.approx(math.degrees(dtheta), rel=1e-6)
    assert report["depth"]["d_true"] == pytest.approx(run.info["d_true"], rel=1e-6)
    assert report["depth"]["dhat0"] == pytest.approx(run.info["dhat0"])
    # The report's numbers carry 7 significant digits: compare at that precision.
    # Both dhat_final and relative_error are rounded to 7 significant digits.
    assert report["depth"]["relative_error"] == pytest.approx(abs(report["depth"]["dhat_final"] - run.info["d_true"]) / run.info["d_true"], abs=1e-6)
    e3 = np.degrees(run.state["e3"])
    assert report["errors"]["e3"]["max"] == pytest.approx(np.nanmax(e3))
    assert report["errors"]["e1"]["rmse"] == pytest.approx(np.sqrt(np.nanmean(run.state["e1"] ** 2)))
    assert report["commands"]["v_peak_mps"] == pytest.approx(np.max(np.abs(run.state["v_c"])))
    assert report["target"]["lost_frames"] == int(run.lost.sum())
    assert report["condition35"]["fit_min_abs_xhd1_dot"] == pytest.approx(run.info["condition35"]["min_abs_xhd1_dot"], rel=1e-6)
    assert report["lyapunov"]["initial"] > report["lyapunov"]["final"] > 0
    assert report["verdict"]["checks"]["finished"].startswith("pass: run finished")


def test_replay_has_no_pose_error_no_V_and_never_converges(runs):
    report = report_json(runs["replay"])
    assert "pose_error" not in report
    assert report["lyapunov"] == {"initial": None, "final": None, "ratio": None, "increase_fraction": None}
    assert report["run"]["source"]["mode"] == "replay"
    assert report["verdict"]["converged"] is False
    assert report["verdict"]["checks"]["closed_loop"].startswith("fail: open-loop replay")


def test_a_run_stopped_for_a_lost_target_did_not_converge(runs):
    report = report_json(runs["stopped"])
    assert report["verdict"]["converged"] is False
    assert any(r.startswith("fail: run stopped at t =") for r in report["verdict"]["reasons"])
    assert report["target"]["longest_loss_s"] > 0.5


# ----------------------------------------------------------------------------- table
def test_plain_table_matches_the_json(runs, monkeypatch):
    monkeypatch.setenv("COLUMNS", "1000")   # the verdict's sentences on one line each
    result = call_hbvs("report", str(runs["run"]))
    assert result.returncode == 0 and result.stderr == b""
    text = result.stdout.decode()
    assert "\x1b[" not in text and not set(text) & set("─━│┃┏┓└┘")
    report = report_json(runs["run"])
    tables = parse_tables(text)
    errors = next(rows for title, rows in tables.items() if title.startswith("image errors"))
    pose = next(rows for title, rows in tables.items() if title.startswith("pose error"))
    assert errors[0] == ["error", *STATISTICS[:-2], "final |.|", "settling (s)"]
    checked = 0
    for rows, section, names in ((errors, "errors", ("e1", "e2", "ebar2", "e3")), (pose, "pose_error", ("position_m", "heading_deg"))):
        labels = [row[0] for row in rows[1:]]
        assert labels == {"errors": ["e1 (d*)", "e2 (d*)", "ebar2 (d*)", "e3 (deg)"], "pose_error": ["position (m)", "heading (deg)"]}[section]
        for row, name in zip(rows[1:], names):
            for cell, statistic in zip(row[1:], STATISTICS):
                assert close_to_shown(as_number(cell), report[section][name][statistic]), (name, statistic, cell)
                checked += 1
    assert checked == 6 * 9
    metrics = {row[0]: row[1] for row in next(rows for title, rows in tables.items() if title.startswith("Lyapunov"))[1:]}
    for label, (section, key) in {
        "V final / V(0)": ("lyapunov", "ratio"), "dhat final (m)": ("depth", "dhat_final"),
        "v peak (m/s)": ("commands", "v_peak_mps"), "w rms (rad/s)": ("commands", "w_rms_radps"),
        "longest loss (s)": ("target", "longest_loss_s"), "min |x_hd1_dot| run (1/s)": ("condition35", "min_abs_xhd1_dot"),
    }.items():
        assert close_to_shown(as_number(metrics[label]), report[section][key]), label
    verdict = {row[0]: row[1] for row in next(rows for title, rows in tables.items() if title.startswith("verdict"))[1:]}
    assert verdict["converged"] == ("yes" if report["verdict"]["converged"] else "no")
    assert [verdict[label] for label in ("closed loop", "finished", "final position error", "final heading error", "V fell (36)", "commands smooth")] \
        == report["verdict"]["reasons"]


def test_the_verdict_fits_the_terminal(runs, monkeypatch):
    """The verdict's sentences wrap to the reader's width ($COLUMNS, else stderr's terminal),
    even through a pipe; the numbers' tables do not wrap."""
    monkeypatch.setenv("COLUMNS", "80")
    text = call_hbvs("report", str(runs["run"]), str(runs["paper"])).stdout.decode()
    verdict = text[text.index("verdict ("):].splitlines()[1:]
    assert len(verdict) > 8 and max(len(line.rstrip()) for line in verdict) <= 80
    words = " ".join(verdict).split()
    report = report_json(runs["paper"])
    for reason in report["verdict"]["reasons"]:
        assert all(word in words for word in reason.split()), reason


def test_comparison_prints_both_runs_side_by_side(runs):
    result = call_hbvs("report", str(runs["run"]), str(runs["paper"]))
    assert result.returncode == 0
    tables = parse_tables(result.stdout.decode())
    assert tables["run"][0] == ["quantity", "lateral-gain", "paper"]
    both = report_json(runs["run"], runs["paper"])
    assert list(both) == ["runs"] and [r["run"]["law"] for r in both["runs"]] == ["lateral-gain", "paper"]
    errors = {row[0]: row[1:] for row in next(rows for title, rows in tables.items() if title.startswith("image errors"))}
    for label, (name, statistic) in {"e1 final |.| (d*)": ("e1", "final"), "e3 rmse (deg)": ("e3", "rmse"),
                                      "ebar2 max (d*)": ("ebar2", "max")}.items():
        for cell, report in zip(errors[label], both["runs"]):
            assert close_to_shown(as_number(cell), report["errors"][name][statistic])
    gains = {row[0]: row[1:] for row in tables["run"]}
    # k_2 from the fit's rule k_w^2 / (4 x_hd1_dot^2) (about 400 here); the paper's law forces 1.
    assert close_to_shown(as_number(gains["gain k_2 (-)"][0]), both["runs"][0]["run"]["gains"]["k_2"])
    assert 390 < both["runs"][0]["run"]["gains"]["k_2"] < 410 and gains["gain k_2 (-)"][1] == "1"


# ----------------------------------------------------------------------------- thresholds
def test_fail_above_passes_fails_and_rejects_bad_keys(runs):
    value = report_json(runs["run"])["pose_error"]["position_m"]["final"]
    key = "pose_error.position_m.final"
    above = call_hbvs("report", str(runs["run"]), "--json", "--fail-above", f"{key}={value * 1.01}")
    assert above.returncode == 0 and above.stderr == b""
    json.loads(above.stdout)
    below = call_hbvs("report", str(runs["run"]), "--json", "--fail-above", f"{key}={value * 0.99}")
    assert below.returncode == 1
    json.loads(below.stdout)                                   # the report is still printed
    lines = below.stderr.decode().strip().splitlines()
    assert len(lines) == 1 and key in lines[0] and f"{value:.6g}" in lines[0] and f"{value * 0.99:g}" in lines[0]
    for bad, message in (
        ("pose_error.position_m.fnal=1", "no key 'fnal'"),
        ("errors.e1=1", "names a group"),
        ("errors.e1.final", "NAME=VALUE"),
        ("errors.e1.final=abc", "NAME=VALUE"),
    ):
        result = call_hbvs("report", str(runs["run"]), "--fail-above", bad)
        assert result.returncode == 2, bad
        assert result.stdout == b""                            # checked before printing
        stderr = result.stderr.decode().strip().splitlines()
        assert len(stderr) == 1 and message in stderr[0] and stderr[0].startswith("hbvs: error:")


def test_fail_above_on_null_or_absent_values_is_a_usage_error(runs):
    null = call_hbvs("report", str(runs["replay"]), "--fail-above", "lyapunov.final=1")
    assert null.returncode == 2 and b"null" in null.stderr
    absent = call_hbvs("report", str(runs["replay"]), "--fail-above", "pose_error.position_m.final=1")
    assert absent.returncode == 2 and b"no key 'pose_error'" in absent.stderr


def test_fail_above_applies_to_every_run(runs):
    reports = report_json(runs["run"], runs["paper"])["runs"]
    finals = [r["errors"]["e3"]["final"] for r in reports]
    bound = 0.5 * (min(finals) + max(finals))
    result = call_hbvs("report", str(runs["run"]), str(runs["paper"]), "--fail-above", f"errors.e3.final={bound}")
    assert result.returncode == 1
    assert len(result.stderr.decode().strip().splitlines()) == 1


def test_tolerance_option(runs):
    loose = report_json(runs["run"], "--tolerance", "position_m=10", "--tolerance", "heading_deg=90")
    assert loose["pose_error"]["position_m"]["settling_time_s"] is not None
    assert any(r.startswith("pass: final position error") for r in loose["verdict"]["reasons"])
    for bad in ("position=1", "e1=0", "e1"):
        result = call_hbvs("report", str(runs["run"]), "--tolerance", bad)
        assert result.returncode == 2 and result.stdout == b"", bad


# ----------------------------------------------------------------------------- plot
def png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE and data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def test_plot_writes_a_png_of_the_stated_size(runs, tmp_path):
    import matplotlib.image

    path = tmp_path / "figure.png"
    result = call_hbvs("report", str(runs["run"]), str(runs["paper"]), "--json", "--plot", str(path))
    assert result.returncode == 0, result.stderr.decode()
    json.loads(result.stdout)
    width, height = png_size(path)
    assert width == 1400 and 1800 <= height <= 2200                # 7 in wide at 200 dpi, all panels
    image = matplotlib.image.imread(path)
    assert image.shape[:2] == (height, width)
    assert float(np.std(image[..., :3])) > 0.05                # not a blank page


def test_figure_axes_are_labelled_with_units(runs):
    from hbvs_cli.report.plots import plot_runs

    loaded = [read_run(runs["run"]), read_run(runs["paper"])]
    figure = plot_runs(loaded, [build_report(run) for run in loaded])
    assert figure.get_size_inches()[0] == 7.0 and figure.dpi == 200
    labels = set()
    for ax in figure.axes:
        if ax.get_label() == "top":                            # the frame of the two top views
            continue
        assert ax.get_lines(), ax.get_title(loc="left")
        for label in (ax.get_xlabel(), ax.get_ylabel()):
            assert re.search(r"\(.+\)", label), (ax.get_title(loc="left"), label)
            labels.add(label)
    assert {"time t (s)", "$e_1$ (units of $d^*$)", r"$\bar{e}_2$ (units of $d^*$)", "$e_3$ (deg)", "$v_c$ (m/s)",
            r"$\omega_c$ (rad/s)", "depth (m)",
            "x (m)", "y (m)", "position error (cm)", "|heading error| (deg)", "V / V(0) (-)"} <= labels
    axes = {ax.get_label(): ax for ax in figure.axes}
    assert axes["V"].get_yscale() == "log"
    assert [t.get_text() for t in figure.legends[0].get_texts()][1].startswith("paper (")


def test_replay_figure_leaves_out_what_it_has_no_data_for(runs):
    """A replay has no ground-truth poses and no V: by default those panels are left out;
    named with --panels, each says in its middle what is missing."""
    from hbvs_cli.report.figure_style import FigureStyle
    from hbvs_cli.report.plots import PANEL_NAMES, plot_runs

    run = read_run(runs["replay"])
    figure = plot_runs([run], [build_report(run)])
    axes = {ax.get_label(): ax for ax in figure.axes}
    assert set(axes) == set(PANEL_NAMES) - {"position", "heading", "top", "V"}
    assert all(axes[name].get_lines() for name in ("e1", "ebar2", "e2", "e3", "v", "w", "dhat"))
    figure = plot_runs([run], [build_report(run)], FigureStyle(panels=("position", "V", "top", "e1")))
    axes = {ax.get_label(): ax for ax in figure.axes}
    texts = {name: " ".join(t.get_text() for t in ax.texts) for name, ax in axes.items()}
    assert "V unknown" in texts["V"] and "no ground-truth poses" in texts["top"] and "no ground-truth poses" in texts["position"]


# ----------------------------------------------------------------------------- TUM
def test_export_tum_parses_back_to_the_poses(runs, tmp_path):
    result = call_hbvs("report", str(runs["run"]), "--json", "--export-tum", str(tmp_path / "tum"))
    assert result.returncode == 0, result.stderr.decode()
    run = read_run(runs["run"])
    for suffix, poses in (("taught", run.desired_pose), ("repeated", run.true_pose)):
        data = np.loadtxt(tmp_path / "tum" / f"run.{suffix}.tum", comments="#")
        assert data.shape == (run.steps, 8)
        np.testing.assert_allclose(data[:, 0], run.state["t"], atol=1e-9)
        np.testing.assert_allclose(data[:, 1:3], poses[:, :2], atol=1e-9)
        assert np.all(data[:, 3] == data[0, 3]) and data[0, 3] > 0     # the camera height
        np.testing.assert_allclose(np.linalg.norm(data[:, 4:], axis=1), 1.0, atol=1e-8)
        np.testing.assert_allclose(data[:, 4:6], 0.0)
        yaw = 2.0 * np.arctan2(data[:, 6], data[:, 7])
        np.testing.assert_allclose(np.angle(np.exp(1j * (yaw - poses[:, 2]))), 0.0, atol=1e-8)


def test_export_tum_needs_ground_truth(runs, tmp_path):
    result = call_hbvs("report", str(runs["replay"]), "--export-tum", str(tmp_path / "tum"))
    assert result.returncode == 2 and b"ground-truth" in result.stderr and result.stdout == b""
    assert not (tmp_path / "tum").exists()


# ----------------------------------------------------------------------------- input
def test_bad_input_exits_3_with_one_line(runs, tmp_path):
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    for path, message in ((runs["teach"], b"'teach' file"), (junk, b"not an MCAP file"), (tmp_path / "missing.mcap", b"no such file")):
        result = call_hbvs("report", str(path))
        assert result.returncode == 3, path
        assert result.stdout == b""
        lines = result.stderr.decode().strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("hbvs: error:") and message.decode() in lines[0]


def test_stdin_is_read_once(runs, tmp_path):
    data = runs["run"].read_bytes()
    from_stdin = report_json("-", input=data)
    from_file = report_json(runs["run"])
    assert from_stdin["run"]["name"] == "stdin"
    assert from_stdin["errors"] == from_file["errors"] and from_stdin["pose_error"] == from_file["pose_error"]
    twice = call_hbvs("report", "-", "-", input=data)
    assert twice.returncode == 2 and b"only once" in twice.stderr
    # With --export-tum stdin is kept in memory, to read the camera height from it too.
    exported = call_hbvs("report", "-", "--export-tum", str(tmp_path), input=data)
    assert exported.returncode == 0, exported.stderr.decode()
    assert np.loadtxt(tmp_path / "stdin.repeated.tum").shape == (from_file["run"]["steps"], 8)


def test_run_report_in_process(runs, capsys):
    from hbvs_cli.stages.report import ReportOptions, run_report

    stderr = io.StringIO()
    code = run_report(ReportOptions(runs=[str(runs["paper"])], json_output=True, fail_above=["commands.v_peak_mps=100"]),
                      Console(stream=stderr))
    assert code == 0 and stderr.getvalue() == ""
    assert json.loads(capsys.readouterr().out)["run"]["law"] == "paper"
    with pytest.raises(UsageError, match="at least one run"):
        run_report(ReportOptions(runs=[]), Console(stream=stderr))
