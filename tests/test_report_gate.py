"""``hbvs report`` as a CI gate, and the bookkeeping behind it (issue 18, "the report as a gate").

One 8 s taught s-curve and its fit; repeats with projected points (cheap): the default
law, the paper's law, a 7 s occlusion with 10 % dropped frames (not stopped, to measure the
loss), the same with the default 3 s lost timeout (stopped), and an open-loop replay.
"""

from __future__ import annotations

import io
import json
import math
import re
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

from hbvs_cli.errors import TargetLostError
from hbvs_cli.io.run_file import read_run
from hbvs_cli.stages.console import Console, ProgressTask

from conftest import run_hbvs

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
def runs(tmp_path_factory) -> dict:
    from hbvs_cli.stages.fit import FitOptions, run_fit
    from hbvs_cli.stages.repeat import RepeatOptions, run_repeat
    from hbvs_cli.stages.teach import TeachOptions, run_teach

    tmp = tmp_path_factory.mktemp("gate")
    quiet = Console(quiet=True)
    paths = {name: tmp / f"{name}.mcap" for name in ("teach", "fit", "run", "paper", "faults", "stopped", "replay")}
    run_teach(TeachOptions(output=str(paths["teach"]), duration=8.0), quiet)
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
    result = run_hbvs("report", *map(str, args), "--json")
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
    loose = ["--tolerance", "position_m=0.05", "--tolerance", "heading_deg=0.5"]
    passed = run_hbvs("report", str(run), "--json", "--require-converged", *loose)
    assert passed.returncode == 0 and passed.stderr == b""
    assert json.loads(passed.stdout)["verdict"]["converged"] is True
    # The case: a tight tolerance turns the verdict to "no", and now the exit code too.
    tight = run_hbvs("report", str(run), "--json", "--require-converged", "--tolerance", "position_m=0.0001")
    assert tight.returncode == 1
    assert json.loads(tight.stdout)["verdict"]["converged"] is False              # the report is still printed
    lines = tight.stderr.decode().strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("hbvs: warning: not converged:") and "final position error" in lines[0]
    without = run_hbvs("report", str(run), "--json", "--tolerance", "position_m=0.0001")
    assert without.returncode == 0                                                 # only when asked
    several = run_hbvs("report", str(run), str(runs["paths"]["faults"]), "--require-converged", *loose)
    assert several.returncode == 1
    lines = several.stderr.decode().strip().splitlines()
    assert len(lines) == 1 and "faults.mcap" in lines[0]


def test_a_comparison_names_its_checks(runs):
    result = run_hbvs("report", str(runs["paths"]["run"]), str(runs["paths"]["replay"]))
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
    assert list(both["runs"][0]["verdict"]["checks"]) == ["closed_loop", "finished", "final_position", "final_heading", "lyapunov"]
    assert list(both["runs"][1]["verdict"]["checks"]) == ["closed_loop", "finished", "final_e1", "final_e2", "final_e3", "lyapunov"]


def _significant_digits(literal: str) -> int:
    """Digits of a decimal literal from the first non-zero one to the last non-zero one."""
    return len(re.split(r"[eE]", literal)[0].lstrip("-").replace(".", "").strip("0"))


def test_json_numbers_are_rounded(runs):
    result = run_hbvs("report", str(runs["paths"]["run"]), str(runs["paths"]["faults"]), "--json")
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
        misuse = run_hbvs("report", str(fit), *bad)
        assert misuse.returncode == 2 and misuse.stdout == b"", bad
        assert len(misuse.stderr.decode().strip().splitlines()) == 1
