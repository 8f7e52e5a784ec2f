"""``hbvs repeat --live --camera VIDEO --cmd-out -`` (issue 23): the camera path without DDS.

The taught run's own images, as a video file played at its own rate, are a robot that is
exactly where it was taught: the loop starts (the target is at its taught start view),
its commands drive forward as taught, and when the video ends the commands go to zero and the run stops (exit 5: no more frames).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

from hbvs_cli.core.camera_clock import CameraClock
from hbvs_cli.io.images import decode_image
from hbvs_cli.io.run_file import read_run
from hbvs_cli.io.teach_file import TeachReader

REPO = Path(__file__).resolve().parents[1]
FIT = REPO / "samples" / "fit.mcap"
TEACH = REPO / "samples" / "teach.mcap"
CALIBRATION = REPO / "samples" / "camera.yaml"


def taught_video(path: Path, seconds: float) -> list[tuple[float, float]]:
    """The first ``seconds`` of the sample teach as an MJPG video at its rate; the taught commands."""
    reader = TeachReader(str(TEACH))
    writer = None
    commands = []
    for frame in reader.frames():
        if frame.t >= seconds:
            break
        image = decode_image(frame.stored_image().data, "teach")
        if writer is None:
            writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (image.shape[1], image.shape[0]))
        writer.write(cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image)
        commands.append(frame.command)
    writer.release()
    return commands


def test_a_video_file_drives_the_loop_and_ends_on_zero(tmp_path):
    video = tmp_path / "taught.avi"
    taught = taught_video(video, 3.0)
    result = subprocess.run(
        [sys.executable, "-m", "hbvs_cli", "repeat", str(FIT), "--live", "--camera", str(video), "--calibration", str(CALIBRATION),
         "--cmd-out", "-", "--lost-timeout", "1", "-o", str(tmp_path / "run.mcap"), "-q"],
        capture_output=True, text=True, timeout=120,
    )
    lines = [json.loads(line) for line in result.stdout.splitlines()]
    assert result.returncode == 5 and "no camera frame" in result.stderr and len(result.stderr.strip().splitlines()) == 1
    moving = [c for c in lines if (c["v"], c["w"]) != (0.0, 0.0)]
    # Started at once (the first frames are the taught start), then about one command a frame.
    assert len(moving) >= 10
    assert (lines[-1]["v"], lines[-1]["w"]) == (0.0, 0.0)
    # Forward, as taught (the speed is dhat's: the adaptive law (31) is still learning d*).
    assert all(0.0 < c["v"] <= 0.5 for c in moving) and all(v > 0 for v, _ in taught)
    # The run file has every step, with the commands sent and the loop's timing.
    run = read_run(tmp_path / "run.mcap")
    sent = [c["v"] for c in moving]
    np.testing.assert_allclose(run.state["v_c"][run.state["v_c"] != 0][: len(sent)], sent)
    assert run.timing is not None and run.timing["t"].size == run.steps and run.info["mode"] == "live"


def test_a_camera_that_comes_back_after_going_stale_is_driven_from_again():
    """Frames stop for longer than --stale-timeout (zero commands, once), then come back
    before --lost-timeout: the loop takes the next frame instead of stopping the run."""
    import time
    from types import SimpleNamespace

    from hbvs_cli.stages.live import LiveLoop

    class GapSource:
        """No frame until ``back_at`` (monotonic s), then one."""

        def __init__(self, back_at: float) -> None:
            self.back_at, self.served = back_at, False

        def latest(self, timeout_s: float):
            time.sleep(max(0.0, min(timeout_s, self.back_at - time.monotonic())))
            if time.monotonic() >= self.back_at and not self.served:
                self.served = True
                return SimpleNamespace(arrival=time.monotonic(), stamp=time.time())
            return None

    stops, events = [], []
    loop = LiveLoop.__new__(LiveLoop)
    loop.t, loop.stopped = 0.0, None
    loop.source = GapSource(time.monotonic() + 0.5)
    loop.options = SimpleNamespace(stale_timeout=0.1)
    loop.settings = SimpleNamespace(lost_timeout=3.0)
    loop.out = SimpleNamespace(stop=stops.append)
    loop.servo = SimpleNamespace(previous=(0.3, 0.1))
    loop.run = SimpleNamespace(event=lambda t, level, text: events.append(text))
    loop.clock, loop.used_at = CameraClock(0.1), time.monotonic()
    frame = loop._next_frame()
    assert frame is not None and loop.stopped is None
    assert len(stops) == 1 and loop.servo.previous == (0.0, 0.0)
    assert any("--stale-timeout" in text for text in events) and events[-1] == "camera frames back"
