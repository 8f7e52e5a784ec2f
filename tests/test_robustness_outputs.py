"""Nothing a user points hbvs at is ever lost: outputs, concurrent runs, truncated stdin.

Every case runs through the command line: as a user runs it (``python -m hbvs_cli``) where
stdin, stdout or the process matter, the others in this process through
``conftest.call_hbvs`` (the same parsing, stages and mapping of errors). Each checks the
exit code, that stderr holds exactly one line (and no traceback), and that the inputs and
any earlier good output are byte-identical afterwards. FIFO cases use ``mkfifo``
in a temporary folder; device and full-disk cases run only as root, inside a private
mount namespace (``unshare -m``) on a tmpfs with ``mknod``: never the real ``/dev``.
"""

from __future__ import annotations

import json
import os
import shutil
import stat
import subprocess
import sys
import threading
from pathlib import Path
from types import SimpleNamespace

import pytest

from conftest import REPO, call_hbvs

PRECIOUS = b"a good output from an earlier run, which hbvs must never lose\n"


# ----------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def files(small_recordings):
    """A 2 s teach, its fit and a run (perception points): small, made once (conftest)."""
    return small_recordings


@pytest.fixture
def work(files, tmp_path):
    """A fresh folder holding copies of t.mcap, f.mcap, r.mcap."""
    for name in ("t.mcap", "f.mcap", "r.mcap"):
        shutil.copyfile(files / name, tmp_path / name)
    return tmp_path


def snapshot(folder: Path) -> dict[str, bytes | str]:
    """Every entry of a folder: file bytes, or what a link points to, or the kind."""
    state: dict[str, bytes | str] = {}
    for entry in sorted(folder.iterdir()):
        if entry.is_symlink():
            state[entry.name] = "-> " + os.readlink(entry)
        elif entry.is_file():
            state[entry.name] = entry.read_bytes()
        else:
            state[entry.name] = f"mode {stat.S_IFMT(entry.lstat().st_mode):o}"
    return state


def one_line(result) -> str:
    text = result.stderr.decode(errors="replace")
    assert "Traceback" not in text, text
    assert text.count("\n") == 1 and text.endswith("\n"), f"expected one line on stderr, got {text!r}"
    return text.strip()


def hbvs(folder: Path, *args: str, **kwargs):
    """``hbvs ARGS`` run in ``folder``."""
    env = kwargs.pop("env", None)
    full_env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    full_env.update(env or {})
    return subprocess.run([sys.executable, "-m", "hbvs_cli", *args], cwd=folder, capture_output=True,
                          timeout=300, env=full_env, **kwargs)


def in_folder(folder: Path, *args: str, input: bytes | None = None):
    """``hbvs ARGS`` run in ``folder``, in this process (``conftest.call_hbvs``), reading
    ``input`` as its stdin."""
    here = os.getcwd()
    os.chdir(folder)
    try:
        return call_hbvs(*args, input=input)
    finally:
        os.chdir(here)


def valid_mcap(path: Path) -> int:
    """Messages in a complete MCAP file, read by the official mcap reader."""
    from mcap.reader import make_reader

    with open(path, "rb") as handle:
        reader = make_reader(handle)
        assert reader.get_summary() is not None
        return sum(1 for _ in reader.iter_messages())


def commands_in(run: Path) -> int:
    from hbvs_cli.io.mcap import McapStream

    return sum(1 for _ in McapStream(run, topics={"/repeat/cmd_vel"}))


# ----------------------------------------------------------------------------- same file
SAME_FILE_CASES = {
    "fit onto its input": (["fit", "t.mcap", "-o", "t.mcap"], None),
    "repeat onto its fit": (["repeat", "f.mcap", "--sim", "-o", "f.mcap"], None),
    "--cmd-out onto the fit": (["repeat", "f.mcap", "--sim", "--cmd-out", "f.mcap", "-o", "new.mcap"], None),
    "--cmd-out and -o one file": (["repeat", "f.mcap", "--sim", "--cmd-out", "r.mcap", "-o", "r.mcap"], None),
    "--plot onto the report's input": (["report", "run.png", "--plot", "run.png"], "png"),
    "fit of a .partial onto its final name": (["fit", "rec.mcap.123-0badc0de.partial", "-o", "rec.mcap"], "partial"),
    "replay of a .partial onto its final name": (["repeat", "f.mcap", "--replay", "rec.mcap.123-0badc0de.partial", "-o", "rec.mcap"], "partial"),
    "fit onto a symlink to its input": (["fit", "t.mcap", "-o", "alias.mcap"], "symlink"),
    "fit onto a hard link of its input": (["fit", "t.mcap", "-o", "hard.mcap"], "hardlink"),
    "--export-tum onto the run": (["report", "r.mcap", "--export-tum", "tum"], "tum"),
}


@pytest.mark.parametrize("case", list(SAME_FILE_CASES))
def test_an_output_that_is_an_input_is_refused_before_anything_is_opened(work, case, monkeypatch):
    """In this process (``call_hbvs``, the same parsing and mapping of errors): what is
    checked is the paths, not the process around them (stdout redirected into an input,
    below, is a real process)."""
    args, setup = SAME_FILE_CASES[case]
    if setup == "png":
        (work / "run.png").write_bytes(b"\x89PNG\r\n\x1a\n" + PRECIOUS)
    elif setup == "partial":
        shutil.copyfile(work / "t.mcap", work / "rec.mcap.123-0badc0de.partial")
    elif setup == "symlink":
        (work / "alias.mcap").symlink_to("t.mcap")
    elif setup == "hardlink":
        os.link(work / "t.mcap", work / "hard.mcap")
    elif setup == "tum":
        (work / "tum").mkdir()
        os.link(work / "r.mcap", work / "tum" / "r.taught.tum")
    before = snapshot(work)
    tum_before = snapshot(work / "tum") if setup == "tum" else None
    monkeypatch.chdir(work)
    result = call_hbvs(*args)
    assert result.returncode == 2, result.stderr
    line = one_line(result)
    assert "same file" in line or "belongs to" in line
    assert snapshot(work) == before
    if tum_before is not None:
        assert snapshot(work / "tum") == tum_before


def test_stdout_redirected_into_the_input_is_refused(work):
    before = (work / "t.mcap").read_bytes()
    with open(work / "t.mcap", "ab") as appended:
        result = subprocess.run([sys.executable, "-m", "hbvs_cli", "fit", "t.mcap", "-o", "-"], cwd=work,
                                stdout=appended, stderr=subprocess.PIPE, timeout=300)
    assert result.returncode == 2
    assert "stdout is the same file as the input" in one_line(result)
    assert (work / "t.mcap").read_bytes() == before


# ----------------------------------------------------------------------------- links, FIFOs
def test_a_symlink_output_keeps_the_link_and_replaces_its_target(work, monkeypatch):
    (work / "old.mcap").write_bytes(PRECIOUS)
    (work / "link.mcap").symlink_to("old.mcap")
    monkeypatch.chdir(work)
    result = call_hbvs("repeat", "f.mcap", "--sim", "--perception", "points", "-o", "link.mcap", "-q")
    assert result.returncode == 0, result.stderr
    assert (work / "link.mcap").is_symlink() and os.readlink(work / "link.mcap") == "old.mcap"
    assert (work / "old.mcap").read_bytes() == (work / "r.mcap").read_bytes()  # the same run, deterministic
    assert not list(work.glob("*.partial"))


def test_a_fifo_output_is_written_in_place_for_its_reader(work, monkeypatch):
    fifo = work / "pipe.mcap"
    os.mkfifo(fifo)
    received = {}

    def read() -> None:
        with open(fifo, "rb") as handle:
            received["data"] = handle.read()

    reader = threading.Thread(target=read)
    reader.start()
    monkeypatch.chdir(work)
    result = call_hbvs("repeat", "f.mcap", "--sim", "--perception", "points", "-o", "pipe.mcap", "-q")
    reader.join(60)
    assert result.returncode == 0, result.stderr
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert received["data"] == (work / "r.mcap").read_bytes()
    assert not list(work.glob("*.partial"))


def test_a_fifo_command_stream_is_written_in_place(work, monkeypatch):
    fifo = work / "cmd.fifo"
    os.mkfifo(fifo)
    received = {}

    def read() -> None:
        with open(fifo, "rb") as handle:
            received["data"] = handle.read()

    reader = threading.Thread(target=read)
    reader.start()
    monkeypatch.chdir(work)
    result = call_hbvs("repeat", "f.mcap", "--sim", "--perception", "points", "-o", "run2.mcap", "--cmd-out", "cmd.fifo", "-q")
    reader.join(60)
    assert result.returncode == 0, result.stderr
    lines = received["data"].decode().splitlines()
    assert len(lines) == commands_in(work / "run2.mcap") > 0 and {"t", "v", "w"} <= set(json.loads(lines[-1]))
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)


def test_dev_stdout_is_written_in_place_not_replaced(work):
    """``-o /dev/stdout`` (a symbolic link to the process's own descriptor 1, here a pipe)."""
    result = hbvs(work, "repeat", "f.mcap", "--sim", "--perception", "points", "-o", "/dev/stdout", "-q")
    assert result.returncode == 0, result.stderr
    assert result.stdout == (work / "r.mcap").read_bytes()
    assert os.path.islink("/dev/stdout")


# ----------------------------------------------------------------------------- --cmd-out
def test_cmd_out_is_atomic_a_failed_run_keeps_the_earlier_file(work, monkeypatch):
    (work / "cmd.jsonl").write_bytes(PRECIOUS)
    (work / "broken.mcap").write_bytes(b"not an mcap file at all")
    before = snapshot(work)
    monkeypatch.chdir(work)
    result = call_hbvs("repeat", "f.mcap", "--replay", "broken.mcap", "--cmd-out", "cmd.jsonl", "-o", "run2.mcap", "-q")
    assert result.returncode == 3
    one_line(result)
    assert snapshot(work) == before
    ok = call_hbvs("repeat", "f.mcap", "--sim", "--perception", "points", "--cmd-out", "cmd.jsonl", "-o", "run2.mcap", "-q")
    assert ok.returncode == 0, ok.stderr
    assert len((work / "cmd.jsonl").read_text().splitlines()) == commands_in(work / "run2.mcap") > 0


# ----------------------------------------------------------------------------- truncated stdin
def test_a_truncated_stdin_does_not_replace_an_existing_output(work):
    data = (work / "t.mcap").read_bytes()
    cut = data[: len(data) * 6 // 10]  # the writer upstream died: no summary, no footer
    (work / "out.mcap").write_bytes(PRECIOUS)
    before = snapshot(work)
    refused = in_folder(work, "fit", "-", "-o", "out.mcap", "-q", input=cut)
    assert refused.returncode == 3
    assert "--allow-truncated" in one_line(refused)
    assert snapshot(work) == before
    # A new output is still written (recovery keeps working), with a warning.
    fresh = in_folder(work, "fit", "-", "-o", "new.mcap", "-q", input=cut)
    assert fresh.returncode == 0 and "ends before its end record" in fresh.stderr.decode()
    assert valid_mcap(work / "new.mcap") > 0
    # And --allow-truncated replaces the existing one.
    allowed = in_folder(work, "fit", "-", "-o", "out.mcap", "-q", "--allow-truncated", input=cut)
    assert allowed.returncode == 0
    assert valid_mcap(work / "out.mcap") == valid_mcap(work / "new.mcap")  # (the settings record the flag)


def test_a_truncated_fit_on_stdin_leaves_the_earlier_run(work):
    data = (work / "f.mcap").read_bytes()
    before = snapshot(work)
    # Cut in the summary: the model is complete, the end record missing.
    refused = in_folder(work, "repeat", "-", "--sim", "--perception", "points", "-o", "r.mcap", "-q", input=data[:-100])
    assert refused.returncode == 3
    assert "--allow-truncated" in one_line(refused)
    # Cut in half: no model at all.
    half = in_folder(work, "repeat", "-", "--sim", "--perception", "points", "-o", "r.mcap", "-q", input=data[: len(data) // 2])
    assert half.returncode == 3
    one_line(half)
    assert snapshot(work) == before


def test_a_write_error_is_an_output_error_with_exit_6(tmp_path, monkeypatch):
    """ENOSPC while writing (no root needed): exit code 6, the earlier file kept, no partial."""
    import errno

    from hbvs_cli.errors import OutputError
    from hbvs_cli.io import output_target
    from hbvs_cli.io.mcap import open_output

    class FillsUp:
        """A file that takes ``room`` bytes, then fails as a full disk does."""

        def __init__(self, raw, room: int) -> None:
            self.raw, self.room = raw, room

        def write(self, data):
            self.room -= len(data)
            if self.room < 0:
                raise OSError(errno.ENOSPC, "No space left on device")
            return self.raw.write(data)

        def __getattr__(self, name):
            return getattr(self.raw, name)

    def write_some(target, **kwargs):
        with open_output(target, chunk_size=64, **kwargs) as writer:
            for k in range(100):
                writer.write("/teach/cmd_vel", "hbvs.VelocityCommand", k, {"timestamp": {"sec": 0, "nsec": k}, "v": 0.0, "w": 0.0})

    with pytest.raises(OutputError) as stdout_full:
        with monkeypatch.context() as patched:
            patched.setattr(sys, "stdout", SimpleNamespace(buffer=FillsUp(open(os.devnull, "wb"), 0)))
            write_some("-")
    assert stdout_full.value.exit_code == 6 and "stdout: cannot write (no space left on the device)" in str(stdout_full.value)
    target = tmp_path / "out.mcap"
    target.write_bytes(PRECIOUS)
    real_fdopen = os.fdopen
    monkeypatch.setattr(output_target.os, "fdopen", lambda fd, *a, **k: FillsUp(real_fdopen(fd, *a, **k), 1000))
    with pytest.raises(OutputError) as disk_full:
        write_some(target)
    assert disk_full.value.exit_code == 6 and "an earlier file of that name is left as it was" in str(disk_full.value)
    assert target.read_bytes() == PRECIOUS and sorted(p.name for p in tmp_path.iterdir()) == ["out.mcap"]


# ----------------------------------------------------------------------------- concurrent runs
#: A writer process that writes ``target`` once per line read from stdin ("ok" or "fail"),
#: answering with its exit code for that round: 0, or 3 when it failed at message 300 (a
#: SystemExit raised inside open_output, as when the process exits there). The two writers
#: live through all the rounds: forty Python start-ups were most of the test's time.
WRITER = r"""
import sys, time
from hbvs_cli.io.mcap import open_output
target, ident = sys.argv[1], int(sys.argv[2])
for order in sys.stdin:
    fail = order.strip() == "fail"
    try:
        with open_output(target, chunk_size=4096) as writer:
            for k in range(400):
                writer.write("/teach/cmd_vel", "hbvs.VelocityCommand", k, {"timestamp": {"sec": 0, "nsec": k}, "v": float(ident), "w": float(k)})
                if k % 50 == 0:
                    writer.flush()
                    time.sleep(0.002)
                if fail and k == 300:
                    raise SystemExit(3)
        code = 0
    except SystemExit as exc:
        code = exc.code
    print(code, flush=True)
"""


def start_writers(target: Path) -> list[subprocess.Popen]:
    env = dict(os.environ, PYTHONPATH=str(REPO))
    return [subprocess.Popen([sys.executable, "-c", WRITER, str(target), str(ident)], env=env, text=True,
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE) for ident in (1, 2)]


def writers_round(writers: list[subprocess.Popen], target: Path, second_fails: bool) -> tuple[set[float], int]:
    """Both writers write ``target`` at once; the second fails midway if ``second_fails``."""
    for ident, writer in zip((1, 2), writers):
        writer.stdin.write("fail\n" if (second_fails and ident == 2) else "ok\n")
        writer.stdin.flush()
    codes = [int(writer.stdout.readline()) for writer in writers]
    assert codes == [0, 3 if second_fails else 0]
    from hbvs_cli.io.mcap import McapStream

    stream = McapStream(target)
    values = [json.loads(m.data) for m in stream]
    assert stream.complete and not stream.truncated
    assert not list(target.parent.glob("*.partial"))
    return {v["v"] for v in values}, len(values)


def test_two_concurrent_writers_to_one_path_twenty_times(tmp_path):
    """The final file is always one writer's complete output; a writer that fails never wins."""
    target = tmp_path / "same.mcap"
    writers = start_writers(target)
    try:
        for round_ in range(20):
            second_fails = round_ % 4 == 3
            values, count = writers_round(writers, target, second_fails)
            assert count == 400 and len(values) == 1
            if second_fails:
                assert values == {1.0}
            valid_mcap(target)
    finally:
        for writer in writers:
            writer.stdin.close()
            writer.wait(60)
    assert [writer.returncode for writer in writers] == [0, 0]


@pytest.mark.campaign
def test_two_concurrent_cli_runs_to_one_path_twenty_times(work, request):
    """The same through the CLI: two repeat runs with different seeds, one -o (about a
    minute: ``pytest -m campaign tests/test_robustness_outputs.py``)."""
    if "campaign" not in (request.config.option.markexpr or ""):
        pytest.skip("runs with: pytest -m campaign tests/test_robustness_outputs.py")
    expected = {}
    for seed in (1, 2):
        assert hbvs(work, "repeat", "f.mcap", "--sim", "--perception", "points", "--pixel-noise", "0.5", "--seed", str(seed), "-o", f"alone{seed}.mcap", "-q").returncode == 0
        expected[seed] = (work / f"alone{seed}.mcap").read_bytes()
    for _ in range(20):
        env = dict(os.environ, PYTHONPATH=str(REPO))
        processes = [subprocess.Popen([sys.executable, "-m", "hbvs_cli", "repeat", "f.mcap", "--sim", "--perception", "points",
                                       "--pixel-noise", "0.5", "--seed", str(seed), "-o", "same.mcap", "-q"], cwd=work, env=env)
                     for seed in (1, 2)]
        assert [p.wait(300) for p in processes] == [0, 0]
        final = (work / "same.mcap").read_bytes()
        assert final in (expected[1], expected[2]) and expected[1] != expected[2]
        assert not list(work.glob("*.partial"))
