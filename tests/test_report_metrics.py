"""Report metrics on signals whose statistics are known in closed form (issue: report)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hbvs_cli.core.metrics import (
    error_summary,
    final_value,
    initial_value,
    longest_true_run_s,
    lyapunov_summary,
    min_abs,
    peak_abs,
    rms,
    sample_rate_hz,
    settling_time,
    signal_statistics,
)
from hbvs_cli.errors import UsageError
from hbvs_cli.io.run_file import STATE_FIELDS, RunData
from hbvs_cli.report.build import DEFAULT_TOLERANCES, build_report, resolve_tolerances

from oracles import REPORT_KEYS

RATE_HZ = 100.0
DT = 1.0 / RATE_HZ
N = 1000                      # 10 s at 100 Hz
A, TAU = 0.2, 1.5             # e(t) = A exp(-t / TAU)
LOST = slice(300, 350)        # the target is lost from 3.00 s to 3.49 s (50 steps)
R = math.exp(-DT / TAU)       # ratio of consecutive samples

#: What the verdict says of an open-loop replay.
REPLAY_VERDICT = (
    "open-loop replay: the commands were computed on the recorded frames, not executed (nothing moved), so it cannot "
    "have converged; dhat adapted on errors no command corrected and is no estimate of d*"
)


def geometric(r: float, start: int, stop: int) -> float:
    """sum_{k=start}^{stop-1} r^k in closed form."""
    return r**start * (1.0 - r ** (stop - start)) / (1.0 - r)


@pytest.fixture
def decay():
    t = np.arange(N) * DT
    e = A * np.exp(-t / TAU)
    e[LOST] = np.nan
    return t, e


def closed_form_sums(power: int) -> float:
    """sum over the valid steps of (e / A)^power."""
    r = R**power
    return geometric(r, 0, N) - geometric(r, LOST.start, LOST.stop)


def test_statistics_of_an_exponential_decay_match_the_closed_form(decay):
    t, e = decay
    n = N - (LOST.stop - LOST.start)
    mean = A * closed_form_sums(1) / n
    mean_square = A**2 * closed_form_sums(2) / n
    # Decreasing samples: the median is the mean of the two middle ones, which lie after the
    # lost stretch (valid positions 474 and 475 are steps 524 and 525).
    median = 0.5 * A * (R**524 + R**525)
    stats = signal_statistics(e)
    assert stats["rmse"] == pytest.approx(math.sqrt(mean_square), rel=1e-12)
    assert stats["mean"] == pytest.approx(mean, rel=1e-12)
    assert stats["median"] == pytest.approx(median, rel=1e-12)
    assert stats["std"] == pytest.approx(math.sqrt(mean_square - mean**2), rel=1e-9)
    assert stats["min"] == pytest.approx(A * R ** (N - 1), rel=1e-12)
    assert stats["max"] == pytest.approx(A, rel=1e-15)
    # ... and agree with numpy on the valid samples.
    valid = e[np.isfinite(e)]
    assert stats["std"] == pytest.approx(np.std(valid), rel=1e-12)
    assert stats["median"] == pytest.approx(np.median(valid), rel=1e-15)


def test_initial_final_and_settling_time(decay):
    t, e = decay
    assert initial_value(e) == pytest.approx(A, rel=1e-15)
    # The last 5 % of 9.99 s starts at 9.4905 s: steps 950..999.
    assert final_value(t, e) == pytest.approx(A * geometric(R, 950, N) / 50, rel=1e-12)
    # |e| <= tol from t* = TAU ln(A / tol) on: the first sample at or after t*.
    tolerance = 0.01
    expected = math.ceil(TAU * math.log(A / tolerance) * RATE_HZ) * DT
    assert settling_time(t, e, tolerance) == pytest.approx(expected, abs=1e-12)
    assert expected == pytest.approx(4.50)


def test_settling_inside_a_lost_stretch_counts_from_the_next_seen_sample(decay):
    t, e = decay
    # The band is entered at 3.2 s, while the target is lost: the first sample seen inside
    # it is at 3.50 s.
    tolerance = A * math.exp(-3.2 / TAU)
    assert settling_time(t, e, tolerance) == pytest.approx(3.50, abs=1e-12)


def test_settling_edge_cases(decay):
    t, e = decay
    assert settling_time(t, e, 1.0) == 0.0                      # always inside the band
    late = e.copy()
    late[-1] = 1.0                                              # leaves the band at the end
    assert settling_time(t, late, 0.01) is None
    blip = e.copy()
    blip[700] = -0.5                                            # a late excursion, negative
    assert settling_time(t, blip, 0.01) == pytest.approx(7.01, abs=1e-12)
    start_lost = e.copy()
    start_lost[:10] = np.nan
    assert initial_value(start_lost) == pytest.approx(A * R**10)
    assert settling_time(t, start_lost, 1.0) == pytest.approx(0.10, abs=1e-12)
    nothing = np.full(N, np.nan)
    assert settling_time(t, nothing, 1.0) is None
    assert initial_value(nothing) is None and final_value(t, nothing) is None
    assert all(v is None for v in signal_statistics(nothing).values())


def test_final_is_the_mean_magnitude_and_skips_lost_samples():
    t = np.arange(200) * DT                                     # 1.99 s: last 5 % from 1.8905 s
    x = np.where(np.arange(200) % 2 == 0, 1.0, -3.0)
    assert final_value(t, x) == pytest.approx(2.0)              # 10 samples, half |1| half |-3|
    x[195:] = np.nan
    assert final_value(t, x) == pytest.approx((3 * 1.0 + 2 * 3.0) / 5)
    x[189:] = np.nan
    assert final_value(t, x) is None                            # lost at the end


def test_error_summary_has_every_statistic(decay):
    t, e = decay
    summary = error_summary(t, e, 0.01)
    assert list(summary) == ["rmse", "mean", "median", "std", "min", "max", "initial", "final", "settling_time_s"]
    assert summary["settling_time_s"] == pytest.approx(4.50)


def test_lyapunov_increase_fraction_on_a_constructed_V():
    V = 1.0 - 0.001 * np.arange(101)                            # decreasing: 100 pairs
    V[50] = V[49] + 0.01                                        # one real increase (49 -> 50)
    V[80] = V[79] + 1e-12                                       # below 1e-9 V(0): noise, not counted
    V[20] = V[19] + 1e-8                                        # above 1e-9 V(0): counted
    V[70:73] = np.nan                                           # pairs 69-70 ... 72-73 are skipped
    summary = lyapunov_summary(V)
    assert summary["initial"] == 1.0
    assert summary["final"] == pytest.approx(0.9)
    assert summary["ratio"] == pytest.approx(0.9)
    assert summary["increase_fraction"] == pytest.approx(2 / 96)


def test_lyapunov_unknown_is_all_null():
    assert lyapunov_summary(np.full(10, np.nan)) == {"initial": None, "final": None, "ratio": None, "increase_fraction": None}
    assert lyapunov_summary(np.array([0.0, 0.0]))["ratio"] is None


def test_longest_loss_in_seconds():
    t = np.arange(N) * DT
    lost = np.zeros(N, dtype=bool)
    assert longest_true_run_s(t, lost) == 0.0
    lost[LOST] = True                                           # 50 steps
    lost[600:610] = True                                        # 10 steps
    assert longest_true_run_s(t, lost) == pytest.approx(0.50, abs=1e-12)
    lost[:] = False
    lost[-70:] = True                                           # to the end: the last step lasts one period
    assert longest_true_run_s(t, lost) == pytest.approx(0.70, abs=1e-12)


def test_small_helpers():
    x = np.array([np.nan, -2.0, 1.0, 0.5])
    assert peak_abs(x) == 2.0 and min_abs(x) == 0.5
    assert rms(x) == pytest.approx(math.sqrt((4 + 1 + 0.25) / 3))
    assert sample_rate_hz(np.arange(5) * 0.02) == pytest.approx(50.0)
    assert sample_rate_hz(np.array([0.0])) is None
    assert peak_abs(np.array([np.nan])) is None


# ----------------------------------------------------------------------------- build_report on a synthetic run
def synthetic_run(mode: str = "sim", ground_truth: bool = True, events=None, truncated: bool = False) -> RunData:
    """A 10 s run at 100 Hz whose errors decay as A exp(-t / TAU), lost from 3.00 to 3.49 s."""
    t = np.arange(N) * DT
    decay = A * np.exp(-t / TAU)
    state = {key: np.zeros(N) for key in STATE_FIELDS}
    state["t"] = t
    for key in ("e1", "e2", "ebar2"):
        state[key] = decay.copy()
    state["e3"] = np.radians(10.0) * np.exp(-t / TAU)          # 10 deg -> 0
    state["V"] = decay**2 if ground_truth else np.full(N, np.nan)
    state["dhat"] = np.linspace(3.0, 3.9, N)
    state["x_hd1_dot"] = -0.02 - 0.01 * np.sin(t)
    state["v_c"] = 0.1 * np.ones(N)
    state["w_c"] = 0.05 * np.cos(t)
    lost = np.zeros(N, dtype=bool)
    lost[LOST] = True
    for key in ("e1", "e2", "ebar2", "e3", "V"):
        state[key][lost] = np.nan
    desired = np.stack([0.1 * t, np.zeros(N), np.full(N, math.pi - 0.01)], axis=-1)
    true = desired.copy()
    true[:, 1] = 0.03 * np.exp(-t / TAU)                       # 3 cm lateral offset, decaying
    true[:, 2] = -math.pi + 0.01                               # 0.02 rad left of the taught heading, across +-pi
    return RunData(
        name="synthetic.mcap",
        info={"mode": mode, "law": "paper", "gains": {"k_v": 4.0, "k_w": 1.0, "gamma": 2500.0, "k_2": 1.0},
              "settings": {"input": "fit.mcap"}, "d_true": 4.0 if ground_truth else None,
              "condition35": {"min_abs_xhd1_dot": 0.0123}},
        state=state, saturated=np.arange(N) < 100, lost=lost, lost_reason=[""] * N,
        true_pose=true if ground_truth else None, desired_pose=desired if ground_truth else None,
        events=list(events or []), truncated=truncated,
    )


def test_report_of_a_synthetic_run():
    report = build_report(synthetic_run(), {}).to_dict()
    assert tuple(report) == REPORT_KEYS
    assert report["run"] == {
        "name": "synthetic.mcap", "label": "paper", "duration_s": pytest.approx(9.99), "steps": N, "rate_hz": pytest.approx(100.0),
        "law": "paper", "gains": {"k_v": 4.0, "k_w": 1.0, "gamma": 2500.0, "k_2": 1.0},
        "source": {"mode": "sim", "fit_file": "fit.mcap"}, "truncated": False,
    }
    assert report["errors"]["e1"]["max"] == pytest.approx(A)
    assert report["errors"]["e3"]["initial"] == pytest.approx(10.0)          # degrees
    # e3 = 10 deg exp(-t / TAU) <= 0.2 deg from TAU ln 50 = 5.868 s on.
    assert report["errors"]["e3"]["settling_time_s"] == pytest.approx(math.ceil(TAU * math.log(50) * RATE_HZ) * DT)
    position = report["pose_error"]["position_m"]
    assert position["initial"] == pytest.approx(0.03)
    assert position["settling_time_s"] == pytest.approx(math.ceil(TAU * math.log(3.0) * RATE_HZ) * DT)
    heading = report["pose_error"]["heading_deg"]
    assert heading["mean"] == pytest.approx(math.degrees(0.02)) and heading["final"] == pytest.approx(math.degrees(0.02))
    assert report["lyapunov"]["ratio"] == pytest.approx((R ** (N - 1)) ** 2)
    assert report["lyapunov"]["increase_fraction"] == 0.0
    # dhat rises 0.09 m/s from 3 m: within 10 % of d* = 4 m (3.6 m) from t = 6.66 s on, and
    # still moving at the end (2.25 % of d* per second).
    assert report["depth"] == {"dhat0": 3.0, "dhat_final": pytest.approx(3.9), "d_true": 4.0,
                               "relative_error": pytest.approx(0.025), "learning_reference": "d_true",
                               "learning_time_s": pytest.approx(6.66, abs=0.011), "end_rate_per_s": pytest.approx(0.9 / 9.99 / 4.0, rel=1e-6),
                               "still_moving": True, "warning": report["depth"]["warning"]}
    assert report["depth"]["warning"].startswith("dhat is still moving at the end of the run (+2.3 % per second)")
    t = np.arange(N) * DT
    dw_dt = np.diff(0.05 * np.cos(t)) / DT
    # The taught commands (25) at d* = 4 m: w_d = 0, v_d = 4 (0.02 + 0.01 sin t).
    dv_d_dt = np.diff(4.0 * (0.02 + 0.01 * np.sin(t))) / DT
    assert report["commands"] == {"v_peak_mps": pytest.approx(0.1), "v_rms_mps": pytest.approx(0.1),
                                  "w_peak_radps": pytest.approx(0.05),
                                  "w_rms_radps": pytest.approx(0.05 * math.sqrt(np.mean(np.cos(t) ** 2))),
                                  "saturated_fraction": pytest.approx(0.1),
                                  "v_tv_per_s": 0.0, "w_tv_per_s": pytest.approx(np.sum(np.abs(np.diff(0.05 * np.cos(t)))) / 9.99),
                                  "dv_dt_rms_mps2": 0.0, "dw_dt_rms_radps2": pytest.approx(np.sqrt(np.mean(dw_dt**2))),
                                  "at_limit_fraction": 0.0,
                                  "limits": {"max_v": None, "max_w": None, "max_accel": None},
                                  "taught": {"v_tv_per_s": pytest.approx(np.sum(np.abs(np.diff(4.0 * 0.01 * np.sin(t)))) / 9.99),
                                             "w_tv_per_s": 0.0, "dv_dt_rms_mps2": pytest.approx(np.sqrt(np.mean(dv_d_dt**2))),
                                             "dw_dt_rms_radps2": 0.0}}
    assert report["target"] == {"lost_frames": 50, "lost_fraction": pytest.approx(0.05), "longest_loss_s": pytest.approx(0.5),
                                "dropped_frames": 0, "dropped_fraction": 0.0}
    assert report["condition35"]["min_abs_xhd1_dot"] == pytest.approx(0.01, abs=1e-6)      # at sin t = -1
    assert report["condition35"]["fit_min_abs_xhd1_dot"] == 0.0123
    # Converged: finished, position 0.03 exp(-9.5 / 1.5) m << 1 cm, heading 1.15 deg > 0.2 deg: no.
    assert report["verdict"]["converged"] is False
    assert "fail: final |heading error| 1.15 deg > 0.2 deg" in report["verdict"]["reasons"]
    assert any(r.startswith("pass: final position error") for r in report["verdict"]["reasons"])


def test_the_typed_report_is_its_json():
    """Each section's fields are the JSON's keys and values; a missing section is None in
    the report and absent from the JSON; ``value`` reads a dotted JSON key (--fail-above)."""
    from hbvs_cli.report.result import MissingKey

    report = build_report(synthetic_run(), {})
    document = report.to_dict()
    assert report.depth.dhat0 == document["depth"]["dhat0"] == 3.0
    assert report.pose_error["position_m"].final == document["pose_error"]["position_m"]["final"]
    assert report.commands.taught.dv_dt_rms_mps2 == report.value("commands.taught.dv_dt_rms_mps2")
    assert report.timing is None and "timing" not in document
    replay = build_report(synthetic_run(mode="replay", ground_truth=False), {})
    assert replay.pose_error is None and "pose_error" not in replay.to_dict()
    with pytest.raises(MissingKey) as missing:
        replay.value("pose_error.position_m.final")
    assert missing.value.where == "the report" and missing.value.part == "pose_error"
    assert replay.verdict.failures()[0] == REPLAY_VERDICT


def test_tolerances_change_the_verdict_and_the_settling_times():
    loose = build_report(synthetic_run(), {"heading_deg": 2.0}).to_dict()
    assert loose["verdict"]["converged"] is True
    final_cm = 3.0 * geometric(R, 950, N) / 50
    assert loose["verdict"]["reasons"] == [
        "pass: closed loop (sim)",
        "pass: run finished (9.99 s, 1000 steps)",
        f"pass: final position error {final_cm:.3g} cm <= 1 cm",
        "pass: final |heading error| 1.15 deg <= 2 deg",
        f"pass: V final / V(0) = {(R ** (N - 1)) ** 2:.3g} < 0.5",
        f"pass: commands smooth: RMS dv/dt 0 <= {10 * loose['commands']['taught']['dv_dt_rms_mps2'] + 1:.3g} m/s^2, "
        f"RMS dw/dt {loose['commands']['dw_dt_rms_radps2']:.3g} <= 1 rad/s^2",
    ]
    assert loose["pose_error"]["heading_deg"]["settling_time_s"] == 0.0
    tight = build_report(synthetic_run(), {"position_m": 1e-6, "heading_deg": 2.0}).to_dict()
    assert tight["verdict"]["converged"] is False
    assert tight["pose_error"]["position_m"]["settling_time_s"] is None


def test_replay_stopped_and_truncated_runs_never_converge():
    replay = build_report(synthetic_run(mode="replay", ground_truth=False), {}).to_dict()
    assert "pose_error" not in replay
    assert replay["lyapunov"] == {"initial": None, "final": None, "ratio": None, "increase_fraction": None}
    assert replay["depth"]["d_true"] is None and replay["depth"]["relative_error"] is None
    assert replay["verdict"]["converged"] is False
    assert replay["verdict"]["checks"]["closed_loop"] == "fail: " + REPLAY_VERDICT
    # Without ground truth the image errors are checked: e1, e2 but not ebar2, and e3.
    checked = [r.split(":")[1].split()[1] for r in replay["verdict"]["reasons"] if "final" in r]
    assert checked == ["|e1|", "|e2|", "|e3|"]
    assert replay["verdict"]["reasons"][-2].startswith("skip: V unknown")
    assert replay["verdict"]["reasons"][-1].startswith("pass: commands smooth")
    stopped = build_report(synthetic_run(events=[(4.0, 4, "target lost for more than 3 s: run stopped")]), {"heading_deg": 2.0}).to_dict()
    assert stopped["verdict"]["converged"] is False
    assert stopped["verdict"]["checks"]["finished"] == "fail: run stopped at t = 4.00 s (target lost for more than 3 s: run stopped)"
    truncated = build_report(synthetic_run(truncated=True), {"heading_deg": 2.0}).to_dict()
    assert truncated["verdict"]["converged"] is False and truncated["run"]["truncated"] is True


def test_default_tolerances_and_bad_overrides():
    assert resolve_tolerances() == DEFAULT_TOLERANCES == {
        "position_m": 0.01, "heading_deg": 0.2, "e1": 0.0025, "e2": 0.0025, "ebar2": 0.0025, "e3": 0.2,
    }
    with pytest.raises(UsageError, match="unknown name 'e4'"):
        resolve_tolerances({"e4": 1.0})
    for bad in (0.0, -1.0, math.inf, math.nan):
        with pytest.raises(UsageError, match="positive"):
            resolve_tolerances({"e1": bad})


def test_chattering_commands_fail_the_verdict_and_limits_are_counted():
    """Rule 5 (docs/report.md): v switching between +-0.5 m/s every step, as the paper's
    law did at 200 Hz with 0.2 px of noise, fails however small the errors; the fraction
    of steps at a limit counts |v| at max_v."""
    run = synthetic_run()
    run.state["v_c"] = 0.5 * np.where(np.arange(N) % 2 == 0, 1.0, -1.0)
    run.info["settings"]["limits"] = {"max_v": 0.5, "max_w": 0.6, "max_accel": None}
    report = build_report(run, {"heading_deg": 2.0}).to_dict()
    commands = report["commands"]
    assert commands["dv_dt_rms_mps2"] == pytest.approx(1.0 / DT)              # 100 m/s^2
    assert commands["v_tv_per_s"] == pytest.approx(1.0 * (N - 1) / 9.99)
    assert commands["at_limit_fraction"] == 1.0
    assert report["verdict"]["converged"] is False
    assert report["verdict"]["reasons"][-1].startswith("fail: commands chatter: RMS dv/dt 100 > 1.29 m/s^2")


def test_a_dhat_that_wanders_about_d_true_is_not_still_moving():
    """With ground truth, a drift at the end within 2 % of d* is noise about the truth; the
    same drift without ground truth, or one ending 2.5 % from d*, is still moving."""
    run = synthetic_run()
    run.state["dhat"] = np.linspace(3.8, 4.05, N)            # 0.63 % of d* per second, ends 1.25 % above d*
    depth = build_report(run, {}).depth
    assert depth.end_rate_per_s == pytest.approx(0.25 / 9.99 / 4.0, rel=1e-6) and depth.relative_error == pytest.approx(0.0125)
    assert depth.still_moving is False and depth.warning is None
    run.state["dhat"] = np.linspace(3.6, 3.9, N)             # 0.75 % per second, ends 2.5 % below d*
    assert build_report(run, {}).depth.still_moving is True
    run.state["dhat"] = np.linspace(3.8, 4.05, N)
    run.info["d_true"] = None
    assert build_report(run, {}).depth.still_moving is True
