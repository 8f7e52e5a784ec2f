"""The whole chain as a user runs it: a shell pipeline and ``hbvs demo``."""

from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys
from pathlib import Path


def hbvs_command() -> str:
    """The installed ``hbvs`` script next to this Python, or ``python -m hbvs_cli``."""
    script = Path(sys.executable).with_name("hbvs")
    return shlex.quote(str(script)) if script.exists() else f"{shlex.quote(sys.executable)} -m hbvs_cli"


def shell(command: str, timeout: float = 300) -> subprocess.CompletedProcess:
    env = dict(os.environ, MPLBACKEND="Agg")
    return subprocess.run(["bash", "-o", "pipefail", "-c", command], capture_output=True, timeout=timeout, env=env)


def test_the_pipeline_through_a_real_shell_with_nothing_on_disk(tmp_path, tmp_path_factory, default_fit):
    """Also the fit as a stage of its own: through a pipe, in another process, message for
    message the session's fit of the same teach (only the recorded input name differs:
    "-"); without -q its summary table goes to stderr, and stdout holds the fit file alone
    (``tee`` copies it, outside the pipeline's folder, for the comparison)."""
    from hbvs_cli.io.mcap import McapStream, read_metadata

    h = hbvs_command()
    piped_fit = tmp_path_factory.mktemp("tap") / "fit.mcap"
    result = shell(f"cd {shlex.quote(str(tmp_path))} && {h} teach --sim -o - | {h} fit - -o - | tee {shlex.quote(str(piped_fit))}"
                   f" | {h} repeat - --sim -o - | {h} report - --json")
    assert result.returncode == 0, result.stderr.decode()
    assert list(tmp_path.iterdir()) == []  # nothing written to disk

    def contents(source):
        stream = McapStream(source)
        messages = [(m.topic, m.schema_name, m.log_time, m.data) for m in stream]
        metadata = read_metadata(stream, "hbvs")
        names = (metadata.pop("input"), metadata["settings"].pop("input"))
        return messages, metadata, names

    assert piped_fit.read_bytes().startswith(b"\x89MCAP0\r\n")
    piped, reference = contents(piped_fit), contents(default_fit[0])
    assert len(piped[0]) > 600 and piped[:2] == reference[:2]
    assert piped[2] == ("stdin", "-") and reference[2][0].endswith("teach.mcap")
    for words in ("frames used / total", "600 / 600", "d* from taught commands", "condition (35)", "lambda"):
        assert words in result.stderr.decode()
    report = json.loads(result.stdout)  # stdout carries only data
    assert report["verdict"]["converged"] is True
    assert report["run"]["law"] == "lateral-gain" and report["run"]["steps"] == 599
    assert report["pose_error"]["position_m"]["final"] < 0.01
    assert report["pose_error"]["heading_deg"]["final"] < 0.2
    assert abs(report["depth"]["dhat_final"] - report["depth"]["d_true"]) < 0.05 * report["depth"]["d_true"]
    # Messages went to stderr: every stage's summary line.
    stderr = result.stderr.decode()
    assert "teach:" in stderr and "hbvs fit" in stderr and "repeat:" in stderr


def test_a_failing_stage_fails_the_pipeline_without_hanging():
    h = hbvs_command()
    result = shell(f"{h} teach --path nowhere -o - | {h} fit - -o - | {h} repeat - --sim -o - | {h} report -", timeout=120)
    assert result.returncode != 0
    assert b"unknown --path 'nowhere'" in result.stderr
    assert b"Traceback" not in result.stderr
    # One line for one failure: the downstream stages see an empty pipe and exit 9 in silence.
    assert result.stderr.count(b"hbvs: error:") == 1 and len(result.stderr.splitlines()) == 1


def test_a_closed_reader_does_not_leave_a_traceback():
    h = hbvs_command()
    result = shell(f"{h} teach --sim -o - | head -c 100 > /dev/null", timeout=120)
    assert b"Traceback" not in result.stderr


def test_demo_into_a_temporary_folder(demo_output):
    """``hbvs demo --out`` as a process of its own (conftest's ``demo_output``, whose files
    the other tests share as the default teach, fit and image runs)."""
    out, code, stdout, stderr = demo_output
    assert code == 0, stderr.decode()
    names = sorted(p.name for p in out.iterdir())
    assert names == ["fit.mcap", "report.json", "report.png", "run-lateral-gain.mcap", "run-paper.mcap", "teach.mcap"]
    reports = json.loads((out / "report.json").read_text())["runs"]
    lateral, paper = reports
    assert lateral["run"]["law"] == "lateral-gain" and paper["run"]["law"] == "paper"
    assert lateral["verdict"]["converged"] is True
    assert lateral["pose_error"]["position_m"]["final"] < 0.01 and lateral["pose_error"]["heading_deg"]["final"] < 0.2
    # The paper's law is still converging laterally after 20 s (see docs/results.md).
    assert paper["pose_error"]["position_m"]["final"] > 5 * lateral["pose_error"]["position_m"]["final"]
    table = stdout.decode()
    assert "lateral-gain" in table and "paper" in table and "converged" in table
    assert (out / "report.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
