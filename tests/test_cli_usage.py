"""Using the command line: help labels, --debug, demo -o, one-line usage errors, an unquoted
glob, options that do not apply to a source, frame counts, outputs in a missing folder."""

from __future__ import annotations

import json
import os
import re

import cv2
import numpy as np
import pytest

from hbvs_cli.io.teach_file import TeachReader

from conftest import REPO, make_teach, run_hbvs

COMMANDS = ("teach", "fit", "repeat", "report", "demo")


@pytest.fixture
def hbvs(capsys, monkeypatch):
    """Run the command line in this process (as ``main`` does, without its signal
    handlers): returns (exit code, stdout, stderr)."""
    from hbvs_cli.cli.app import _run

    monkeypatch.setenv("COLUMNS", "200")
    monkeypatch.setenv("TERM", "dumb")

    def run(*args: str) -> tuple[int, str, str]:
        capsys.readouterr()
        try:
            code = _run(list(args), debug=False)
        except SystemExit as stop:  # --help and --version end with typer's Exit
            code = stop.code or 0
        out = capsys.readouterr()
        return code, out.out, out.err

    return run


@pytest.fixture
def help_text(hbvs):
    def text(*command: str) -> str:
        code, out, err = hbvs(*command, "--help")
        assert code == 0, err
        return out

    return text


@pytest.mark.parametrize("command", [(), *[(c,) for c in COMMANDS]])
def test_help_shows_value_kinds_not_python_types(help_text, command):
    text = help_text(*command)
    for python_label in ("<bool>", "<str>", "<int>", "<float", "<path>", "list[", "{input}", "{runs}"):
        assert python_label not in text, (command, python_label)
    # Flags take no value: nothing stands between the flag's names and its help.
    for line in text.splitlines():
        if re.search(r"--(quiet|help|sim|json|with-images|record-images|debug|version)\b", line):
            assert not re.search(r"\b(TEXT|INTEGER|NUMBER|PATH)\b", line), line


def test_help_labels_values_and_arguments(help_text):
    teach, fit, report = help_text("teach"), help_text("fit"), help_text("report")
    assert re.search(r"--fps\s+NUMBER", teach) and re.search(r"--seed\s+INTEGER", teach)
    assert re.search(r"--camera\s+TEXT", teach)   # an index, a device, a URL: as repeat --live --camera
    assert re.search(r"--calibration\s+PATH", teach) and re.search(r"--output\s+-o\s+TEXT", teach)
    assert "Usage: hbvs fit [OPTIONS] INPUT" in fit and "Usage: hbvs report [OPTIONS] RUNS..." in report
    assert re.search(r"--fail-above\s+TEXT", report)


def test_debug_works_after_the_command_and_keeps_the_exit_code(tmp_path):
    missing = str(tmp_path / "missing.mp4")
    plain = run_hbvs("teach", "--video", missing, "-o", str(tmp_path / "t.mcap"))
    after = run_hbvs("teach", "--video", missing, "-o", str(tmp_path / "t.mcap"), "--debug")
    before = run_hbvs("--debug", "teach", "--video", missing, "-o", str(tmp_path / "t.mcap"))
    assert plain.returncode == after.returncode == before.returncode == 3
    assert b"Traceback" not in plain.stderr and len(plain.stderr.decode().strip().splitlines()) == 1
    for result in (after, before):
        assert b"Traceback" in result.stderr and b"InputError" in result.stderr
        assert result.stderr.decode().strip().splitlines()[-1] == plain.stderr.decode().strip()


def test_demo_takes_o_output_and_still_the_old_out(help_text):
    text = help_text("demo")
    assert re.search(r"--output\s+-o\s+PATH", text) and "--out " not in text
    from hbvs_cli.cli.app import app
    import typer.main

    demo = typer.main.get_command(app).commands["demo"]
    names = {opt for param in demo.params for opt in param.opts}
    assert {"-o", "--output", "--out"} <= names


@pytest.mark.parametrize("args, words", [
    (("teach", "--dots", "1"), "--dots"),
    (("teach", "--quality", "101"), "--quality"),
    (("fit", "x.mcap", "--max-lost", "2"), "--max-lost"),
    (("teach", "--bogus"), "--bogus"),
    (("fit",), "INPUT"),
])
def test_usage_errors_are_one_line(hbvs, args, words):
    code, _, err = hbvs(*args)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, lines
    assert lines[0].startswith("hbvs: error: ") and words in lines[0] and "-h" in lines[0]


def test_an_unquoted_images_glob_is_explained(hbvs, tmp_path):
    folder = tmp_path / "frames"
    folder.mkdir()
    files = []
    for k in range(40):
        files.append(folder / f"frame{k:03d}.png")
        cv2.imwrite(str(files[-1]), np.zeros((8, 8), np.uint8))
    code, _, err = hbvs("teach", "--images", *map(str, files), "-o", str(tmp_path / "t.mcap"))
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1
    assert "--images got 40 file names" in lines[0] and f"--images '{folder}/*.png'" in lines[0]
    assert "frame039" not in lines[0]  # not a list of 600 names
    assert not (tmp_path / "t.mcap").exists()
    # Any other stray arguments: still one line, of bounded length.
    code, _, err = hbvs("teach", "-o", str(tmp_path / "t.mcap"), *[f"stray{k}" for k in range(500)])
    assert code == 2 and len(err.strip().splitlines()) == 1 and len(err) < 400 and "unexpected extra" in err


@pytest.fixture(scope="module")
def video(tmp_path_factory):
    """A 12-frame MJPG video at 30 fps and a calibration for it."""
    from hbvs_cli.core.camera import CameraIntrinsics
    from hbvs_cli.io.calibration import save_calibration_ros

    folder = tmp_path_factory.mktemp("video")
    path = folder / "drive.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (160, 120), isColor=False)
    rng = np.random.default_rng(1)
    for _ in range(12):
        writer.write(rng.integers(0, 255, (120, 160), dtype=np.uint8))
    writer.release()
    calibration = folder / "camera.yaml"
    save_calibration_ros(CameraIntrinsics(fx=100.0, fy=100.0, cx=79.5, cy=59.5, width=160, height=120), calibration)
    return path, calibration


def test_video_fps_replaces_the_container_rate(video, tmp_path):
    path, calibration = video
    teach = make_teach(tmp_path / "t.mcap", video=path, calibration=calibration, fps=15.0)
    reader = TeachReader(teach)
    frames = list(reader.frames())
    assert len(frames) == 12 and frames[-1].t == pytest.approx(11 / 15, abs=1e-6)
    assert reader.info["settings"]["fps"] == 15.0 and reader.info["settings"]["source"]["timestamps"] == "fps override"


def test_video_metadata_records_no_simulator_settings_and_jpeg_quality(video, tmp_path):
    path, calibration = video
    reader = TeachReader(make_teach(tmp_path / "t.mcap", video=path, calibration=calibration, jpeg_quality=80))
    frames = list(reader.frames())
    settings = reader.info["settings"]
    for key in ("noise", "blur", "exposure", "seed", "path", "target", "dots", "offset", "texture"):
        assert key not in settings, key
    assert settings["jpeg_quality"] == 80 and settings["video"] == str(path)
    assert reader.world_description is None
    assert all(frame.stored_image().format == "jpeg" for frame in frames)


@pytest.mark.parametrize("extra, words", [
    (("--noise", "5"), "--noise describes the simulated robot and camera"),
    (("--path", "arc", "--seed", "3"), "--path, --seed describe"),
])
def test_simulation_options_are_refused_with_a_recorded_source(hbvs, video, tmp_path, extra, words):
    path, calibration = video
    code, _, err = hbvs("teach", "--video", str(path), "--calibration", str(calibration), *extra, "-o", str(tmp_path / "t.mcap"))
    assert code == 2 and words in err
    assert not (tmp_path / "t.mcap").exists()


def test_fps_is_refused_where_the_source_has_its_own_clock(hbvs, tmp_path):
    code, _, err = hbvs("teach", "--bag", str(tmp_path / "x.mcap"), "--fps", "15", "-o", str(tmp_path / "t.mcap"))
    assert code == 2 and "--fps does not go with --bag" in err


def test_duration_gives_duration_times_rate_frames(video, tmp_path):
    """5 s at 30 fps is 150 frames (t = 0 ... 4.967 s), for the simulator and a recording."""
    sim = TeachReader(make_teach(tmp_path / "sim.mcap", duration=5.0))
    assert sum(1 for _ in sim.frames()) == 150
    path, calibration = video
    recorded = TeachReader(make_teach(tmp_path / "video.mcap", video=path, calibration=calibration, duration=0.2))
    assert sum(1 for _ in recorded.frames()) == 6  # t = 0 ... 5/30 s, not 7 frames up to 0.2 s


def test_sim_metadata_still_records_every_setting(tmp_path):
    reader = TeachReader(make_teach(tmp_path / "sim.mcap", duration=0.2, noise=1.5))
    next(reader.frames())
    settings = reader.info["settings"]
    assert settings["noise"] == 1.5 and settings["blur"] == 0.0 and settings["fps"] == 30.0
    assert settings["path"] == "s-curve" and settings["target"] == "dots" and settings["seed"] == 0
    assert settings["sim"] is True  # the default source is the simulator, --sim or not
    assert json.dumps(settings)  # JSON-ready


@pytest.mark.parametrize("args", [
    ("teach", "--duration", "0.1", "-o", "{missing}/t.mcap"),
    ("report", "{fit}", "--plot", "{missing}/fit.png"),
    ("export", "{fit}", "-o", "{missing}/bag"),
], ids=["teach -o", "report --plot", "export -o"])
def test_an_output_in_a_missing_folder_exits_6(tmp_path, args):
    """An output that cannot be written is exit 6, not 3 (which is for inputs)."""
    from conftest import SAMPLES, call_hbvs

    values = {"missing": str(tmp_path / "no-such-folder"), "fit": str(SAMPLES / "fit.mcap")}
    result = call_hbvs(*(arg.format(**values) for arg in args))
    assert result.returncode == 6, result.stderr
    assert result.stderr.decode().count("\n") == 1 and b"does not exist" in result.stderr
    assert not (tmp_path / "no-such-folder").exists()


#: Every command's help, as typer renders it 200 columns wide: made at 7bf9143, before the options were declared as
#: dataclasses (issue 45). A change of an option's words is meant: write the file again with
#: ``HBVS_WRITE_HELP=1 pytest -n 0 tests/test_cli_usage.py -k every_help``.
HELP_FILE = REPO / "tests" / "data" / "help.txt"
ALL_COMMANDS = ((), ("teach",), ("fit",), ("repeat",), ("robot-sim",), ("report",), ("export",), ("info",), ("sweep",), ("demo",))


def test_every_help_text_is_as_recorded(help_text):
    from hbvs_cli.io.shipped import shipped_root

    text = "".join(f"=== hbvs {' '.join(command)}\n{help_text(*command)}" for command in ALL_COMMANDS)
    # Where docs/ is installed differs between checkouts; lines end without rich's padding.
    lines = [line.rstrip() for line in text.replace(str(shipped_root()), "SHIPPED_ROOT").splitlines()]
    if os.environ.get("HBVS_WRITE_HELP"):
        HELP_FILE.write_text("\n".join(lines) + "\n")
    assert lines == HELP_FILE.read_text().splitlines()
