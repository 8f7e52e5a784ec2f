"""Issue 47 live and replayed: ``robot-sim`` renders a route fit's whole route, and ``repeat --live``
and ``--replay`` follow a route segment by segment, each segment's detector against its own F*_i."""

from __future__ import annotations

import socket
import subprocess
import sys
import time

import cv2
import numpy as np
import pytest

from hbvs_cli.io.route_file import read_route_file
from hbvs_cli.sim.render import RenderSettings
from hbvs_cli.sim.route_world import RouteRenderer, recorded_route

from conftest import call_hbvs

HBVS = [sys.executable, "-m", "hbvs_cli"]
#: The corridor's first 16 s (the dot target, then the marker board) at this frame rate (Hz).
RATE = 15.0


@pytest.fixture(scope="module")
def corridor_fit(tmp_path_factory):
    """The corridor's first 16 s taught in simulation and fitted: a route file of two segments."""
    folder = tmp_path_factory.mktemp("corridor")
    teach, fit = folder / "teach.mcap", folder / "fit.mcap"
    for args in (("teach", "--sim", "--route", "corridor", "--duration", "16", "--fps", str(RATE), "-o", str(teach)),
                 ("fit", str(teach), "-o", str(fit))):
        assert call_hbvs(*args).returncode == 0
    return fit


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def first_mjpeg_frame(url: str, timeout_s: float = 30.0) -> np.ndarray:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        capture = cv2.VideoCapture(url)
        ok, frame = capture.read()
        capture.release()
        if ok:
            return cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY) if frame.ndim == 3 else frame
        time.sleep(0.2)
    raise AssertionError(f"no frame from {url}")


def test_robot_sim_renders_every_target_of_a_route_fit(corridor_fit, tmp_path):
    """robot-sim on a route fit serves the route as its simulated teach saw it: at the taught start
    (no offset) its MJPEG frame is the route renderer's frame within the sensor noise (2 gray
    levels) and JPEG, also where only the second and third targets are drawn (measured: 2.2 gray
    levels mean there, the bare wall 69 away)."""
    plan = read_route_file(str(corridor_fit))
    route = recorded_route(plan.world, plan.models[0].camera)
    port = free_port()
    (tmp_path / "none.jsonl").write_text("")
    robot = subprocess.Popen([*HBVS, "robot-sim", str(corridor_fit), "--mjpeg", str(port), "--cmd-in", str(tmp_path / "none.jsonl"),
                              "--offset", "0,0,0", "--duration", "20", "-q"], stderr=subprocess.PIPE, text=True)
    try:
        frame = first_mjpeg_frame(f"http://127.0.0.1:{port}/").astype(float)
    finally:
        robot.terminate()
        robot.wait(timeout=10)
    renderer = RouteRenderer(route, RenderSettings(noise_std=0.0))
    start = plan.taught_poses[0, 1:]
    expected = renderer.render_scene(start).astype(float)
    wall = float(RenderSettings().background)
    later = np.zeros(expected.shape, dtype=bool)
    for index in (1, 2):
        alone = renderer.parts[index].render_scene(route.local_pose(index, start))
        later |= alone != int(wall)
    assert later.sum() > 500  # the second and third targets are in the frame
    difference = np.abs(frame - expected)
    print(f"mean |frame - route| {difference.mean():.2f}, on targets 2 and 3 {difference[later].mean():.2f}, "
          f"wall there {np.abs(expected[later] - wall).mean():.1f}")
    assert difference.mean() < 3.0 and difference[later].mean() < 4.0
    assert np.abs(expected[later] - wall).mean() > 20.0
