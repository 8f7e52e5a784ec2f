"""``hbvs repeat --live`` against ``hbvs robot-sim --ros2`` (issue 23): two processes over
DDS on loopback (a third listens to the commands), in real time.

The default suite runs the loop at twice the taught pace (10 s) and checks that it
converges like ``--sim`` and ends on zero commands, and a frame of the wrong size (exit 3,
only zeros); the rest (the whole trajectory, stop signals, a killed stand-in, a lost target,
a robot away from the start, the time from each stop's cause to the zero command, the other
bad inputs) runs with
``pytest -m campaign tests/test_live_loop.py`` (about 3 minutes).
"""

from __future__ import annotations

import itertools
import json
import math
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
import warnings
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("cyclonedds")

from hbvs_cli.core.metrics import final_value  # noqa: E402
from hbvs_cli.io.fit_file import read_fit_file  # noqa: E402
from hbvs_cli.io.ros2_dds import loopback_config  # noqa: E402
from hbvs_cli.io.run_file import read_run  # noqa: E402
from hbvs_cli.sim.scene import simulation_world  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
FIT = REPO / "samples" / "fit.mcap"
HBVS = [sys.executable, "-m", "hbvs_cli"]
#: The sample fit's camera rate (Hz) and so its frame interval (s).
FRAME_INTERVAL = 0.1
_domains = itertools.count()


def skip_unless_campaign(request):
    if "campaign" not in (request.config.option.markexpr or ""):
        pytest.skip("runs with: pytest -m campaign tests/test_live_loop.py")


def dds_env() -> dict[str, str]:
    """Loopback DDS (lo, no multicast, peer 127.0.0.1) on a domain of this test's own."""
    domain = 100 + (os.getpid() * 13 + next(_domains)) % 120
    return dict(os.environ, CYCLONEDDS_URI=loopback_config(), ROS_DOMAIN_ID=str(domain), MPLBACKEND="Agg")


LISTENER = textwrap.dedent("""
    import json, sys, time
    from hbvs_cli.io import ros2_dds as dds
    node = dds.Ros2Node()
    reader = node.subscriber("/cmd_vel", dds.Twist, dds.command_qos())
    print("ready", flush=True)
    while True:
        for sample in reader.take(N=32):
            if hasattr(sample, "linear"):
                print(json.dumps({"wall": time.time(), "v": sample.linear.x, "w": sample.angular.z}), flush=True)
        time.sleep(0.002)
""")


class Listener:
    """The third process: every command on /cmd_vel with its wall-clock arrival."""

    def __init__(self, env: dict[str, str]) -> None:
        self.process = subprocess.Popen([sys.executable, "-c", LISTENER], stdout=subprocess.PIPE, text=True, env=env)
        assert self.process.stdout.readline().strip() == "ready"
        self.received: list[dict[str, float]] = []
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        for line in self.process.stdout:
            if line.startswith("{"):
                self.received.append(json.loads(line))

    def wait_moving(self, timeout: float = 60.0) -> None:
        """Until a non-zero command came (the live run has started)."""
        deadline = time.monotonic() + timeout
        while not any((c["v"], c["w"]) != (0.0, 0.0) for c in list(self.received)):
            assert time.monotonic() < deadline, "the live run never started"
            time.sleep(0.05)

    def commands(self) -> list[dict[str, float]]:
        time.sleep(0.3)  # the last zeros on their way
        self.close()
        return list(self.received)

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.terminate()
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:  # two orphaned listeners had outlived a SIGTERM
            self.process.kill()
            self.process.wait()
        self._thread.join(timeout=10)


@contextmanager
def listeners():
    """Starts listeners (:class:`Listener`), each ended on leaving, passed or failed: its
    loop never ends on its own (a failed test had left its listener polling the topic)."""
    started: list[Listener] = []

    def start(env: dict[str, str]) -> Listener:
        started.append(Listener(env))
        return started[-1]

    try:
        yield start
    finally:
        for listener in started:
            listener.close()


@pytest.fixture
def listen():
    """:func:`listeners` for one test."""
    with listeners() as start:
        yield start


def robot_sim(env, tmp_path, *options, duration=40.0, fit=FIT):
    poses = tmp_path / "poses.jsonl"
    process = subprocess.Popen([*HBVS, "robot-sim", str(fit), "--ros2", "--duration", str(duration), "--poses-out", str(poses), "-q", *options],
                               stderr=subprocess.PIPE, text=True, env=env)
    return process, poses


def repeat_live(env, tmp_path, *options, topic="/camera/image_raw"):
    return subprocess.Popen([*HBVS, "repeat", str(FIT), "--live", "--ros2-image", topic, "-o", str(tmp_path / "live.mcap"), "-q", *options],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)


def stop(*processes):
    """Ctrl-C (a stand-in keeps its poses), then kill what is still running."""
    for process in processes:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
            try:
                process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


def live_final_errors(run_path: Path, poses_path: Path, speed: float) -> tuple[float, float]:
    """The final position (m) and heading (deg) errors of a live run, from the stand-in's
    true poses against the taught pose at the same run time (as hbvs report's final)."""
    fit = read_fit_file(FIT)
    scene = simulation_world(fit.model, None, None, speed)
    run = read_run(run_path)
    stamp0, end = run.timing["frame_stamp"][0], run.timing["t"][-1]
    poses = [json.loads(line) for line in poses_path.read_text().splitlines()]
    t = np.array([p["stamp"] - stamp0 for p in poses])
    pose = np.array([[p["x"], p["y"], p["phi"]] for p in poses])
    keep = (t >= 0) & (t <= end)
    t, pose = t[keep], pose[keep]
    taught = scene.taught_pose_at_run_time(t)
    position = np.hypot(*(pose[:, :2] - taught[:, :2]).T)
    heading = np.degrees(np.abs(np.angle(np.exp(1j * (pose[:, 2] - taught[:, 2])))))
    return final_value(t.tolist(), position.tolist()), final_value(t.tolist(), heading.tolist())


def sim_final_errors(tmp_path, speed: float) -> tuple[float, float]:
    from hbvs_cli.report.build import build_report

    from conftest import make_run

    path = tmp_path / f"sim{speed:g}.mcap"
    make_run(FIT, path, sim=True, speed=speed)  # in this process: the live run is the one that needs processes
    report = build_report(read_run(path))
    return report.pose_error["position_m"].final, abs(report.pose_error["heading_deg"].final)


def drive_stand_in(env, tmp_path, speed: float, robot_options=(), live_options=(), topic="/camera/image_raw") -> tuple[float, float]:
    """robot-sim and ``repeat --live`` to the taught trajectory's end (exit 0); the final position (m)
    and heading (deg) errors (:func:`live_final_errors`)."""
    # The stand-in is ended by Ctrl-C once the run is over.
    robot, poses = robot_sim(env, tmp_path, *robot_options, duration=20.0 / speed + 60.0)
    live = repeat_live(env, tmp_path, "--speed", str(speed), *live_options, topic=topic)
    try:
        _, err = live.communicate(timeout=150)
        assert live.returncode == 0, err
        robot.send_signal(signal.SIGINT)
        robot.wait(timeout=30)
        if robot.returncode != 0:  # its exit past its grace (hbvs_cli.cli.app.DDS_EXIT_GRACE_S): said, the run still measured
            warnings.warn(f"robot-sim exited {robot.returncode} after Ctrl-C: {robot.stderr.read()[-3000:]}")
    finally:
        stop(live, robot)
    return live_final_errors(tmp_path / "live.mcap", poses, speed)


def converge_like_sim(tmp_path, listen, speed: float, jpeg: bool = False) -> dict:
    env = dict(dds_env())
    listener = listen(env)
    position, heading = drive_stand_in(env, tmp_path, speed, ["--image-format", "jpeg"] if jpeg else [],
                                       topic="/camera/image_raw" + ("/compressed" if jpeg else ""))
    commands = listener.commands()
    sim_position, sim_heading = sim_final_errors(tmp_path, speed)
    print(f"speed {speed}: live final {100 * position:.3f} cm, {heading:.3f} deg; sim {100 * sim_position:.3f} cm, {sim_heading:.3f} deg")
    assert position <= 2 * sim_position + 0.005
    assert heading <= 2 * sim_heading + math.degrees(0.005 / 4.0)  # 5 mm at the target's distance
    # It ends on zero commands, more than one, and they are the last ones.
    moving = [k for k, c in enumerate(commands) if (c["v"], c["w"]) != (0.0, 0.0)]
    assert moving and len(commands) - 1 - moving[-1] >= 2
    run = read_run(tmp_path / "live.mcap")
    assert run.info["mode"] == "live" and run.timing is not None
    assert np.all(run.timing["latency_s"] > 0) and np.all(run.timing["dropped"] >= 0)
    return {"commands": commands, "run": run}


def test_live_loop_converges_like_sim_and_ends_on_zero(tmp_path, listen):
    """At twice the taught pace (10 s of motion)."""
    converge_like_sim(tmp_path, listen, 2.0)


@pytest.mark.campaign
def test_live_loop_converges_like_sim_whole_trajectory(tmp_path, listen, request):
    """The taught pace (20 s), and the end's zero within a frame interval + 50 ms."""
    skip_unless_campaign(request)
    result = converge_like_sim(tmp_path, listen, 1.0)
    commands = result["commands"]
    last_moving = max(k for k, c in enumerate(commands) if (c["v"], c["w"]) != (0.0, 0.0))
    assert commands[last_moving + 1]["wall"] - commands[last_moving]["wall"] <= FRAME_INTERVAL + 0.05


@pytest.mark.campaign
def test_live_loop_on_compressed_images_converges_like_sim(tmp_path, listen, request):
    """sensor_msgs/msg/CompressedImage (JPEG) on /camera/image_raw/compressed, at twice the pace."""
    skip_unless_campaign(request)
    converge_like_sim(tmp_path, listen, 2.0, jpeg=True)


def _zero_after(commands, cause_wall: float) -> float:
    """Seconds from the cause to the first zero command after it."""
    return min(c["wall"] for c in commands if c["wall"] >= cause_wall - 1e-3 and (c["v"], c["w"]) == (0.0, 0.0)) - cause_wall


@pytest.mark.campaign
@pytest.mark.parametrize("signum, code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_a_stop_signal_sends_zero(tmp_path, listen, signum, code, request):
    skip_unless_campaign(request)
    env = dds_env()
    listener = listen(env)
    robot, _ = robot_sim(env, tmp_path)
    live = repeat_live(env, tmp_path, "--cmd-out", str(tmp_path / "cmds.jsonl"))
    try:
        listener.wait_moving()
        time.sleep(1.0)
        assert live.poll() is None
        cause = time.time()
        live.send_signal(signum)
        _, err = live.communicate(timeout=30)
    finally:
        stop(live, robot)
    commands = listener.commands()
    assert live.returncode == code and err.strip().splitlines()[-1] in ("hbvs: terminated", "hbvs: interrupted")
    assert any((c["v"], c["w"]) != (0.0, 0.0) for c in commands if c["wall"] < cause)
    after = [c for c in commands if c["wall"] >= cause]
    assert len(after) >= 2 and all((c["v"], c["w"]) == (0.0, 0.0) for c in after[-2:])
    delay = _zero_after(commands, cause)
    print(f"zero {1e3 * delay:.1f} ms after the signal")
    assert delay <= FRAME_INTERVAL + 0.05
    # The record survives the stop: the run file finished and kept, ending on the zero, saying why.
    assert_kept_with_reason(tmp_path / "live.mcap", "SIGTERM" if signum == signal.SIGTERM else "SIGINT")
    log = [json.loads(line) for line in (tmp_path / "cmds.jsonl").read_text().splitlines()]
    assert any(c["v"] != 0.0 for c in log) and (log[-1]["v"], log[-1]["w"]) == (0.0, 0.0)


@pytest.mark.campaign
def test_a_killed_stand_in_stops_the_robot_within_the_stale_timeout(tmp_path, listen, request):
    skip_unless_campaign(request)
    env = dds_env()
    listener = listen(env)
    robot, _ = robot_sim(env, tmp_path)
    live = repeat_live(env, tmp_path, "--lost-timeout", "1")
    try:
        listener.wait_moving()
        time.sleep(1.0)
        cause = time.time()
        robot.kill()
        _, err = live.communicate(timeout=30)
    finally:
        stop(live, robot)
    commands = listener.commands()
    assert live.returncode == 5 and len(err.strip().splitlines()) == 1 and "no camera frame" in err
    delay = _zero_after(commands, cause)
    print(f"zero {1e3 * delay:.1f} ms after the stand-in was killed")
    assert delay <= 0.3 + 0.05
    assert all((c["v"], c["w"]) == (0.0, 0.0) for c in commands if c["wall"] >= cause + delay)


@pytest.mark.campaign
def test_a_lost_target_stops_at_once_and_the_run_after_the_lost_timeout(tmp_path, listen, request):
    skip_unless_campaign(request)
    env = dds_env()
    listener = listen(env)
    robot, poses = robot_sim(env, tmp_path, "--occlude", "6:30")
    live = repeat_live(env, tmp_path, "--lost-timeout", "1")
    try:
        _, err = live.communicate(timeout=60)
    finally:
        stop(live, robot)
    commands = listener.commands()
    assert live.returncode == 5 and "lost" in err and len(err.strip().splitlines()) == 1
    first_hidden = min(p["stamp"] for p in map(json.loads, poses.read_text().splitlines()) if p["occluded"])
    delay = _zero_after(commands, first_hidden)
    print(f"zero {1e3 * delay:.1f} ms after the first frame without the target")
    assert delay <= FRAME_INTERVAL + 0.05
    run = read_run(tmp_path / "live.mcap")
    assert run.lost[-1] and np.all(run.state["v_c"][run.lost] == 0.0)

def assert_refused_with_only_zeros(live, err: str, listener, code: int, words: str, tmp_path: Path) -> None:
    """``repeat --live`` ended with ``code`` and one line saying ``words``, the listener on
    the command topic heard only zeros, and the run file was kept with why it stopped."""
    commands = listener.commands()
    lines = err.strip().splitlines()
    assert live.returncode == code and len(lines) == 1 and words in lines[0], err
    assert commands and all((c["v"], c["w"]) == (0.0, 0.0) for c in commands)
    assert_kept_with_reason(tmp_path / "live.mcap", words)


def assert_kept_with_reason(path: Path, words: str) -> None:
    """The run file is a complete MCAP file that says why the run stopped (``hbvs info``) and
    ends on a zero command."""
    from hbvs_cli.io.file_info import read_file_info
    from hbvs_cli.io.mcap import McapStream
    from hbvs_cli.io.topics import COMMAND_TOPIC

    info = read_file_info(path)
    assert info.complete and words in info.stopped, info.stopped
    commands = [message.json("run") for message in McapStream(path) if message.topic == COMMAND_TOPIC]
    assert commands and (commands[-1]["v"], commands[-1]["w"]) == (0.0, 0.0)



@pytest.mark.campaign
@pytest.mark.parametrize("offset, words", [("-0.45,0.05,2", "from the taught start"), ("0.5,0.3,15", "the target is not in view")])
def test_a_robot_away_from_the_start_never_moves(tmp_path, listen, offset, words, request):
    skip_unless_campaign(request)
    env = dds_env()
    listener = listen(env)
    robot, _ = robot_sim(env, tmp_path, "--offset", offset)
    live = repeat_live(env, tmp_path)
    try:
        _, err = live.communicate(timeout=60)
    finally:
        stop(live, robot)
    assert_refused_with_only_zeros(live, err, listener, 8, words, tmp_path)


PUBLISHER = textwrap.dedent("""
    import sys, time
    import numpy as np
    from hbvs_cli.io import ros2_dds as dds
    width, height, encoding, fx = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], float(sys.argv[4])
    node = dds.Ros2Node()
    images = node.publisher("/camera/image_raw", dds.Image, dds.sensor_qos())
    infos = node.publisher("/camera/camera_info", dds.CameraInfo, dds.sensor_qos())
    channels = 3 if encoding == "bgr8" else (4 if encoding == "32FC1" else 1)
    while True:
        header = dds.Header(stamp=dds.stamp_of(time.time()))
        images.write(dds.Image(header=header, height=height, width=width, encoding=encoding, step=width * channels,
                               data=bytes(width * height * channels)))
        infos.write(dds.CameraInfo(header=header, height=240, width=320, k=[fx, 0, 159.5, 0, 250.0, 119.5, 0, 0, 1]))
        time.sleep(0.1)
""")


@pytest.mark.parametrize("width, height, encoding, fx, words", [
    (64, 48, "mono8", 250.0, "a live frame is 64x48"),
    pytest.param(320, 240, "32FC1", 250.0, "unsupported image encoding", marks=pytest.mark.campaign),
    pytest.param(320, 240, "mono8", 300.0, "disagrees with the fit's camera", marks=pytest.mark.campaign),
])
def test_bad_input_is_one_line_exit_3_and_only_zeros(tmp_path, listen, width, height, encoding, fx, words, request):
    if width == 320:
        skip_unless_campaign(request)
    env = dds_env()
    listener = listen(env)
    camera = subprocess.Popen([sys.executable, "-c", PUBLISHER, str(width), str(height), encoding, str(fx)], env=env)
    live = repeat_live(env, tmp_path)
    try:
        _, err = live.communicate(timeout=60)
    finally:
        stop(live, camera)
    assert_refused_with_only_zeros(live, err, listener, 3, words, tmp_path)


@pytest.mark.campaign
def test_no_publisher_of_that_type_is_one_line(tmp_path, request):
    skip_unless_campaign(request)
    env = dds_env()
    live = repeat_live(env, tmp_path, "--lost-timeout", "1")
    _, err = live.communicate(timeout=60)
    lines = err.strip().splitlines()
    assert live.returncode == 3 and len(lines) == 1 and "no sensor_msgs/msg/Image publisher" in lines[0], err


def test_live_options_are_checked_first(tmp_path):
    from conftest import call_hbvs

    for options, words in [
        (["--live"], "one frame source"),
        (["--live", "--camera", "0"], "--calibration"),
        (["--live", "--ros2-image", "/c", "--cmd-type", "wrench"], "--cmd-type"),
        (["--live", "--sim", "--ros2-image", "/c"], "choose one mode"),
        (["--live", "--ros2-image", "/c", "--occlude", "1:2"], "for --sim"),
    ]:
        result = call_hbvs("repeat", str(FIT), *options, "-o", str(tmp_path / "r.mcap"))
        stderr = result.stderr.decode()
        assert result.returncode == 2 and len(stderr.strip().splitlines()) == 1 and words in stderr, (options, stderr)


TELEOP = textwrap.dedent("""
    import time
    from hbvs_cli.io import ros2_dds as dds
    node = dds.Ros2Node()
    writer = node.publisher("/cmd_vel", dds.Twist, dds.command_qos())
    while True:
        writer.write(dds.Twist(linear=dds.Vector3(x=0.1), angular=dds.Vector3(z=0.02)))
        time.sleep(0.05)
""")


@pytest.mark.campaign
def test_teach_records_a_running_ros2_camera_and_the_operators_commands(tmp_path, request):
    """teach --ros2-image --ros2-cmd: the stand-in driven by a teleop process, 3 s, written to stdout
    (a process that spoke DDS ends without the interpreter's teardown: every byte is flushed first)."""
    skip_unless_campaign(request)
    from hbvs_cli.io.teach_file import TeachReader

    env = dds_env()
    robot, _ = robot_sim(env, tmp_path)
    teleop = subprocess.Popen([sys.executable, "-c", TELEOP], env=env)
    teach = tmp_path / "teach.mcap"
    try:
        with open(teach, "wb") as stdout:
            result = subprocess.run([*HBVS, "teach", "--ros2-image", "/camera/image_raw", "--ros2-cmd", "/cmd_vel", "--duration", "3",
                                     "-o", "-", "-q"], stdout=stdout, stderr=subprocess.PIPE, text=True, env=env, timeout=120)
    finally:
        stop(teleop, robot)
    assert result.returncode == 0, result.stderr
    reader = TeachReader(str(teach))
    frames = list(reader.frames())
    assert 20 <= len(frames) <= 31 and frames[-1].t < 3.0
    assert reader.camera.width == 320 and reader.camera.fx == 250.0
    assert all(frame.command == (0.1, 0.02) for frame in frames[5:])
    assert reader.info["settings"]["ros2_image"] == "/camera/image_raw"
    fitted = subprocess.run([*HBVS, "fit", str(teach), "-o", str(tmp_path / "fit.mcap"), "-q"], capture_output=True, text=True, timeout=300)
    assert fitted.returncode == 0, fitted.stderr


@pytest.mark.campaign
def test_without_ros_mjpeg_camera_and_json_commands_converge_like_sim(tmp_path, request):
    """robot-sim --mjpeg PORT --cmd-in FIFO and repeat --live --camera URL --cmd-out FIFO: no DDS."""
    skip_unless_campaign(request)
    import socket

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    fifo = tmp_path / "commands"
    os.mkfifo(fifo)
    poses = tmp_path / "poses.jsonl"
    env = dict(os.environ)
    robot = subprocess.Popen([*HBVS, "robot-sim", str(FIT), "--mjpeg", str(port), "--cmd-in", str(fifo), "--duration", "80",
                              "--poses-out", str(poses), "-q"], env=env)
    live = subprocess.Popen([*HBVS, "repeat", str(FIT), "--live", "--camera", f"http://127.0.0.1:{port}/", "--calibration",
                             str(REPO / "samples" / "camera.yaml"), "--cmd-out", str(fifo), "--speed", "2",
                             "-o", str(tmp_path / "live.mcap"), "-q"], stderr=subprocess.PIPE, text=True, env=env)
    try:
        _, err = live.communicate(timeout=120)
        assert live.returncode == 0, err
    finally:
        stop(live, robot)
    position, heading = live_final_errors(tmp_path / "live.mcap", poses, 2.0)
    sim_position, sim_heading = sim_final_errors(tmp_path, 2.0)
    print(f"without ROS: live final {100 * position:.3f} cm, {heading:.3f} deg; sim {100 * sim_position:.3f} cm, {sim_heading:.3f} deg")
    assert position <= 2 * sim_position + 0.005
    assert heading <= 2 * sim_heading + math.degrees(0.005 / 4.0)
    last = json.loads(poses.read_text().splitlines()[-1])
    assert (last["v"], last["w"]) == (0.0, 0.0)
