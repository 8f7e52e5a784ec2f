"""docs/walkthrough.md: every ``hbvs`` command of the page runs, in order, from the practice
footage hbvs makes (step 0: a taught drive and a second one started 10 cm further back and 5 cm
to the side, as videos, with their calibration) to the report, with nothing but hbvs; and the
calibration files it describes are read alike."""

from __future__ import annotations

import json
import re
import shlex

import numpy as np
import pytest

from conftest import REPO, call_hbvs

PAGE = REPO / "docs" / "walkthrough.md"
#: Seconds of each practice drive (step 0's --duration).
DRIVE_S = 8.0


def page_commands() -> list[list[str]]:
    """The ``hbvs`` command lines of the page's bash blocks, in order, as argument lists."""
    blocks = re.findall(r"```bash\n(.*?)```", PAGE.read_text(), flags=re.S)
    lines = [line.split("#")[0].strip() for block in blocks for line in block.splitlines()]
    return [shlex.split(line)[1:] for line in lines if line.startswith("hbvs ")]


def write_calibrations(folder):
    """The default camera as the ROS camera calibrator and as OpenCV's sample write it."""
    import cv2

    from hbvs_cli.core.camera import DEFAULT_CAMERA
    from hbvs_cli.io.calibration import save_calibration_ros

    save_calibration_ros(DEFAULT_CAMERA, folder / "camera.yaml")
    camera = DEFAULT_CAMERA
    K = np.array([[camera.fx, 0.0, camera.cx], [0.0, camera.fy, camera.cy], [0.0, 0.0, 1.0]])
    storage = cv2.FileStorage(str(folder / "camera.yml"), cv2.FILE_STORAGE_WRITE)
    storage.write("image_width", camera.width)
    storage.write("image_height", camera.height)
    storage.write("camera_matrix", K)
    storage.write("distortion_coefficients", np.zeros((1, 5)))
    storage.release()


def test_every_command_of_the_walkthrough_runs(tmp_path, monkeypatch):
    """From step 0's practice footage (made by hbvs) to the simulated repeat: every command
    of the page, verbatim, with nothing but hbvs (issue 46)."""
    from hbvs_cli.core.camera import DEFAULT_CAMERA
    from hbvs_cli.io.calibration import load_calibration

    commands = page_commands()
    assert [c[0] for c in commands] == ["teach", "teach", "teach", "info", "fit", "report", "teach", "repeat", "report", "repeat", "report"]
    monkeypatch.chdir(tmp_path)
    for args in commands:
        result = call_hbvs(*args)
        assert result.returncode == 0, (args, result.stderr.decode())
    assert load_calibration(tmp_path / "camera.yaml") == DEFAULT_CAMERA
    # The practice videos hold every simulated frame: the taught file made from the video has them all.
    practice = json.loads(call_hbvs("info", "practice.mcap", "--json").stdout)
    taught = json.loads(call_hbvs("info", "teach.mcap", "--json").stdout)
    assert taught["frames"] == practice["frames"] == int(DRIVE_S * 30)
    # What the page says of the replay: the second drive's offset, e1 about 0.1 / 4 at the start.
    replay = json.loads(call_hbvs("report", "replay.mcap", "--json").stdout)
    assert replay["errors"]["e1"]["initial"] == pytest.approx(0.025, abs=0.005)
    assert not replay["verdict"]["converged"] and "pose_error" not in replay
    assert (tmp_path / "fit.png").stat().st_size > 10_000 and (tmp_path / "replay.png").stat().st_size > 10_000


def test_the_pages_opencv_calibration_reads_as_the_ros_one(tmp_path):
    """Step 1's OpenCV FileStorage, written under the names of OpenCV's sample, is the same
    camera as the ROS camera_info YAML."""
    from hbvs_cli.io.calibration import load_calibration

    write_calibrations(tmp_path)
    assert load_calibration(tmp_path / "camera.yml") == load_calibration(tmp_path / "camera.yaml")
