"""The surfaces added after the four stages keep their promises (issue 26): ``sweep``,
``export``, the live view and ROS 2 bag inputs lose nothing, hang on nothing, expose nothing,
and answer every user mistake with one line and a documented exit code (never 70).

Each test names the promise it checks; docs/robustness.md lists them. The whole adversarial
campaign over these surfaces is :func:`test_adversarial_campaign_over_the_new_surfaces`
(``pytest -m campaign``).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from conftest import SAMPLES, SUITE_OR_CAMPAIGN, call_hbvs, campaign_extent, run_hbvs, run_with_peak_memory
from oracles import copy_message

FIT = SAMPLES / "fit.mcap"
TEACH = SAMPLES / "teach.mcap"
HBVS = [sys.executable, "-m", "hbvs_cli"]


def one_line(result) -> str:
    """The single stderr line of a failed command (and that it is a single line)."""
    text = result.stderr.decode() if isinstance(result.stderr, bytes) else result.stderr
    lines = [line for line in text.strip().splitlines() if line]
    assert len(lines) == 1, text
    return lines[0]


def dead_pid() -> int:
    """The pid of a process that has ended (for partial names of a killed process)."""
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


def digest_tree(folder: Path) -> dict[str, str]:
    """SHA-256 of every file under ``folder`` (a sweep's lock file aside: it names its holder)."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file() and p.name != ".hbvs-sweep.lock"}


# ----------------------------------------------------------------------------- 9. safety semantics
@pytest.mark.parametrize("option", ["--max-v", "--max-w", "--max-accel"])
def test_a_zero_actuator_limit_is_refused_not_taken_for_no_limit(tmp_path, option):
    result = call_hbvs("repeat", str(FIT), "--sim", "--perception", "points", option, "0", "-o", str(tmp_path / "r.mcap"))
    assert result.returncode == 2
    assert f"{option} must be positive" in one_line(result) and "inf for no limit" in one_line(result)
    assert not (tmp_path / "r.mcap").exists()
    config = tmp_path / "gains.toml"
    config.write_text("[limits]\nmax_v = 0.0\n")
    result = call_hbvs("repeat", str(FIT), "--sim", "--config", str(config), "-o", str(tmp_path / "r.mcap"))
    assert result.returncode == 2 and "--max-v must be positive" in one_line(result)


def test_a_replay_applies_the_actuator_limits_and_its_report_says_so(tmp_path):
    run = tmp_path / "replay.mcap"
    result = call_hbvs("repeat", str(FIT), "--replay", str(TEACH), "--max-v", "0.05", "--max-w", "0.04", "-o", str(run), "-q")
    assert result.returncode == 0, result.stderr
    report = json.loads(call_hbvs("report", str(run), "--json").stdout)
    commands = report["commands"]
    assert commands["v_peak_mps"] <= 0.05 + 1e-12 and commands["w_peak_radps"] <= 0.04 + 1e-12
    assert commands["limits"] == {"max_v": 0.05, "max_w": 0.04, "max_accel": None}
    # The law asked for more than the limits (the sample drive runs at 0.2 m/s): the
    # report counts the clipped steps, not zero.
    assert commands["saturated_fraction"] > 0.5


# ----------------------------------------------------------------------------- the sweep's parameters
def test_every_sweep_parameter_has_the_bounds_of_the_repeat_option_it_sets():
    from hbvs_cli.settings.commands import REPEAT
    from hbvs_cli.sweep.spec import PARAMETERS

    own = {"offset_x", "offset_y", "offset_theta", "dhat0_factor", "occlusion_start", "occlusion_length"}
    for name, parameter in PARAMETERS.items():
        if name in own:
            assert parameter.own
            continue
        # The very declaration of the option, not a copy of it.
        assert not parameter.own and parameter.setting is REPEAT[name]
        for value in (REPEAT[name].bounds.get("min"), REPEAT[name].bounds.get("max")):
            if value is not None:
                assert parameter.bound_violation(value) is None
                step = 10 ** -9 * max(1.0, abs(value)) if parameter.kind == "float" else 1
                outside = value - step if value == REPEAT[name].bounds.get("min") else value + step
                assert parameter.bound_violation(outside) == REPEAT[name].violation(outside) is not None


@pytest.mark.parametrize("vary, option, value", [
    ("drop_rate=1.5,0.1", "--drop-rate", "1.5"),
    ("rate=0.05,30", "--rate", "0.05"),
    ("latency=1e19,1e20", "--latency", "10000000000000000000"),
    ("dhat0=1e-300,1", "--dhat0", "1e-300"),
    ("k_v=-1,1", "--kv", "-1"),
    ("speed=0.0001,1", "--speed", "0.0001"),
])
def test_a_value_repeat_refuses_the_sweep_refuses_with_the_same_message_before_running(tmp_path, vary, option, value):
    repeat = call_hbvs("repeat", str(FIT), "--sim", "--perception", "points", f"{option}={value}", "-o", str(tmp_path / "r.mcap"))
    sweep = call_hbvs("sweep", str(FIT), "--vary", vary, "-o", str(tmp_path / "sweep"), "--no-plots")
    assert sweep.returncode == repeat.returncode != 0
    repeat_message = re.sub(r" \(see 'hbvs repeat -h'\)$", "", one_line(repeat)).removeprefix("hbvs: error: ")
    assert repeat_message in one_line(sweep)
    assert not (tmp_path / "sweep").exists()  # refused before the results folder was made


# ----------------------------------------------------------------------------- 7. sizes, paths, kept files
@pytest.mark.parametrize("arguments", [
    ["--vary", "k_v=0.1:1:1000000000"],
    ["--vary", "k_v=0.1:1", "--sampling", "sobol", "--samples", "1000000000"],
    ["--vary", "k_v=0.1,1", "--repeats", "1000000000"],
    ["--vary", "k_v=0.1:1:1000", "--vary", "k_w=0.1:1:1000", "--vary", "gamma=1:2:1000"],
])
def test_sweep_sizes_are_bounded_before_anything_is_allocated(tmp_path, arguments):
    result = call_hbvs("sweep", str(FIT), *arguments, "-o", str(tmp_path / "sweep"))
    assert result.returncode == 7
    assert "sweep-runs limit" in one_line(result) and "hbvs --limit sweep-runs=N" in one_line(result)


def test_a_spec_file_grid_of_a_billion_steps_is_refused_by_the_limit(tmp_path):
    spec = tmp_path / "spec.toml"
    spec.write_text("[vary]\nk_v = {from = 0.1, to = 1.0, steps = 1000000000}\n")
    result = call_hbvs("sweep", str(FIT), "--spec", str(spec), "-o", str(tmp_path / "sweep"))
    assert result.returncode == 7 and "sweep-runs" in one_line(result)


def test_a_relative_output_folder_reaches_the_workers_as_an_absolute_path(tmp_path, monkeypatch):
    from hbvs_cli.stages.sweep import SweepOptions, prepare

    monkeypatch.chdir(tmp_path)
    plan, spec, table, tasks = prepare(SweepOptions(fit=str(FIT), output=Path("relative"), vary=["k_v=0.5,1"], keep_runs="all"))
    try:
        keep = Path(tasks.task(0).keep_path)
        assert keep.is_absolute() and keep == tmp_path / "relative" / "runs" / "run-000000.mcap"
    finally:
        table.release()


def test_a_kept_run_file_is_whole_or_absent_and_the_temporary_folder_goes(tmp_path, monkeypatch):
    import errno

    from hbvs_cli.stages import sweep_run as runner

    source = tmp_path / "run.mcap"
    source.write_bytes(os.urandom(3 << 20))
    kept = tmp_path / "results" / "runs" / "run-000001.mcap"
    runner.keep_file(str(source), str(kept))
    assert kept.read_bytes() == source.read_bytes()

    def full_disk(reader, writer, length):
        writer.write(reader.read(1000))
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(runner.shutil, "copyfileobj", full_disk)
    other = kept.with_name("run-000002.mcap")
    with pytest.raises(OSError):
        runner.keep_file(str(source), str(other))
    assert not other.exists() and sorted(p.name for p in kept.parent.iterdir()) == ["run-000001.mcap"]
    # A run whose file cannot be kept: its row says so, and its temporary folder is gone.
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    monkeypatch.setattr(runner.tempfile, "tempdir", str(scratch))
    task = runner.RunTask(fit_path=str(FIT), index=2, point=2, repeat=0, seed=1, values={},
                          arguments={"sim": True, "seed": 1, "perception": "points"}, command="hbvs repeat",
                          keep_path=str(other), keep="all")
    row = runner.execute_run(task)
    assert row["status"] == "ok" and row["run_file"] is None and "run file not kept" in row["error"]
    assert list(scratch.iterdir()) == []


# ----------------------------------------------------------------------------- 1. the sweep's folder
@pytest.fixture(scope="module")
def small_sweep(tmp_path_factory):
    """A finished 2-run sweep (points with 1 px of noise, one worker), made once for the tests
    below (from this process: tests/test_sweep.py runs sweeps as their own processes)."""
    folder = tmp_path_factory.mktemp("sweep") / "results"
    result = call_hbvs("sweep", str(FIT), "--vary", "offset_y=-0.1,0.1", "--set", "perception=points", "--set", "pixel_noise=1",
                       "-o", str(folder), "--workers", "1", "--no-plots", "--quiet")
    assert result.returncode == 0, result.stderr
    return folder


def copy_of(folder: Path, tmp_path: Path) -> Path:
    target = tmp_path / "results"
    shutil.copytree(folder, target)
    return target


def test_a_second_sweep_into_a_locked_folder_stops_with_one_line_and_exit_6(small_sweep, tmp_path):
    from hbvs_cli.io.output_target import FolderLock
    from hbvs_cli.io.sweep_table import LOCK

    folder = copy_of(small_sweep, tmp_path)
    before = digest_tree(folder)
    with FolderLock(folder / LOCK, "test"):
        result = call_hbvs("sweep", str(FIT), "--vary", "offset_y=-0.1,0.1", "--set", "perception=points", "--set", "pixel_noise=1", "-o", str(folder), "--no-plots")
    assert result.returncode == 6
    assert f"(pid {os.getpid()})" in one_line(result) and "another hbvs process" in one_line(result)
    assert digest_tree(folder) == before


@pytest.mark.campaign
def test_two_sweeps_started_together_into_one_folder_leave_one_whole_table(request, tmp_path):
    campaign_extent(request, "campaign")
    import pyarrow.parquet as pq

    for round_ in range(3):
        folder = tmp_path / f"results-{round_}"
        command = [*HBVS, "sweep", str(FIT), "--vary", "offset_y=-0.1:0.1:4", "--set", "perception=points", "-o", str(folder),
                   "--workers", "1", "--no-plots", "--quiet"]
        children = [subprocess.Popen(command, stderr=subprocess.PIPE) for _ in range(2)]
        outcomes = sorted((child.wait(timeout=600), child.stderr.read().decode()) for child in children)
        # One ran; the other stopped at the lock (or, started after the first ended, found it done).
        assert outcomes[0][0] == 0 and outcomes[1][0] in (0, 6), outcomes
        if outcomes[1][0] == 6:
            assert "another hbvs process" in outcomes[1][1]
        table = pq.read_table(folder / "runs.parquet")
        assert table.column("index").to_pylist() == [0, 1, 2, 3]
        assert [p.name for p in folder.rglob("*.partial")] == []


def test_a_sweep_removes_only_the_partial_files_of_dead_processes(small_sweep, tmp_path):
    folder = copy_of(small_sweep, tmp_path)
    stale = folder / f"runs.csv.{dead_pid()}-0badc0de.partial"
    alive = folder / f"runs.csv.{os.getpid()}-feedf00d.partial"
    someone = folder / "parts" / "notes.partial"
    for path in (stale, alive, someone):
        path.write_text("x")
    result = call_hbvs("sweep", str(FIT), "--vary", "offset_y=-0.1,0.1", "--set", "perception=points", "--set", "pixel_noise=1", "-o", str(folder), "--no-plots", "--json")
    assert result.returncode == 0, result.stderr
    assert not stale.exists() and alive.exists() and someone.exists()
    assert json.loads(result.stdout)["runs"]["done"] == 2


def test_a_part_never_replaces_another(tmp_path):
    import pyarrow as pa
    import pyarrow.parquet as pq

    from hbvs_cli.io import sweep_table as results

    schema = pa.schema([pa.field("index", pa.int64()), pa.field("status", pa.string())])
    table = results.ResultsTable(tmp_path / "sweep", schema, {"spec": 1}, flush_rows=1, flush_seconds=1e9)
    try:
        # Another writer's part under the number this one would take next.
        taken = tmp_path / "sweep" / results.PARTS / "part-000001.parquet"
        pq.write_table(pa.Table.from_pylist([{"index": 99, "status": "theirs"}], schema=schema), taken)
        table.append({"index": 0, "status": "ok"})
        assert pq.read_table(taken).column("status").to_pylist() == ["theirs"]
        parts = sorted(p.name for p in (tmp_path / "sweep" / results.PARTS).iterdir())
        assert parts == ["part-000001.parquet", "part-000002.parquet"]
    finally:
        table.release()


@pytest.mark.parametrize("content", ["[1, 2, 3]", "{}", '{"fingerprint": 1}', "not json", "null"])
def test_a_broken_sweep_json_is_an_input_error(small_sweep, tmp_path, content):
    folder = copy_of(small_sweep, tmp_path)
    (folder / "sweep.json").write_text(content)
    for arguments in (("sweep", str(FIT), "--vary", "offset_y=-0.1,0.1", "-o", str(folder)), ("report", str(folder))):
        result = call_hbvs(*arguments)
        assert result.returncode == 3, result.stderr
        assert "sweep.json" in one_line(result)


def test_a_results_table_of_another_sweep_is_an_input_error(small_sweep, tmp_path):
    import pyarrow as pa
    import pyarrow.parquet as pq

    folder = copy_of(small_sweep, tmp_path)
    pq.write_table(pa.table({"index": [0, 1], "k_v": [0.5, 1.0], "status": ["ok", "ok"]}), folder / "runs.parquet")
    result = call_hbvs("report", str(folder))
    assert result.returncode == 3 and "another sweep" in one_line(result)
    result = call_hbvs("sweep", str(FIT), "--vary", "offset_y=-0.1,0.1", "--set", "perception=points", "--set", "pixel_noise=1", "-o", str(folder), "--no-plots")
    assert result.returncode == 3 and "another sweep" in one_line(result)


def test_an_output_folder_that_is_a_dangling_link_is_refused(tmp_path):
    (tmp_path / "results").symlink_to(tmp_path / "missing" / "results")
    result = call_hbvs("sweep", str(FIT), "--vary", "k_v=0.5,1", "-o", str(tmp_path / "results"))
    assert result.returncode == 6 and "does not exist" in one_line(result)


@pytest.mark.parametrize("address", ["not a url", "foo://x:1", "tcp://:"])
def test_a_scheduler_address_that_is_not_one_is_a_usage_error(tmp_path, address):
    result = call_hbvs("sweep", str(FIT), "--vary", "k_v=0.5,1", "-o", str(tmp_path / "s"), "--scheduler", address)
    assert result.returncode == 2 and "--scheduler" in one_line(result)
    assert not (tmp_path / "s").exists()


# ----------------------------------------------------------------------------- 6. report RESULTS/
def test_report_of_a_sweep_gates_on_convergence_and_takes_a_label(small_sweep):
    # With 1 px of pixel noise the two runs of the sample fit end about 1 cm off: not converged (report's verdict).
    result = call_hbvs("report", str(small_sweep), "--require-converged", "--label", "nightly")
    assert result.returncode == 1
    assert "not converged: 2 of 2 runs of the sweep" in result.stderr.decode()
    assert result.stdout.decode().splitlines()[0].startswith("sweep nightly: 2 of 2 runs")
    summary = json.loads(call_hbvs("report", str(small_sweep), "--json", "--label", "nightly").stdout)
    assert summary["label"] == "nightly" and summary["folder"] == str(small_sweep)
    assert call_hbvs("report", str(small_sweep)).returncode == 0  # no gate asked for
    result = call_hbvs("report", str(small_sweep), "--label", "a", "--label", "b")
    assert result.returncode == 2 and "--label" in one_line(result)


# ----------------------------------------------------------------------------- 5. the dashboard
def test_the_dashboard_address_is_loopback_unless_a_host_is_named():
    from hbvs_cli.errors import UsageError
    from hbvs_cli.sweep.engine import dashboard_address

    assert dashboard_address(None) is None
    assert dashboard_address("8787") == "127.0.0.1:8787"
    assert dashboard_address("0.0.0.0:8787") == "0.0.0.0:8787"
    for bad in ("", "x", "127.0.0.1:99999", "http://h:1/x"):
        with pytest.raises(UsageError):
            dashboard_address(bad)


def test_without_dashboard_the_scheduler_serves_its_health_check_alone_on_loopback():
    pytest.importorskip("distributed")
    import urllib.error
    import urllib.request

    from hbvs_cli.sweep.engine import dask_client

    with dask_client(None, None, 1) as client:
        sockets = client.run_on_scheduler(_http_sockets)
        assert sockets and all(host == "127.0.0.1" for host, _ in sockets)
        host, port = sockets[0]
        assert urllib.request.urlopen(f"http://{host}:{port}/health", timeout=10).status == 200
        for page in ("/status", "/info/main/workers.html", "/proxy/8787/127.0.0.1/status"):
            with pytest.raises(urllib.error.HTTPError) as info:
                urllib.request.urlopen(f"http://{host}:{port}{page}", timeout=10)
            assert info.value.code == 404


def _http_sockets(dask_scheduler=None):
    return [tuple(s.getsockname()[:2]) for s in dask_scheduler.http_server._sockets.values()]


# ----------------------------------------------------------------------------- 2. export
@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    folder = tmp_path_factory.mktemp("export")
    bag = folder / "bag"
    result = call_hbvs("export", str(TEACH), "-o", str(bag), "-q")
    assert result.returncode == 0, result.stderr
    return bag


def test_export_marks_its_bags_and_replaces_only_those(exported, tmp_path):
    from hbvs_cli.io.ros_export import written_by_hbvs

    assert written_by_hbvs(exported)
    project = tmp_path / "paper"
    project.mkdir()
    (project / "metadata.yaml").write_text("title: my paper\n")
    (project / "paper.tex").write_text("\\documentclass{article}\n")
    bag_like = tmp_path / "bag_like"
    shutil.copytree(exported, bag_like)
    (bag_like / "notes.txt").write_text("mine")  # a bag with a file it does not list
    foreign = tmp_path / "foreign"
    shutil.copytree(exported, foreign)
    text = (foreign / "metadata.yaml").read_text().replace("hbvs_export: '1'", "recorder: ros2")
    (foreign / "metadata.yaml").write_text(text)  # a bag another tool wrote
    for folder in (project, bag_like, foreign):
        before = digest_tree(folder)
        result = call_hbvs("export", str(TEACH), "-o", str(folder), "-q")
        assert result.returncode == 2 and "not a ROS 2 bag written by hbvs export" in one_line(result)
        assert digest_tree(folder) == before
    again = tmp_path / "again"
    shutil.copytree(exported, again)
    assert call_hbvs("export", str(TEACH), "-o", str(again), "-q").returncode == 0


def test_export_refuses_an_input_stored_inside_the_bag(exported, tmp_path):
    bag = tmp_path / "bag"
    shutil.copytree(exported, bag)
    shutil.copy(TEACH, bag / "teach.mcap")
    result = call_hbvs("export", str(bag / "teach.mcap"), "-o", str(bag), "-q")
    assert result.returncode == 2 and "inside the bag" in one_line(result)
    assert (bag / "teach.mcap").read_bytes() == TEACH.read_bytes()


def test_a_truncated_input_does_not_replace_a_bag_unless_allowed(exported, tmp_path):
    bag = tmp_path / "bag"
    shutil.copytree(exported, bag)
    before = digest_tree(bag)
    from hbvs_cli.io.mcap import McapStream, McapWriter

    # The sample in 64 KB chunks (it is one chunk as hbvs writes it), cut in the middle.
    rechunked = tmp_path / "teach-small-chunks.mcap"
    stream = McapStream(TEACH)
    with open(rechunked, "wb") as handle:
        writer = McapWriter(handle, chunk_size=64 * 1024)
        for k, message in enumerate(stream):
            if k == 0:
                for name, values in stream.metadata.items():
                    writer._writer.add_metadata(name, values)
            copy_message(writer, message)
        writer.finish()
    truncated = tmp_path / "teach-cut.mcap"
    truncated.write_bytes(rechunked.read_bytes()[: rechunked.stat().st_size // 2])
    result = call_hbvs("export", str(truncated), "-o", str(bag), "-q")
    assert result.returncode == 3 and "--allow-truncated" in one_line(result)
    assert digest_tree(bag) == before
    result = call_hbvs("export", str(truncated), "-o", str(bag), "--allow-truncated", "-q")
    assert result.returncode == 0 and digest_tree(bag) != before
    assert [p.name for p in tmp_path.iterdir() if p.name.endswith(".partial")] == []


@SUITE_OR_CAMPAIGN
def test_exports_to_one_bag_at_once_all_succeed_and_leave_one_whole_bag(request, extent, exported, tmp_path):
    full = campaign_extent(request, extent)
    bag = tmp_path / "bag"
    for _ in range(3 if full else 1):
        children = [subprocess.Popen([*HBVS, "export", str(TEACH), "-o", str(bag), "-q"], stderr=subprocess.PIPE)
                    for _ in range(4 if full else 2)]
        outcomes = [(child.wait(timeout=300), child.stderr.read().decode()) for child in children]
        assert all(code == 0 for code, _ in outcomes), outcomes
        assert sorted(p.name for p in bag.iterdir()) == sorted(p.name for p in exported.iterdir())
        assert (bag / "bag.mcap").read_bytes() == (exported / "bag.mcap").read_bytes()
        assert [p.name for p in tmp_path.iterdir()] == ["bag"]  # no partial folder, no lock file


def test_export_removes_the_partial_folders_of_killed_exports_and_no_other(tmp_path):
    stale = tmp_path / f"bag.{dead_pid()}-0badc0de.partial"
    alive = tmp_path / f"bag.{os.getpid()}-feedf00d.partial"
    recovery = tmp_path / "bag.partial"
    for folder in (stale, alive, recovery):
        (folder / "bag").mkdir(parents=True)
        (folder / "bag" / "bag.mcap").write_bytes(b"x" * 1000)
    result = call_hbvs("export", str(TEACH), "-o", str(tmp_path / "bag"), "-q")
    assert result.returncode == 0, result.stderr
    assert not stale.exists() and alive.exists() and recovery.exists()


# ----------------------------------------------------------------------------- 3. the live view
def test_a_server_that_never_stops_does_not_hold_the_process(monkeypatch, tmp_path):
    foxglove = pytest.importorskip("foxglove")
    from hbvs_cli.io import live_view

    never = threading.Event()

    class StuckServer:
        port = 1

        def stop(self):  # what the SDK's stop did with a client that stopped reading
            never.wait()

    monkeypatch.setattr(foxglove, "start_server", lambda **kwargs: StuckServer())
    announced = []
    with live_view.live_writer(0, 0.0, announced.append):
        assert "ws://127.0.0.1:1 " in announced[0]  # the StuckServer's port
    # Out of the block: the stop was given up on; its thread is a daemon.
    stuck = [t for t in threading.enumerate() if t.name == "hbvs-live-stop"]
    assert stuck and all(t.daemon for t in stuck)
    assert live_view.stop_within(lambda: None, 1.0) is True
    never.set()


@pytest.mark.parametrize("speed", ["1e-300", "1e-4", "1e300", "-1", "nan"])
def test_a_live_speed_out_of_range_is_a_usage_error(tmp_path, speed):
    pytest.importorskip("foxglove")
    result = call_hbvs("repeat", str(FIT), "--sim", "--foxglove", "0", "--foxglove-speed", speed, "-o", str(tmp_path / "r.mcap"))
    assert result.returncode == 2 and "--foxglove-speed" in one_line(result)
    assert not (tmp_path / "r.mcap").exists()


# ----------------------------------------------------------------------------- 4. small hostile files
def alias_bomb(levels: int = 9, width: int = 9) -> str:
    lines = ["a0: &a0 [" + ", ".join(["1"] * width) + "]"]
    for level in range(1, levels):
        lines.append(f"a{level}: &a{level} [" + ", ".join([f"*a{level - 1}"] * width) + "]")
    return "\n".join(lines) + "\n"


def test_a_calibration_alias_bomb_is_refused_before_it_is_shown(tmp_path):
    calibration = tmp_path / "camera.yaml"
    calibration.write_text(alias_bomb() + "image_width: 640\nimage_height: 480\ncamera_matrix: {rows: 3, cols: 3, data: *a8}\n")
    assert calibration.stat().st_size < 2000
    from hbvs_cli.errors import CalibrationError
    from hbvs_cli.io.calibration import load_calibration

    with pytest.raises(CalibrationError, match="alias bomb"):
        load_calibration(calibration)


@pytest.fixture(scope="module")
def bag_metadata(exported):
    return (exported / "metadata.yaml").read_text()


@pytest.mark.parametrize("change, expected", [
    (lambda text: text.replace("  message_count: 1002\n", "  message_count: many\n", 1), "message_count must be a whole number"),
    (lambda text: alias_bomb() + text.replace("ros_distro: rosbags", "ros_distro: *a8"), "alias bomb"),
    (lambda text: text.replace("ros_distro: rosbags", "ros_distro: [1, 2]"), "ros_distro"),
])
def test_a_hostile_bag_metadata_is_one_line_and_exit_3(exported, tmp_path, change, expected):
    bag = tmp_path / "bag"
    shutil.copytree(exported, bag)
    (bag / "metadata.yaml").write_text(change((bag / "metadata.yaml").read_text()))
    result = call_hbvs("teach", "--bag", str(bag), "-o", str(tmp_path / "t.mcap"), "-q")
    assert result.returncode == 3, result.stderr
    assert expected in one_line(result) and len(one_line(result)) < 400


def test_yaml_aliases_are_counted_without_being_expanded():
    from hbvs_cli.errors import InputError
    from hbvs_cli.io.limits import load_yaml_documents

    assert load_yaml_documents("a: &x [1, 2]\nb: *x\n---\nc: 3\n", "f") == [{"a": [1, 2], "b": [1, 2]}, {"c": 3}]
    with pytest.raises(InputError, match=r"in a\d expand"):
        load_yaml_documents(alias_bomb(), "f")  # 9^9 values: counted, never built
    with pytest.raises(InputError, match="alias bomb"):
        load_yaml_documents("a: &x [*x]\n", "f")  # an alias inside itself


# ----------------------------------------------------------------------------- 8. closed stdin
@pytest.mark.parametrize("arguments", [
    ["fit", "-", "-o", "f.mcap"],
    pytest.param(["repeat", "-", "--sim", "-o", "r.mcap"], marks=pytest.mark.campaign),
    pytest.param(["report", "-"], marks=pytest.mark.campaign),
    ["export", "-", "-o", "bag"],
])
def test_a_stage_started_with_stdin_closed_says_so(request, tmp_path, arguments):
    # One process each (a second of CPU): fit and export in the suite, all four with -m campaign.
    if request.node.get_closest_marker("campaign"):
        campaign_extent(request, "campaign")
    result = subprocess.run([*HBVS, *arguments], cwd=tmp_path, capture_output=True, timeout=120,
                            preexec_fn=lambda: os.close(0))
    assert result.returncode == 3
    assert "stdin: it is closed" in one_line(result)
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------- 11. the campaign
def pick(rng: np.random.Generator, options: list):
    """One of ``options`` (any objects), seeded."""
    return options[int(rng.integers(len(options)))]


def _hostile_attempts(rng: np.random.Generator, folder: Path, count: int, sweep_folder: Path, bag: Path) -> list[dict]:
    """``count`` seeded attempts at the new surfaces, as a careless or hostile user makes them."""
    names = ["k_v", "k_w", "gamma", "k_2", "dhat0", "dhat0_factor", "rate", "speed", "latency", "drop_rate", "outlier_rate",
             "pixel_noise", "lost_timeout", "occlusion_start", "occlusion_length", "law", "perception", "nosuch"]
    numbers = ["0", "-1", "1e-300", "1e300", "1e19", "nan", "inf", "-inf", "0.05", "1.5", "30", "0.5", "abc", "", "1e9"]
    attempts: list[dict] = []
    for index in range(count):
        kind = ["vary", "grid", "spec", "sweep_json", "export_folder", "calibration", "metadata", "live_speed", "stdin",
                "dashboard", "scheduler"][index % 11]
        work = folder / f"attempt-{index:03d}"
        work.mkdir()
        guarded: list[Path] = []
        stdin_closed = False
        if kind == "vary":
            values = ",".join(pick(rng, numbers) for _ in range(int(rng.integers(1, 4))))
            arguments = ["sweep", str(FIT), "--vary", f"{pick(rng, names)}={values}", "-o", str(work / "s"), "--no-plots",
                         "--workers", "1", "--set", "perception=points", "--set", "lost_timeout=0.01", "--set", "drop_rate=1"]
        elif kind == "grid":
            low, high = pick(rng, numbers), pick(rng, numbers)
            steps = str(int(10 ** rng.uniform(5, 12)))
            arguments = ["sweep", str(FIT), "--vary", f"{pick(rng, names)}={low}:{high}:{steps}", "-o", str(work / "s")]
        elif kind == "spec":
            spec = work / "spec.toml"
            spec.write_text(pick(rng, [
                "[vary]\nk_v = {from = 0.1, to = 1.0, steps = 1000000000}\n",
                "samples = 1000000000\nsampling = 'sobol'\n[vary]\nkv = {from = 0.1, to = 1.0}\n",
                "[vary]\nrate = [0.01, 1e300]\n", "[vary]\nlatency = [1e19]\n", "vary = 3\n", "[fixed]\nmax_v = 0\n",
                "repeats = 1e9\n[vary]\nkv=[1]\n", "= broken toml",
            ]))
            arguments = ["sweep", str(FIT), "--spec", str(spec), "-o", str(work / "s")]
        elif kind == "sweep_json":
            results = work / "results"
            shutil.copytree(sweep_folder, results)
            (results / "sweep.json").write_text(pick(rng, ["[1,2,3]", "{}", "null", '{"fingerprint": {}, "schema": 5}', "\x00\xff",
                                                            '{"fingerprint": {"spec": {"vary": [], "fixed": {}}}, "schema": {}}']))
            guarded.append(results)
            arguments = ["report", str(results)] if rng.random() < 0.5 else [
                "sweep", str(FIT), "--vary", "offset_y=-0.1,0.1", "--set", "perception=points", "-o", str(results), "--no-plots"]
        elif kind == "export_folder":
            target = work / "target"
            target.mkdir()
            (target / "metadata.yaml").write_text(pick(rng, ["rosbag2_bagfile_information: {}\n", "title: x\n", alias_bomb(),
                                                              (bag / "metadata.yaml").read_text()]))
            (target / pick(rng, ["paper.tex", "bag.mcap", "data.db3"])).write_bytes(os.urandom(int(rng.integers(10, 5000))))
            guarded.append(target)
            arguments = ["export", str(TEACH), "-o", str(target), "-q"]
        elif kind == "calibration":
            calibration = work / "camera.yaml"
            levels, width = int(rng.integers(3, 12)), int(rng.integers(3, 12))
            key = pick(rng, ["camera_matrix", "distortion_coefficients", "image_width", "distortion_model"])
            calibration.write_text(alias_bomb(levels, width) + f"image_width: 640\nimage_height: 480\n{key}: *a{levels - 1}\n")
            arguments = ["teach", "--images", str(work), "--calibration", str(calibration), "-o", str(work / "t.mcap")]
        elif kind == "metadata":
            copy = work / "bag"
            shutil.copytree(bag, copy)
            text = (copy / "metadata.yaml").read_text()
            text = pick(rng, [
                text.replace("  message_count: 1002\n", "  message_count: many\n", 1),
                alias_bomb(int(rng.integers(5, 12)), 9) + text.replace("ros_distro: rosbags", "ros_distro: *a4"),
                text.replace("ros_distro: rosbags", "ros_distro: " + "x" * 5000),
                text.replace("relative_file_paths:", "relative_file_paths: 7\nold_paths:"),
                text[: int(rng.integers(0, len(text)))],
            ])
            (copy / "metadata.yaml").write_text(text)
            arguments = ["teach", "--bag", str(copy), "-o", str(work / "t.mcap"), "-q"]
        elif kind == "live_speed":
            arguments = ["repeat", str(FIT), "--sim", "--perception", "points", "--foxglove", "0",
                         "--foxglove-speed", pick(rng, ["1e-300", "-1", "nan", "1e300", "1e-9"]), "-o", str(work / "r.mcap")]
        elif kind == "stdin":
            stdin_closed = True
            arguments = pick(rng, [["fit", "-", "-o", str(work / "f.mcap")], ["repeat", "-", "--sim", "-o", str(work / "r.mcap")],
                                    ["report", "-"], ["export", "-", "-o", str(work / "bag")]])
        elif kind == "dashboard":
            arguments = ["sweep", str(FIT), "--vary", "k_v=0.5,1", "--dashboard", pick(rng, ["x", "99999", "h:p", ":"]),
                         "-o", str(work / "s")]
        else:
            arguments = ["sweep", str(FIT), "--vary", "k_v=0.5,1", "--scheduler",
                         pick(rng, ["not a url", "foo://x:1", "tcp://:", "inproc://x", "tcp://[::1"]), "-o", str(work / "s")]
        attempts.append({"kind": kind, "arguments": [str(a) for a in arguments], "guarded": guarded, "stdin_closed": stdin_closed,
                         "work": work})
    return attempts


@SUITE_OR_CAMPAIGN
def test_adversarial_campaign_over_the_new_surfaces(request, extent, tmp_path, small_sweep, exported):
    """>= 100 seeded attempts (sweep, export, live view, bag and calibration inputs): no exit
    70, no file lost or corrupted, peak memory under 300 MB for inputs under 1 MB."""
    full = campaign_extent(request, extent)
    count = 110 if full else 2
    rng = np.random.default_rng(2026_11_26)
    attempts = _hostile_attempts(rng, tmp_path, count, small_sweep, exported)
    peaks, codes = [], {}
    for attempt in attempts:
        before = {folder: digest_tree(folder) for folder in attempt["guarded"]}
        code, stderr, peak = _run_in_child(attempt["arguments"], attempt["stdin_closed"], attempt["work"])
        codes[code] = codes.get(code, 0) + 1
        peaks.append(peak)
        assert code not in (70, -9), (attempt["kind"], attempt["arguments"], stderr)
        assert code == 0 or len([line for line in stderr.splitlines() if line.startswith("hbvs: error")]) == 1, (attempt["arguments"], stderr)
        assert "Traceback" not in stderr
        for folder, digest in before.items():
            if attempt["kind"] == "export_folder" and code == 0:
                continue  # a bag hbvs wrote, replaced as asked
            assert digest_tree(folder) == digest, (attempt["arguments"], "a guarded folder changed")
        assert peak < 300 * 2**20, (attempt["arguments"], peak)
    print(f"campaign: {len(attempts)} attempts, exit codes {dict(sorted(codes.items()))}, "
          f"peak memory max {max(peaks) / 2**20:.0f} MB, median {np.median(peaks) / 2**20:.0f} MB")


def _run_in_child(arguments: list[str], stdin_closed: bool, cwd: Path) -> tuple[int, str, int]:
    """Run hbvs in a child and return its exit code, stderr and its own peak RSS (bytes)."""
    import tempfile

    with tempfile.TemporaryFile() as errors:
        code, peak = run_with_peak_memory([*HBVS, *arguments], cwd, errors, dict(os.environ, MPLBACKEND="Agg"),
                                          close_stdin=stdin_closed, timeout=300)
        errors.seek(0)
        return code, errors.read().decode(errors="replace"), peak


def zstd_of_zeros(megabytes: int) -> bytes:
    """A zstd frame of ``megabytes`` MiB of zeros, a few KB long (made in 1 MiB steps)."""
    zstd = pytest.importorskip("backports.zstd") if sys.version_info < (3, 14) else pytest.importorskip("compression.zstd")
    compressor = zstd.ZstdCompressor()
    block = bytes(1 << 20)
    return b"".join([compressor.compress(block) for _ in range(megabytes)] + [compressor.flush()])


def compressed_bag(folder: Path, mode: str) -> Path:
    """A one-image ROS 2 bag, message-compressed (SQLite) or file-compressed (MCAP)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    types = store.types
    message = types["sensor_msgs/msg/CompressedImage"](
        header=types["std_msgs/msg/Header"](stamp=types["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id="c"),
        format="jpeg", data=np.frombuffer(b"\xff\xd8" * 10, dtype=np.uint8))
    plugin = StoragePlugin.SQLITE3 if mode == "message" else StoragePlugin.MCAP
    writer = Writer(folder, version=8, storage_plugin=plugin)
    writer.set_compression(CompressionMode.MESSAGE if mode == "message" else CompressionMode.FILE, CompressionFormat.ZSTD)
    writer.open()
    connection = writer.add_connection("/camera/image/compressed", "sensor_msgs/msg/CompressedImage", typestore=store)
    writer.write(connection, 0, store.serialize_cdr(message, "sensor_msgs/msg/CompressedImage"))
    writer.close()
    return folder


def test_a_message_compressed_bag_bomb_stops_at_the_message_cap(tmp_path):
    import sqlite3

    bag = compressed_bag(tmp_path / "bag", "message")
    database = next(bag.glob("*.db3"))
    with sqlite3.connect(database) as connection:
        connection.execute("update messages set data = ?", (zstd_of_zeros(100),))  # 100 MiB in ~4 KB
    assert database.stat().st_size < 1 << 20
    result = call_hbvs("teach", "--bag", str(bag), "-o", str(tmp_path / "t.mcap"), "-q")
    assert result.returncode == 3 and "expands to more than the 64 MiB" in one_line(result)


def test_a_file_compressed_bag_bomb_stops_at_the_decompressed_bytes_limit(tmp_path, monkeypatch):
    bag = compressed_bag(tmp_path / "bag", "file")
    next(bag.glob("*.zstd")).write_bytes(zstd_of_zeros(40))
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    result = run_hbvs("--limit", "decompressed-bytes=1e7", "teach", "--bag", str(bag), "-o", str(tmp_path / "t.mcap"), "-q",
                      env={"TMPDIR": str(scratch)})
    assert result.returncode == 7 and "decompressed-bytes limit" in one_line(result)
    assert list(scratch.iterdir()) == []  # the decompressed file went with the error


@pytest.mark.parametrize("address", ["0:18792", "*:18794", "[::]:18793", "[::1]:18799", "::18795", "18798:18798"])
def test_a_dashboard_on_every_interface_or_ipv6_is_refused_before_anything_is_written(address, tmp_path):
    """Hostile spellings of --dashboard (issue 46): "0" and "*" would listen on 0.0.0.0 though
    nobody named it, IPv6 forms and an all-digit host failed after the results folder and its
    lock were made. Each is a usage error (exit 2, one line) and nothing is written."""
    pytest.importorskip("distributed")
    results = tmp_path / "results"
    result = call_hbvs("sweep", str(SAMPLES / "fit.mcap"), "--vary", "offset_y=-0.1:0.1:2", "--dashboard", address,
                       "-o", str(results), "--quiet")
    assert result.returncode == 2 and "--dashboard" in one_line(result)
    assert not results.exists() and list(tmp_path.iterdir()) == []
