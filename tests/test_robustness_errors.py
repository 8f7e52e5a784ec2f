"""Every error is one line and a documented exit code; every size is bounded before allocating.

Through the command line, as a user runs it: a reader that closes the pipe (141), stdout
or stderr closed, a full disk and devices (6; only as root, in a private mount namespace
on a tmpfs, never the real ``/dev``), option values and file contents that used to end in
"internal error" (70; all but the first of these in this process, through the same
parsing and mapping of errors), native logging and numpy warnings, typer's usage errors, and the
size limits (7), whose peak memory is measured with ``resource`` (``os.wait4``) and must
stay under 300 MB (one case as its own ``hbvs`` process, the others one after another in
a second process, whose peak bounds each of theirs).
"""

from __future__ import annotations

import json
import os
import shutil
import stat
import struct
import subprocess
import sys
import textwrap
import zlib
from pathlib import Path

import pytest
import zstandard

from conftest import REPO, call_hbvs, run_with_peak_memory
from oracles import copy_message
from test_robustness_hostile import MAGIC, channel, footer, header, message, record, schema, string
from test_robustness_outputs import PRECIOUS, hbvs, one_line, snapshot

#: Peak resident memory (MB) any hostile file or option may cost.
MAX_PEAK_MB = 300


@pytest.fixture(scope="module")
def files(tmp_path_factory, small_recordings):
    """A 2 s teach, its fit, a run (conftest's small_recordings), and hostile variants of
    them (made once)."""
    folder = tmp_path_factory.mktemp("errors")
    for name in ("t.mcap", "f.mcap", "r.mcap"):
        shutil.copyfile(small_recordings / name, folder / name)
    from hbvs_cli.io.foxglove_scene import SIMULATION_EPOCH_NS  # where a simulated teach's clock starts

    rewrite(folder / "t.mcap", folder / "late.mcap", lambda topic, t, m: (t - SIMULATION_EPOCH_NS + 2**64 - 10**10, m))
    rewrite(folder / "t.mcap", folder / "fast.mcap", set_speed)
    rewrite(folder / "f.mcap", folder / "huge-spline.mcap", huge_coefficients)
    rewrite(folder / "f.mcap", folder / "long.mcap", long_trajectory)
    (folder / "bomb.mcap").write_bytes(message_bomb(messages=1_100_000, chunks=1))
    (folder / "bombs.mcap").write_bytes(message_bomb(messages=200_000, chunks=3))
    return folder


@pytest.fixture
def work(files, tmp_path):
    for entry in files.iterdir():
        shutil.copyfile(entry, tmp_path / entry.name)
    return tmp_path


# ----------------------------------------------------------------------------- hostile files
def rewrite(source: Path, target: Path, change) -> None:
    """Copy an hbvs MCAP file, passing every message through ``change(topic, log_time, msg)``."""
    from hbvs_cli.io.mcap import McapStream, McapWriter

    stream = McapStream(source)
    messages = list(stream)
    with open(target, "wb") as handle:
        writer = McapWriter(handle)
        for name, values in stream.metadata.items():
            writer._writer.add_metadata(name, dict(values))
        for m in messages:
            if m.message_encoding != "json":  # foxglove messages (protobuf): copied as they are, retimed
                log_time, _ = change(m.topic, m.log_time, None)
                copy_message(writer, m, log_time)
                continue
            log_time, payload = change(m.topic, m.log_time, json.loads(m.data))
            copy_message(writer, m, log_time, json.dumps(payload).encode())
        writer.finish()


def set_speed(topic, log_time, payload):
    if topic == "/teach/cmd_vel":
        payload["v"] = 1e308
    return log_time, payload


def huge_coefficients(topic, log_time, payload):
    if topic == "/fit/model":
        for spline in payload["trajectory"]["channels"].values():
            spline["coefficients"] = [1e308] * len(spline["coefficients"])
    return log_time, payload


def long_trajectory(topic, log_time, payload):
    """A fit whose trajectory claims to last 3e5 s (repeat used to allocate 4.5 GB)."""
    if topic == "/fit/model":
        payload["trajectory"]["t_end"] = 3e5
    return log_time, payload


def message_bomb(messages: int, chunks: int) -> bytes:
    """Zstd chunks of empty messages on a topic nobody reads: a few KB that hold millions."""
    records = schema(1, "hbvs.VelocityCommand") + channel(1, 1, "/other") + message(1, b"") * messages
    packed = zstandard.ZstdCompressor(level=3).compress(records)
    body = struct.pack("<QQQI", 0, 0, len(records), zlib.crc32(records)) + string("zstd") + struct.pack("<Q", len(packed)) + packed
    return MAGIC + header() + record(0x06, body) * chunks + footer()


# ----------------------------------------------------------------------------- measured runs
def measured(folder: Path, *args: str) -> tuple[int, str, float]:
    """Run ``hbvs ARGS``; exit code, stderr and the peak resident memory in MB (wait4)."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    with open(folder / "stderr.txt", "wb") as err:
        code, peak = run_with_peak_memory([sys.executable, "-m", "hbvs_cli", *args], folder, err, env)
    return code, (folder / "stderr.txt").read_text(), peak / 2**20


LIMIT_CASES = {
    "a chunk of 1.1 million empty messages (fit)": (["fit", "bomb.mcap", "-o", "x.mcap"], "chunk-messages"),
    "a chunk of 1.1 million empty messages (report)": (["report", "bomb.mcap"], "chunk-messages"),
    "a chunk of 1.1 million empty messages (repeat)": (["repeat", "bomb.mcap", "--sim", "-o", "x.mcap"], "chunk-messages"),
    "messages per file": (["--limit", "messages=300000", "fit", "bombs.mcap", "-o", "x.mcap"], "messages"),
    "decompressed bytes per file": (["--limit", "input-bytes=1000000", "fit", "t.mcap", "-o", "x.mcap"], "input-bytes"),
    "a fit lasting 3e5 s": (["repeat", "long.mcap", "--sim", "-o", "x.mcap"], "steps"),
    "--rate 1e6": (["repeat", "f.mcap", "--sim", "--rate", "1e6", "-o", "x.mcap"], "steps"),
    "--speed 1e-6": (["repeat", "f.mcap", "--sim", "--speed", "1e-6", "-o", "x.mcap"], "steps"),
    "teach --fps 1e6": (["teach", "--sim", "--fps", "1e6", "-o", "x.mcap"], "steps"),
}


#: The case run as its own ``hbvs`` process; the others share one process (:data:`BATCH`).
ALONE = "a chunk of 1.1 million empty messages (fit)"

#: Runs ``hbvs`` commands one after another in one process, each through the command
#: line's own parsing and mapping of errors (conftest's ``call_hbvs``), and writes their exit
#: codes and stderr as JSON. argv: the JSON file to write, the commands ({name: args}) as
#: JSON, the tests' folder.
BATCH = """
import json, sys
sys.path.insert(0, sys.argv[3])
from conftest import call_hbvs
from hbvs_cli.io import limits
results = {}
for name, args in json.loads(sys.argv[2]).items():
    limits.set_limits([f"{n}={limit.default}" for n, limit in limits.LIMITS.items()])  # a command's --limit is its own
    result = call_hbvs(*args)
    results[name] = [result.returncode, result.stderr.decode()]
with open(sys.argv[1], "w") as handle:
    json.dump(results, handle)
"""


@pytest.fixture(scope="module")
def limit_batch(files, tmp_path_factory):
    """Every size case but :data:`ALONE` in one process: a new process for each cost a
    second of CPU in imports alone. A process's peak memory is at least the peak of each
    command it ran, so the one peak bounds them all."""
    work = tmp_path_factory.mktemp("limits")
    for entry in files.iterdir():
        shutil.copyfile(entry, work / entry.name)
    before = snapshot(work)
    report = tmp_path_factory.mktemp("limits-report") / "results.json"
    cases = {case: args for case, (args, _) in LIMIT_CASES.items() if case != ALONE}
    env = dict(os.environ, PYTHONPATH=str(REPO))
    with open(report.with_name("stderr.txt"), "wb") as err:
        code, peak = run_with_peak_memory([sys.executable, "-c", BATCH, str(report), json.dumps(cases), str(REPO / "tests")],
                                          work, err, env)
    assert code == 0, report.with_name("stderr.txt").read_text()
    return json.loads(report.read_text()), peak / 2**20, before, snapshot(work)


@pytest.mark.parametrize("case", list(LIMIT_CASES))
def test_hostile_sizes_stop_at_a_named_limit_under_300_mb(files, tmp_path, request, case):
    args, limit = LIMIT_CASES[case]
    if case == ALONE:  # as a user runs it
        work = tmp_path
        for entry in files.iterdir():
            shutil.copyfile(entry, work / entry.name)
        before = snapshot(work)
        code, stderr, peak_mb = measured(work, *args)
        after = snapshot(work)
        after.pop("stderr.txt"), before.pop("stderr.txt", None)
    else:
        results, peak_mb, before, after = request.getfixturevalue("limit_batch")
        code, stderr = results[case]
    assert code == 7, stderr
    assert stderr.count("\n") == 1 and "Traceback" not in stderr
    assert f"the {limit} limit" in stderr and f"hbvs --limit {limit}=N" in stderr
    assert peak_mb < MAX_PEAK_MB, f"{case}: {peak_mb:.0f} MB"
    assert after == before


def reset_limits(limits) -> None:
    """Every limit back to its default, as a new process has them."""
    limits.set_limits([f"{name}={limit.default}" for name, limit in limits.LIMITS.items()])


def test_a_raised_limit_lets_the_same_input_through(work, monkeypatch):
    """``--limit`` raises a limit: the steps of --rate 100 over 2 s pass once allowed (in
    this process: the limits go back to their defaults after)."""
    from hbvs_cli.io import limits

    monkeypatch.chdir(work)
    try:
        result = call_hbvs("--limit", "steps=100", "repeat", "f.mcap", "--sim", "--perception", "points", "--rate", "100", "-o", "x.mcap", "-q")
        assert result.returncode == 7 and "the steps limit of 100 steps" in result.stderr.decode()
        reset_limits(limits)
        result = call_hbvs("--limit", "steps=1000", "repeat", "f.mcap", "--sim", "--perception", "points", "--rate", "100", "-o", "x.mcap", "-q")
        assert result.returncode == 0, result.stderr
    finally:
        reset_limits(limits)


def test_a_limit_must_be_a_whole_number():
    """``--limit steps=1.5`` is refused (its message asks for a whole number; it used to become
    1); ``5e6`` is a whole number written short."""
    from hbvs_cli.errors import UsageError
    from hbvs_cli.io import limits

    try:
        for text in ("steps=1.5", "messages=2.000001", "steps=0", "steps=inf"):
            with pytest.raises(UsageError, match="whole number"):
                limits.set_limits([text])
        limits.set_limits(["messages=5e6", "steps=1000"])
        assert limits.current("messages") == 5_000_000 and limits.current("steps") == 1000
    finally:
        reset_limits(limits)
    result = call_hbvs("--limit", "steps=1.5", "info", "nothing.mcap")
    assert result.returncode == 2 and "whole number" in one_line(result)


@pytest.mark.campaign
def test_the_default_per_file_message_limit(work, request):
    """Thirty chunks of 200 000 messages: stopped at 4 194 304 (``-m campaign``, ~30 s)."""
    if "campaign" not in (request.config.option.markexpr or ""):
        pytest.skip("runs with: pytest -m campaign tests/test_robustness_errors.py")
    (work / "many.mcap").write_bytes(message_bomb(messages=200_000, chunks=30))
    code, stderr, peak_mb = measured(work, "fit", "many.mcap", "-o", "x.mcap")
    assert code == 7 and "the messages limit of 4194304" in stderr and peak_mb < MAX_PEAK_MB


# ----------------------------------------------------------------------------- values
VALUE_CASES = {
    "teach --duration inf": (["teach", "--sim", "--duration", "inf", "-o", "x.mcap"], 2),
    "teach --fps inf": (["teach", "--sim", "--fps", "inf", "-o", "x.mcap"], 2),
    # The sources trust --fps: a video's or an image folder's rate of 0 is refused here.
    "teach --images --fps 0": (["teach", "--images", ".", "--fps", "0", "-o", "x.mcap"], 2),
    "teach --blur 1e6": (["teach", "--sim", "--blur", "1e6", "-o", "x.mcap"], 2),
    "teach --seed -1": (["teach", "--sim", "--seed", "-1", "-o", "x.mcap"], 2),
    "repeat --seed -1": (["repeat", "f.mcap", "--sim", "--seed", "-1", "-o", "x.mcap"], 2),
    "repeat --rate nan": (["repeat", "f.mcap", "--sim", "--rate", "nan", "-o", "x.mcap"], 2),
    "repeat --depth -1": (["repeat", "f.mcap", "--sim", "--depth", "-1", "-o", "x.mcap"], 2),
    "repeat --speed 0": (["repeat", "f.mcap", "--sim", "--speed", "0", "-o", "x.mcap"], 2),
    "fit --smoothing 1e308": (["fit", "t.mcap", "--smoothing", "1e308", "-o", "x.mcap"], 2),
    "fit --target-size 0": (["fit", "t.mcap", "--target-size", "0", "-o", "x.mcap"], 2),
    "an unknown option": (["teach", "--bogus"], 2),
    "an unknown limit": (["--limit", "memory=1", "teach"], 2),
    "teach log times near 2^64": (["fit", "late.mcap", "-o", "x.mcap"], 3),
    "spline coefficients of 1e308": (["repeat", "huge-spline.mcap", "--sim", "-o", "x.mcap"], 3),
    "a teach driving at 1e308 m/s": (["fit", "fast.mcap", "-o", "f.mcap"], 3),
}


def error_line(result) -> str:
    """The one error line; the 2 s teach's fit also warns that its short drive leaves the
    plane's normal ambiguous and uncertain, warnings that come before the error and are not
    part of it."""
    text = result.stderr.decode()
    lines = [line for line in text.splitlines() if not line.startswith("hbvs: warning: ")]
    assert "Traceback" not in text and len(lines) == 1, text
    return lines[0]


@pytest.mark.parametrize("case", list(VALUE_CASES))
def test_values_that_were_internal_errors_are_one_line_with_their_code(work, case, monkeypatch):
    args, code = VALUE_CASES[case]
    before = snapshot(work)
    args = [*args, "-q"] if args[0] in ("teach", "fit", "repeat") else list(args)
    # The first case as a user runs it; the others in this process, through the same
    # parsing and mapping of errors to exit codes (a new process costs half a second).
    if case == next(iter(VALUE_CASES)):
        result = hbvs(work, *args)
    else:
        monkeypatch.chdir(work)
        result = call_hbvs(*args)
    assert result.returncode == code, result.stderr
    line = error_line(result)
    assert "internal error" not in line
    assert snapshot(work) == before  # nothing written, the earlier f.mcap kept


def test_fit_refuses_a_model_repeat_would_refuse_before_writing(work, monkeypatch):
    monkeypatch.chdir(work)
    result = call_hbvs("fit", "fast.mcap", "-o", "f.mcap", "-q")
    assert result.returncode == 3
    assert "repeat could not use" in error_line(result) and "dhat0" in result.stderr.decode()


# ----------------------------------------------------------------------------- pipes, stdio
PIPE_CASES = {
    "teach -o -": ["teach", "--sim", "--duration", "0.3", "-o", "-", "-q"],
    "fit -o -": ["fit", "t.mcap", "-o", "-", "-q"],
    "repeat -o -": ["repeat", "f.mcap", "--sim", "--perception", "points", "-o", "-", "-q"],
    "repeat --cmd-out -": ["repeat", "f.mcap", "--sim", "--perception", "points", "--cmd-out", "-", "-o", "x.mcap", "-q"],
    "report": ["report", "r.mcap"],
    "report --json": ["report", "r.mcap", "--json"],
    "--help": ["--help"],
    "info": ["info", "r.mcap"],
}


@pytest.mark.parametrize("case", list(PIPE_CASES))
def test_a_reader_that_closed_the_pipe_gives_exit_141_and_says_nothing(work, case):
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader is gone before the first byte (as `| head -c 0`)
    env = dict(os.environ, PYTHONPATH=str(REPO))
    try:
        result = subprocess.run([sys.executable, "-m", "hbvs_cli", *PIPE_CASES[case]], cwd=work, stdout=write_end,
                                stderr=subprocess.PIPE, timeout=300, env=env)
    finally:
        os.close(write_end)
    assert result.returncode == 141, result.stderr
    # As a process SIGPIPE ends: the reader left, nothing went wrong here (a stage's own warnings stay).
    assert not [line for line in result.stderr.decode().splitlines() if "error" in line or "pipe" in line], result.stderr
    assert not list(work.glob("*.partial")) and not (work / "x.mcap").exists()


def shell_pipeline(work, stages: list[str]) -> tuple[list[int], list[str]]:
    """``hbvs A | hbvs B | ...`` in bash: each stage's exit code, and the lines on stderr."""
    hbvs_command = f"{sys.executable} -m hbvs_cli"
    line = " | ".join(f"{hbvs_command} {stage}" for stage in stages) + ' ; echo "${PIPESTATUS[@]}" >&3'
    codes_read, codes_write = os.pipe()
    env = dict(os.environ, PYTHONPATH=str(REPO))
    try:
        result = subprocess.run(["bash", "-c", f"exec 3>&{codes_write}; {line}"], cwd=work, capture_output=True, timeout=300,
                                env=env, pass_fds=(codes_write,))
    finally:
        os.close(codes_write)
    with os.fdopen(codes_read) as codes:
        return [int(code) for code in codes.read().split()], result.stderr.decode().splitlines()


def test_a_failed_pipeline_says_one_line_and_the_later_stages_exit_9_quietly(work):
    """The first stage's error is the only line; the stages after it see an empty pipe and
    exit 9 without a word (README, "Exit codes")."""
    codes, lines = shell_pipeline(work, ["fit missing.mcap -o -", "repeat - --sim -o -", "report -"])
    assert codes == [3, 9, 9]
    assert lines == ["hbvs: error: missing.mcap: no such file"]
    # A stage that fails later, after its input: its own line, the next stage quiet.
    codes, lines = shell_pipeline(work, ["repeat f.mcap --sim --perception points -o - --dhat0 -1", "report -"])
    assert codes == [2, 9] and len(lines) == 1 and lines[0].startswith("hbvs: error:")
    # Empty input from a file (not a pipe) is still an error that says so.
    empty = work / "empty.mcap"
    empty.write_bytes(b"")
    with open(empty, "rb") as stdin:
        result = subprocess.run([sys.executable, "-m", "hbvs_cli", "info", "-"], stdin=stdin, capture_output=True, cwd=work,
                                env=dict(os.environ, PYTHONPATH=str(REPO)), timeout=60)
    assert result.returncode == 3 and "empty" in one_line(result)


def test_info_into_head_is_silent(work):
    hbvs_command = f"{sys.executable} -m hbvs_cli"
    result = subprocess.run(["bash", "-c", f'{hbvs_command} info r.mcap | head -1; echo "${{PIPESTATUS[0]}}" >&2'], cwd=work,
                            capture_output=True, timeout=120, env=dict(os.environ, PYTHONPATH=str(REPO)))
    assert result.stdout.decode().startswith("file ") and len(result.stdout.decode().splitlines()) == 1
    assert result.stderr.decode().split() in (["0"], ["141"])


def closed(folder: Path, redirect: str, *args: str):
    env = dict(os.environ, PYTHONPATH=str(REPO))
    return subprocess.run(["sh", "-c", f'exec "$@" {redirect}', "sh", sys.executable, "-m", "hbvs_cli", *args],
                          cwd=folder, capture_output=True, timeout=300, env=env)


def test_a_closed_stdout_is_an_output_error_not_a_traceback(work):
    for args in (["teach", "--sim", "--duration", "0.3", "-o", "-", "-q"], ["report", "r.mcap"], ["--help"]):
        result = closed(work, ">&-", *args)
        assert result.returncode == 6, (args, result.stderr)
        assert "stdout" in one_line(result) and "closed" in result.stderr.decode()


def test_a_closed_stdout_does_not_hand_its_descriptor_to_an_output_file(work):
    result = closed(work, ">&-", "repeat", "f.mcap", "--sim", "--perception", "points", "-o", "run.mcap")
    assert result.returncode == 0, result.stderr
    assert (work / "run.mcap").read_bytes() == (work / "r.mcap").read_bytes()


def test_a_closed_stderr_still_gives_the_exit_code(work):
    assert closed(work, "2>&-", "fit", "missing.mcap", "-o", "x.mcap").returncode == 3


# ----------------------------------------------------------------------------- native logging
def test_broken_images_are_one_line_without_libpng_or_opencv_logging(work):
    import cv2
    import numpy as np

    image = (np.random.default_rng(7).random((240, 320)) * 255).astype(np.uint8)
    png = bytearray(cv2.imencode(".png", image)[1].tobytes())
    at = png.find(b"IDAT")
    length = struct.unpack(">I", png[at - 4:at])[0]
    for k in range(at + 104, at + 164):  # damage the compressed data, keep the CRC right
        png[k] ^= 0x5A
    png[at + 4 + length: at + 8 + length] = struct.pack(">I", zlib.crc32(bytes(png[at: at + 4 + length])))
    tiff = cv2.imencode(".tiff", image)[1].tobytes()
    calibration = REPO / "samples" / "camera.yaml"
    for name, data, said in (("bad.png", bytes(png), "IDAT: incorrect data check"), ("bad.tiff", tiff[: len(tiff) // 3], "TIFFReadDirectory")):
        folder = work / name.replace(".", "_")
        folder.mkdir()
        (folder / name).write_bytes(data)
        result = hbvs(work, "teach", "--images", str(folder), "--calibration", str(calibration), "-o", "x.mcap", "-q")
        assert result.returncode == 3
        line = one_line(result)
        # What the library said is captured and quoted in our one line, without OpenCV's log prefix.
        assert "cannot be decoded" in line and said in line and "[ERROR" not in line
        # --debug shows what the native libraries said (the logging is only hidden).
        debug = hbvs(work, "--debug", "teach", "--images", str(folder), "--calibration", str(calibration), "-o", "x.mcap", "-q")
        assert b"libpng" in debug.stderr or b"TIFF" in debug.stderr


def test_numpy_warnings_and_native_stderr_never_reach_the_terminal(tmp_path):
    script = textwrap.dedent("""
        import os
        import numpy as np
        from hbvs_cli.cli import app as cli
        from hbvs_cli.errors import InputError

        @cli.app.command("noisy")
        def noisy():
            np.log(np.array([-1.0, 0.0]))               # RuntimeWarnings
            np.array([np.nan]).mean(axis=0) / 0.0
            os.write(2, b"libpng error: IDAT: incorrect data check\\n")   # native code writes to fd 2
            raise InputError("frame.png: cannot be decoded as an image")

        cli.main(["noisy"])
    """)
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, timeout=120,
                            env=dict(os.environ, PYTHONPATH=str(REPO)))
    assert result.returncode == 3
    assert result.stderr.decode() == "hbvs: error: frame.png: cannot be decoded as an image\n"


# ----------------------------------------------------------------------------- devices, full disk
DEVICE_DRIVER = textwrap.dedent("""
    import json, os, subprocess, sys
    work, dev, small = sys.argv[1], sys.argv[2], sys.argv[3]
    subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", dev], check=True)
    subprocess.run(["mount", "-t", "tmpfs", "-o", "size=8k", "tmpfs", small], check=True)
    os.mknod(os.path.join(dev, "null"), 0o666 | 0o020000, os.makedev(1, 3))
    os.mknod(os.path.join(dev, "full"), 0o666 | 0o020000, os.makedev(1, 7))
    with open(os.path.join(small, "out.mcap"), "wb") as handle:
        handle.write(sys.argv[4].encode())
    # Files named on the command line in this process (conftest's call_hbvs: the command
    # line's parsing and mapping of errors, without a new process's imports); stdout onto
    # the device as a process of its own.
    sys.path.insert(0, sys.argv[5])
    from conftest import call_hbvs
    os.chdir(work)
    def run(args):
        result = call_hbvs(*args)
        return {"code": result.returncode, "stderr": result.stderr.decode()}
    def run_process(args, stdout):
        result = subprocess.run([sys.executable, "-m", "hbvs_cli", *args], stdout=stdout, stderr=subprocess.PIPE)
        return {"code": result.returncode, "stderr": result.stderr.decode()}
    repeat = ["repeat", "f.mcap", "--sim", "--perception", "points", "-q"]
    outcome = {
        "null": run(repeat + ["-o", os.path.join(dev, "null")]),
        "full": run(repeat + ["-o", os.path.join(dev, "full")]),
        "cmd_full": run(repeat + ["-o", "new.mcap", "--cmd-out", os.path.join(dev, "full")]),
        "report_full": run_process(["report", "r.mcap", "--json"], stdout=open(os.path.join(dev, "full"), "wb")),
        "disk_full": run(repeat + ["-o", os.path.join(small, "out.mcap")]),
    }
    kinds = {name: oct(os.lstat(os.path.join(dev, name)).st_mode) for name in ("null", "full")}
    with open(os.path.join(small, "out.mcap"), "rb") as handle:
        kept = handle.read().decode(errors="replace")
    print(json.dumps({"outcome": outcome, "kinds": kinds, "kept": kept, "left": sorted(os.listdir(small))}))
""")


@pytest.mark.skipif(os.geteuid() != 0 or shutil.which("unshare") is None, reason="devices only as root, in a private mount namespace")
def test_devices_and_a_full_disk_in_a_private_mount_namespace(work):
    dev, small = work / "dev", work / "small"
    dev.mkdir(), small.mkdir()
    env = dict(os.environ, PYTHONPATH=str(REPO))
    result = subprocess.run(["unshare", "-m", "--propagation", "private", sys.executable, "-c", DEVICE_DRIVER,
                             str(work), str(dev), str(small), PRECIOUS.decode(), str(REPO / "tests")],
                            capture_output=True, timeout=600, env=env)
    if result.returncode != 0 and b"unshare" in result.stderr:
        pytest.skip(f"no private mount namespace here: {result.stderr.decode().strip()}")
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    outcome = report["outcome"]
    # -o onto a device writes into it, in place: exit 0, still a character device.
    assert outcome["null"] == {"code": 0, "stderr": ""}
    assert all(stat.S_ISCHR(int(mode, 8)) for mode in report["kinds"].values())
    # /dev/full: one line, "no space left", exit 6, for -o, --cmd-out and stdout alike.
    for name in ("full", "cmd_full", "report_full", "disk_full"):
        assert outcome[name]["code"] == 6, (name, outcome[name])
        assert outcome[name]["stderr"].count("\n") == 1 and "no space left" in outcome[name]["stderr"].lower()
    # A full disk keeps the earlier output and leaves no partial file.
    assert report["kept"] == PRECIOUS.decode() and report["left"] == ["out.mcap"]
    assert not (work / "new.mcap").exists()
