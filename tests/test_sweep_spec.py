"""The sweep's plan (grid, scipy.stats.qmc samples, seeds, printed options), its summary
statistics, and the baseline laws it compares."""

from __future__ import annotations

import math
import shlex

import numpy as np
import pytest

from hbvs_cli.errors import InvalidValueError, UsageError
from hbvs_cli.sweep.spec import SweepPlan, build_spec, parse_vary, repeat_arguments, repeat_command, run_seed


def test_a_grid_crosses_every_listed_value_and_repeats_each_point():
    spec = build_spec(None, ["offset_y=-0.3:0.3:13", "law=paper,lateral-gain"], ["perception=points"], repeats=20, seed=3)
    plan = SweepPlan(spec)
    assert plan.points == 26 and plan.runs == 520
    runs = list(plan)
    assert [r.index for r in runs] == list(range(520))
    offsets = sorted({r.values["offset_y"] for r in runs})
    assert offsets == pytest.approx(np.linspace(-0.3, 0.3, 13), abs=1e-12) and offsets[7] == 0.05
    for law in ("paper", "lateral-gain"):
        assert sum(r.values["law"] == law for r in runs) == 260
    assert all(r.values["perception"] == "points" for r in runs)
    # Run i is point i // repeats; its seed comes from the sweep seed and i alone.
    assert runs[41].point == 2 and runs[41].repeat == 1 and runs[41].seed == run_seed(3, 41)
    assert len({r.seed for r in runs}) == 520
    assert plan.run(41) == runs[41]


def test_sampled_ranges_stay_in_range_and_every_law_meets_the_same_samples():
    for method in ("sobol", "halton", "lhs", "random"):
        spec = build_spec({"vary": {"dhat0_factor": {"from": 0.5, "to": 2.0}, "offset_theta": {"from": -10, "to": 10},
                                    "law": ["paper", "non-adaptive"]}}, sampling=method, samples=64, seed=9)
        plan = SweepPlan(spec)
        assert plan.runs == 128
        values = [plan.run(i).values for i in range(plan.runs)]
        factors = np.array([v["dhat0_factor"] for v in values])
        assert factors.min() >= 0.5 and factors.max() <= 2.0 and np.ptp(factors) > 1.2
        # Paired design: the second law gets exactly the first law's samples.
        assert [v["dhat0_factor"] for v in values[:64]] == [v["dhat0_factor"] for v in values[64:]]
        # Low-discrepancy: each quarter of the range holds about a quarter of the samples.
        counts = np.histogram(factors[:64], bins=4, range=(0.5, 2.0))[0]
        assert counts.min() >= (16 if method != "random" else 8)
        # Seeded: the same spec gives the same samples.
        assert SweepPlan(spec).run(5).values == plan.run(5).values


def test_options_and_spec_errors_are_usage_errors():
    for bad in ("nothing", "bogus=1,2", "law=paper:lateral-gain", "offset_y=0:1:0", "pixel_noise=-1,2", "law=fastest"):
        with pytest.raises(UsageError):
            parse_vary(bad)
    with pytest.raises(UsageError, match="grid needs values"):
        build_spec(None, ["offset_y=-0.3:0.3"])
    with pytest.raises(UsageError, match="both varied and fixed"):
        build_spec({"vary": {"k_v": [1, 2]}, "fixed": {"k_v": 3}})
    with pytest.raises(UsageError, match="nothing varies"):
        build_spec(None, [], ["perception=points"])


def test_the_printed_command_holds_exactly_the_options_of_the_run():
    from hbvs_cli.stages.repeat import RepeatOptions

    values = {"offset_y": 0.1 + 0.2, "dhat0_factor": 0.7, "occlusion_length": 1.5, "latency": 2, "law": "kanayama", "perception": "points"}
    arguments = repeat_arguments(values, 123, d_true=4.0)
    assert arguments["offset"] == "-0.1,0.30000000000000004,2.0" and arguments["dhat0"] == 0.7 * 4.0
    assert arguments["occlude"] == ["8.0:9.5"]
    command = repeat_command("/data/fit.mcap", arguments)
    words = shlex.split(command)
    assert words[:4] == ["hbvs", "repeat", "/data/fit.mcap", "--sim"] and "--seed=123" in words
    # Read back the way the CLI reads it: the same floats, to the last bit.
    parsed = dict(w[2:].split("=", 1) for w in words if w.startswith("--") and "=" in w)
    assert float(parsed["dhat0"]) == arguments["dhat0"] and parsed["offset"] == arguments["offset"]
    RepeatOptions(input="/data/fit.mcap", **arguments)


def test_wilson_interval_matches_the_formula():
    from hbvs_cli.report.sweep_summary import wilson_interval

    for k, n in ((0, 10), (7, 10), (40, 40), (123, 400)):
        p, z = k / n, 1.959963984540054
        centre = (p + z * z / (2 * n)) / (1 + z * z / n)
        half = z / (1 + z * z / n) * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
        low, high = wilson_interval(k, n)
        assert low == pytest.approx(max(centre - half, 0.0), abs=1e-12) and high == pytest.approx(min(centre + half, 1.0), abs=1e-12)
    assert wilson_interval(0, 0) == (None, None)


# ----------------------------------------------------------------------------- baseline laws
def test_kanayama_reconstruction_is_the_pose_error_in_the_robot_frame(rng):
    """e_xy = dhat (x_h - Rz(e3) x_hd) is the desired pose seen from the robot, (3)-(5)."""
    from hbvs_cli.core.controller import DesiredState, Measurement
    from hbvs_cli.core.laws import reconstructed_tracking_error

    d_star = 4.0
    reference = np.array([0.3, -0.2, 0.4])  # F* in the world (x, y, phi)
    for _ in range(20):
        robot = reference + rng.uniform(-1, 1, 3) * [1.5, 1.0, 0.4]
        desired_pose = reference + rng.uniform(-1, 1, 3) * [1.5, 1.0, 0.4]

        def homography_state(pose):
            c, s = math.cos(pose[2]), math.sin(pose[2])
            x_f = np.array([[c, s], [-s, c]]) @ (reference[:2] - pose[:2])
            return reference[2] - pose[2], x_f / d_star

        theta, x_h = homography_state(robot)
        theta_d, x_hd = homography_state(desired_pose)
        e_x, e_y, e_theta = reconstructed_tracking_error(
            Measurement(theta=theta, x_h1=x_h[0], x_h2=x_h[1]),
            DesiredState(theta_d=theta_d, x_hd1=x_hd[0], x_hd2=x_hd[1], theta_d_dot=0.0, x_hd1_dot=0.0, x_hd2_dot=0.0),
            d_star,
        )
        c, s = math.cos(robot[2]), math.sin(robot[2])
        expected = np.array([[c, s], [-s, c]]) @ (desired_pose[:2] - robot[:2])
        assert np.allclose([e_x, e_y], expected, atol=1e-12)
        assert e_theta == pytest.approx(math.remainder(desired_pose[2] - robot[2], math.tau), abs=1e-12)


def test_baselines_hold_their_depth_and_drop_the_depth_term_of_v():
    from hbvs_cli.core.controller import ControllerGains, DesiredState, Measurement, TrackingErrors, lyapunov
    from hbvs_cli.core.laws import KanayamaController, gains_for_law, make_controller

    desired = DesiredState(theta_d=0.01, x_hd1=-0.3, x_hd2=0.02, theta_d_dot=0.01, x_hd1_dot=0.025, x_hd2_dot=0.0)
    measured = Measurement(theta=0.03, x_h1=-0.28, x_h2=0.05)
    for law in ("non-adaptive", "kanayama"):
        controller = make_controller(law, ControllerGains(), 2.5)
        for _ in range(100):
            output = controller.step(measured, desired, 0.033)
        assert controller.dhat == 2.5 and float(output.dhat_dot) == 0.0
        assert gains_for_law(ControllerGains(), law).gamma == 0.0
    assert isinstance(make_controller("kanayama", ControllerGains(), 2.5), KanayamaController)
    adaptive = make_controller("lateral-gain", ControllerGains(), 2.5)
    adaptive.step(measured, desired, 0.033)
    assert adaptive.dhat != 2.5
    errors = TrackingErrors(e1=0.01, e2=0.02, e3=0.03, ebar2=0.025)
    frozen = gains_for_law(ControllerGains(), "non-adaptive")
    assert lyapunov(errors, 2.5, 4.0, frozen) == pytest.approx(0.5 * 4 * 1e-4 + 0.5 * 400 * 0.025**2 + 0.5 * 9e-4, rel=1e-12)
    with pytest.raises(InvalidValueError):
        ControllerGains(k_v=0.0)


@pytest.mark.parametrize("law", ["non-adaptive", "kanayama"])
def test_each_baseline_tracks_with_the_true_depth(tmp_path, law):
    """With dhat0 = d* and exact points, both baselines bring the robot onto the taught
    path of the sample (within 1 cm and 0.5 deg; the sample's 320 px camera limits heading)."""
    from conftest import SAMPLES, make_run
    from hbvs_cli.io.run_file import read_run
    from hbvs_cli.report.build import build_report

    make_run(SAMPLES / "fit.mcap", tmp_path / "run.mcap", sim=True, perception="points", rate=30.0, law=law, dhat0=4.0)
    report = build_report(read_run(tmp_path / "run.mcap"))
    assert report.run.law == law and report.run.gains["gamma"] == 0.0
    assert report.depth.dhat_final == 4.0
    assert report.pose_error["position_m"].final < 0.01
    assert report.pose_error["heading_deg"].final < 0.5
    assert report.lyapunov.ratio < 0.01


def test_the_final_merge_streams_window_by_window_and_keeps_one_row_per_index(tmp_path, monkeypatch):
    """Parts in completion order, a part written twice (a kill during a merge) and an earlier
    runs.parquet merge into one sorted table, whatever the window."""
    import random

    import pyarrow as pa
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    from hbvs_cli.io import sweep_table as results

    schema = pa.schema([pa.field("index", pa.int64()), pa.field("value", pa.float64()), pa.field("status", pa.string())])
    rng = random.Random(7)
    order = list(range(300))
    # Runs finish out of order, but near their submission (a bounded number in flight).
    for start in range(0, 300, 20):
        block = order[start:start + 20]
        rng.shuffle(block)
        order[start:start + 20] = block
    folder = tmp_path / "sweep"
    first = results.ResultsTable(folder, schema, {"spec": 1}, flush_rows=16, flush_seconds=1e9)
    for index in order[:150]:
        first.append({"index": index, "value": index / 10, "status": "ok"})
    assert first.finish() == 150
    first.release()  # as the sweep does when it ends: the folder's lock
    monkeypatch.setattr(results, "MERGE_WINDOW", 37)
    second = results.ResultsTable(folder, schema, {"spec": 1}, flush_rows=16, flush_seconds=1e9)
    assert second.done == set(order[:150])
    for index in order[150:]:
        second.append({"index": index, "value": index / 10, "status": "ok"})
    second.flush()
    # The same rows once more, as after a kill between the merge and the parts' removal.
    repeated = folder / results.PARTS / "part-999999.parquet"
    pq.write_table(pa.Table.from_pylist([{"index": i, "value": i / 10, "status": "ok"} for i in order[140:180]], schema=schema), repeated)
    windows = list(results.merged_windows(folder, schema))
    assert max(w.num_rows for w in windows) <= 37
    assert second.finish() == 300
    merged = pq.read_table(folder / results.PARQUET)
    assert merged.column("index").to_pylist() == list(range(300))
    assert merged.column("value").to_pylist() == [i / 10 for i in range(300)]
    assert pq.ParquetFile(folder / results.PARQUET).metadata.num_row_groups > 1
    csv = pacsv.read_csv(folder / results.CSV)
    assert csv.column("index").to_pylist() == list(range(300))
    assert not list((folder / results.PARTS).glob("*.parquet")) and not list(folder.rglob("*.partial"))


def test_sweep_help_lists_every_parameter_without_loading_numpy(monkeypatch):
    """``hbvs sweep --help`` names what --vary and --set take, with units (issue 46); the
    names come from a module without numpy, so the command line still starts without it."""
    import subprocess
    import sys

    from hbvs_cli.sweep.parameters import PARAMETERS
    from conftest import call_hbvs

    monkeypatch.setenv("COLUMNS", "400")
    text = " ".join(call_hbvs("sweep", "--help").stdout.decode().split())
    for name, parameter in PARAMETERS.items():
        assert f"{name} (" in text, name
    assert "offset_y (m)" in text and "law (lateral-gain|paper|non-adaptive|kanayama)" in text
    loaded = subprocess.run([sys.executable, "-c", "import sys, hbvs_cli.cli.app; print('numpy' in sys.modules)"],
                            capture_output=True, text=True, check=True).stdout.strip()
    assert loaded == "False"
