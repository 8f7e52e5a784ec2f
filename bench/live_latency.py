"""Frame-to-command latency of ``hbvs repeat --live`` (issue 23): ``python -m bench.live_latency``.

For each target (dots, texture, aruco) a 640x480, 30 Hz teach is simulated and fitted;
then ``hbvs robot-sim --ros2`` (the camera, in its own process) and ``hbvs repeat --live``
run the whole trajectory over DDS on loopback (``CYCLONEDDS_URI`` from
:func:`hbvs_cli.io.ros2_dds.loopback_config`). The run file's ``/repeat/timing`` gives, per
frame, the latency from the frame's arrival to the command's publication; the figure is its
p50 and p99 (aim: p99 under 15 ms on 2 cores), with the frames dropped (arrived while
another was processed: taken over, never queued) and late. Written to
``bench/LIVE_LATENCY.md``. About 1.5 minutes; the camera process shares the cores, so a busy
machine inflates the tail: measure on a quiet one.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "LIVE_LATENCY.md"
HBVS = [sys.executable, "-m", "hbvs_cli"]
CAMERA_640 = """image_width: 640
image_height: 480
camera_name: bench
camera_matrix: {rows: 3, cols: 3, data: [500.0, 0.0, 319.5, 0.0, 500.0, 239.5, 0.0, 0.0, 1.0]}
distortion_model: plumb_bob
distortion_coefficients: {rows: 1, cols: 5, data: [0.0, 0.0, 0.0, 0.0, 0.0]}
"""


def _run(args: list[str], env: dict[str, str] | None = None) -> None:
    result = subprocess.run(args, capture_output=True, text=True, env=env)
    if result.returncode != 0:
        raise SystemExit(f"{' '.join(args)}: {result.stderr.strip()}")


def measure(target: str, folder: Path, speed: float) -> dict[str, float]:
    from hbvs_cli.io.ros2_dds import loopback_config
    from hbvs_cli.io.run_file import read_run

    calibration = folder / "camera640.yaml"
    calibration.write_text(CAMERA_640)
    teach, fit, run = folder / f"teach-{target}.mcap", folder / f"fit-{target}.mcap", folder / f"live-{target}.mcap"
    _run([*HBVS, "teach", "--target", target, "--calibration", str(calibration), "--fps", "30", "-o", str(teach), "-q"])
    _run([*HBVS, "fit", str(teach), "-o", str(fit), "-q"])
    env = dict(os.environ, CYCLONEDDS_URI=loopback_config(), ROS_DOMAIN_ID=str(224 + os.getpid() % 8))
    robot = subprocess.Popen([*HBVS, "robot-sim", str(fit), "--ros2", "--rate", "30", "-q"], env=env)
    try:
        _run([*HBVS, "repeat", str(fit), "--live", "--ros2-image", "/camera/image_raw", "--speed", str(speed), "-o", str(run), "-q"], env)
    finally:
        robot.send_signal(2)
        robot.wait(timeout=30)
    timing = read_run(run).timing
    latency_ms = 1e3 * timing["latency_s"]
    return {
        "frames": float(latency_ms.size),
        "p50": float(np.percentile(latency_ms, 50)), "p99": float(np.percentile(latency_ms, 99)),
        "max": float(latency_ms.max()), "dropped": float(np.nansum(timing["dropped"])), "late": float(np.nansum(timing["late"])),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--speed", type=float, default=1.0, help="pace of the trajectory (2: half the time)")
    parser.add_argument("--targets", default="dots,texture,aruco")
    args = parser.parse_args()
    rows = []
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as folder:
        for target in args.targets.split(","):
            figures = measure(target, Path(folder), args.speed)
            rows.append((target, figures))
            print(f"{target}: {figures}", flush=True)
    lines = [
        "# Frame-to-command latency of `repeat --live` (640x480, 30 Hz, DDS on loopback)",
        "",
        f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, {platform.machine()}, {os.cpu_count()} cores, "
        f"Python {platform.python_version()}; `python -m bench.live_latency --speed {args.speed:g}`. "
        "The stand-in camera (`robot-sim`) runs on the same cores; load average "
        f"{load_before:.1f} before, {os.getloadavg()[0]:.1f} after (a busy machine inflates the tail: measure on a quiet one).",
        "",
        "| target | frames | p50 (ms) | p99 (ms) | max (ms) | aim p99 < 15 ms | dropped | late |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for target, f in rows:
        lines.append(f"| {target} | {f['frames']:.0f} | {f['p50']:.2f} | {f['p99']:.2f} | {f['max']:.2f} | "
                     f"{'yes' if f['p99'] < 15 else 'no'} | {f['dropped']:.0f} | {f['late']:.0f} |")
    lines += ["", "Frames are never queued: a frame that arrived while another was processed is dropped "
              "(counted above) and the newest one measured."]
    RESULTS.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
