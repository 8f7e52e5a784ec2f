"""Shared fixtures and generators for the hbvs test suite."""

from __future__ import annotations

import os
import sys
from pathlib import Path

# As the command line does (cli/app.py): OpenBLAS's own threads spin-wait for work and, on
# two cores that xdist's workers already fill, made a 9600 x 10 SVD take 160 ms instead of
# 4 ms. Set before numpy is first imported; the children the tests start inherit it.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
# Where PYTHONDONTWRITEBYTECODE is set (as on our CI machines) pytest rewrote the asserts of
# every test module again in each worker, 2 s of CPU each time; this process may cache
# them (and hbvs_cli's bytecode, see pytest_configure). The hbvs processes the tests start
# keep the variable: they read the bytecode written here and write none.
sys.dont_write_bytecode = False

import numpy as np  # noqa: E402
import pytest  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
SAMPLES = REPO / "samples"

# Tests never need a display; matplotlib must not look for one.
os.environ.setdefault("MPLBACKEND", "Agg")


def random_planar_scene(rng: np.random.Generator, n_points: int, n_frames: int, tilted: bool):
    """A random target plane seen from F* and from ``n_frames`` random planar poses.

    Returns a dict with the reference points ``m_ref`` (N, 3), the current points ``m``
    (F, N, 3), the true normal, d*, theta (F,), x_h (F, 2), the Euclidean points in F*
    and the true H (F, 3, 3). Scenes with a point near the camera's height or behind a
    camera are redrawn.
    """
    from hbvs_cli.core.frames import rotation_z

    while True:
        nz = rng.normal(0.0, 0.3) if tilted else 0.0
        normal = np.array([1.0, rng.normal(0.0, 0.4), nz])
        normal /= np.linalg.norm(normal)
        d_star = rng.uniform(3.0, 6.0)
        u = np.cross(normal, [0.0, 0.0, 1.0])
        u /= np.linalg.norm(u)
        v = np.cross(normal, u)
        a = rng.uniform(-1.0, 1.0, (n_points, 1))
        b = rng.uniform(0.2, 1.0, (n_points, 1)) * rng.choice([-1.0, 1.0], (n_points, 1))
        points = d_star * normal + a * u + b * v
        m_ref = points / points[:, :1]
        if np.any(np.abs(m_ref[:, 2]) < 0.02) or np.linalg.svd(m_ref, compute_uv=False)[-1] < 0.02:
            continue
        theta = rng.normal(0.0, 0.3, n_frames)
        x_h = rng.normal(0.0, 0.3, (n_frames, 3))
        x_h[:, 2] = 0.0
        m_bar = (d_star * x_h)[:, None, :] + np.einsum("fij,nj->fni", rotation_z(theta), points)
        if np.any(m_bar[..., 0] <= 0.5):
            continue
        return {
            "m_ref": m_ref,
            "m": m_bar / m_bar[..., :1],
            "m_bar": m_bar,
            "points_ref": points,
            "normal": normal,
            "d_star": d_star,
            "theta": theta,
            "x_h": x_h[:, :2],
            "H": rotation_z(theta) + x_h[:, :, None] * normal[None, None, :],
        }


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20031027)


def run_hbvs(*args: str, input: bytes | None = None, check: bool = False, timeout: float = 600, env: dict | None = None):
    """Run the installed ``hbvs`` entry point as a user would (``python -m hbvs_cli``)."""
    import subprocess

    full_env = dict(os.environ)
    full_env.setdefault("MPLBACKEND", "Agg")
    if env:
        full_env.update(env)
    return subprocess.run(
        [sys.executable, "-m", "hbvs_cli", *args],
        input=input,
        capture_output=True,
        check=check,
        timeout=timeout,
        env=full_env,
    )


def call_hbvs(*args: str, input: bytes | None = None):
    """``hbvs ARGS`` run inside this process: the same parsing, stages and mapping of errors
    to one line and an exit code as :func:`run_hbvs`, without the second or so a new Python
    process takes to import numpy, OpenCV and SciPy. For the many small cases of bad input;
    what only a real process shows (native libraries printing on descriptor 2, signals,
    stdio descriptors) stays with :func:`run_hbvs`. ``input``: the bytes ``-`` reads (the
    stages read ``sys.stdin.buffer`` as a stream, seekable or not)."""
    import contextlib
    import io
    import subprocess
    from unittest import mock

    from hbvs_cli.cli.app import _run

    out, err = io.BytesIO(), io.BytesIO()
    stdout = io.TextIOWrapper(out, encoding="utf-8", write_through=True)
    stderr = io.TextIOWrapper(err, encoding="utf-8", write_through=True)
    stdin = contextlib.nullcontext() if input is None else mock.patch.object(
        sys, "stdin", io.TextIOWrapper(io.BytesIO(input), encoding="utf-8"))
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr), stdin:
        code = _run(list(args), debug=False)
    return subprocess.CompletedProcess(list(args), code, out.getvalue(), err.getvalue())


# --------------------------------------------------------------------------- campaigns
#: Parametrizes a test over its extent: ``"suite"``, the part the default suite runs, and
#: ``"campaign"``, the whole of it, marked ``campaign`` so that ``pytest -m campaign``
#: selects it (see :func:`campaign_extent`).
SUITE_OR_CAMPAIGN = pytest.mark.parametrize("extent", ["suite", pytest.param("campaign", marks=pytest.mark.campaign)])


def pytest_runtest_setup(item):
    """A test marked ``campaign`` is skipped before its fixtures are made unless ``-m campaign``
    asked for it: a campaign's module fixture (the 4-target footage route: 33 s) is not built
    for the default suite only to be skipped."""
    if item.get_closest_marker("campaign") and "campaign" not in (item.config.option.markexpr or ""):
        pytest.skip(f"runs with: pytest -m campaign {item.path.relative_to(REPO)}")


def campaign_extent(request, extent: str) -> bool:
    """True for the whole campaign; skips it unless ``-m campaign`` asked for it."""
    if extent == "campaign" and "campaign" not in (request.config.option.markexpr or ""):
        pytest.skip(f"runs with: pytest -m campaign {request.node.path.relative_to(REPO)}")
    return extent == "campaign"


# --------------------------------------------------------------------------- pipelines
def quiet_console():
    from hbvs_cli.stages.console import Console

    return Console(quiet=True)


def make_teach(output, **options):
    """A teach recording (the default simulated scenario unless options say otherwise)."""
    from hbvs_cli.stages.teach import TeachOptions, run_teach

    run_teach(TeachOptions(output=str(output), **options), quiet_console())
    return output


def rendered_s_curve(seed: int, frames: int = 600):
    """The simulated s-curve drive rendered as camera images (the truth is known).

    Returns the world, the command profile, the start pose, the frame times and a
    generator of the grayscale frames.
    """
    from hbvs_cli.core.path import preset_profile
    from hbvs_cli.sim.world import default_world
    from hbvs_cli.sim.render import make_renderer

    world = default_world()
    profile, start = preset_profile("s-curve", 30)
    renderer = make_renderer(world, 2.0, 0.0, 1.0)
    rng = np.random.default_rng(seed)
    times = np.arange(frames) / 30.0
    images = (renderer.render(profile.poses_at(t, start), rng) for t in times)
    return world, profile, start, times, images


def errors_against_drive(model, world, profile, start, times):
    """RMS errors of a fit against the exact desired trajectory of a rendered drive:
    theta_d (deg), x_hd1, x_hd2 (units of d*), and d* itself."""
    from oracles import TaughtPathTrajectory

    _, _, d_star = world.reference_geometry(np.asarray(start))
    truth = TaughtPathTrajectory(profile, start, start, d_star).evaluate(times)
    fitted = model.trajectory.evaluate(times)
    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))  # noqa: E731
    return {
        "theta_deg": float(np.degrees(rms(fitted.theta_d - truth.theta_d))),
        "x_hd1": rms(fitted.x_hd1 - truth.x_hd1),
        "x_hd2": rms(fitted.x_hd2 - truth.x_hd2),
        "d_star": d_star,
    }


def teach_from_rendered_video(folder, seed: int, frames: int = 600):
    """Teach from a lossless video of :func:`rendered_s_curve`.

    Returns the teach path, the world, the command profile, the start pose and the frame times.
    """
    import cv2

    from hbvs_cli.core.camera import DEFAULT_CAMERA
    from hbvs_cli.io.calibration import save_calibration_ros

    world, profile, start, times, images = rendered_s_curve(seed, frames)
    video = Path(folder) / "drive.avi"
    # Uncompressed 8-bit gray (Y800): lossless like FFV1, which spent 4 s of CPU encoding
    # and decoding 600 frames; the 180 MB are deleted once taught.
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"Y800"), 30.0,
                             (DEFAULT_CAMERA.width, DEFAULT_CAMERA.height), isColor=False)
    assert writer.isOpened()
    for image in images:
        writer.write(image)
    writer.release()
    calibration = Path(folder) / "camera.yaml"
    save_calibration_ros(DEFAULT_CAMERA, calibration)
    teach = make_teach(Path(folder) / "video.mcap", video=video, calibration=calibration)
    video.unlink()
    return teach, world, profile, start, times


def gray_footage_teach(folder, name: str = "chessboard") -> Path:
    """A row of the independent footage maker (tests/footage.py) as 60 gray PNG frames (a
    12 s drive at 5 Hz), taught from the images folder: footage without a world, whose
    target fit must find, from a source that decodes gray."""
    import cv2

    import footage

    drive = footage.Drive(duration=12.0, fps=5.0, speed=0.24, period=9.0)
    maker = footage.FootageMaker(*footage.case(name), seed=3)
    pose_of = footage.drive_pose_function(drive)
    images = Path(folder) / "images"
    images.mkdir(parents=True)
    for k, t in enumerate(drive.times()):
        cv2.imwrite(str(images / f"frame_{k:04d}.png"), cv2.cvtColor(maker.render(pose_of, t), cv2.COLOR_BGR2GRAY))
    calibration = maker.camera.write_ros_yaml(Path(folder) / "camera.yaml")
    teach = Path(folder) / "teach.mcap"
    result = call_hbvs("teach", "--images", str(images), "--fps", "5", "--calibration", str(calibration), "-o", str(teach), "-q")
    assert result.returncode == 0, result.stderr.decode()
    return teach


def make_fit(teach_path, fit_path, **options):
    from hbvs_cli.stages.fit import FitOptions, run_fit

    return run_fit(FitOptions(input=str(teach_path), output=str(fit_path), **options), quiet_console())


def make_run(fit_path, run_path, **options):
    from hbvs_cli.stages.repeat import RepeatOptions, run_repeat

    return run_repeat(RepeatOptions(input=str(fit_path), output=str(run_path), **options), quiet_console())


def ground_truth_trajectory(model):
    """The exact desired trajectory of a simulated teach (for comparisons with the fit)."""
    from hbvs_cli.core.path import CommandProfile
    from hbvs_cli.sim.world import World
    from oracles import TaughtPathTrajectory

    path = model.taught_path
    interval = float(np.median(np.diff(path.t)))
    profile = CommandProfile(t=path.t - path.t[0], v=path.v, w=path.w, t_end=float(path.t[-1] - path.t[0] + interval))
    _, _, d_star = World.from_dict(model.world_description).reference_geometry(path.reference_pose)
    return TaughtPathTrajectory(profile, path.start_pose, path.reference_pose, d_star), d_star


def fit_errors(model):
    """RMS errors of a fitted trajectory against the truth, at the taught frame times."""
    truth, d_star = ground_truth_trajectory(model)
    t = model.taught_path.t
    t = t[(t >= model.trajectory.t_start) & (t <= model.trajectory.t_end)]
    fitted, exact = model.trajectory.evaluate(t), truth.evaluate(t - model.taught_path.t[0])
    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))  # noqa: E731
    return {
        "theta_deg": float(np.degrees(rms(fitted.theta_d - exact.theta_d))),
        "x_hd1": rms(fitted.x_hd1 - exact.x_hd1),
        "x_hd2": rms(fitted.x_hd2 - exact.x_hd2),
        "x_hd1_dot_rel": rms(fitted.x_hd1_dot - exact.x_hd1_dot) / rms(exact.x_hd1_dot),
        "d_star": d_star,
    }


def shared_pipeline_folder(tmp_path_factory) -> Path:
    """A folder every xdist worker of this session shares (the workers' base folders sit
    side by side in it), for the recordings below: built once by whichever worker needs
    one first, read by all."""
    base = tmp_path_factory.getbasetemp()
    folder = (base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base) / "shared-pipeline"
    folder.mkdir(exist_ok=True)
    return folder


@pytest.fixture(scope="session")
def pipeline_dir(tmp_path_factory):
    """:func:`shared_pipeline_folder`."""
    return shared_pipeline_folder(tmp_path_factory)


def shared_recording(folder: Path, name: str, build) -> Path:
    """``folder / name``, made by ``build(path)`` unless another worker made it already.

    The stages write through a partial file renamed into place, so a path that exists is
    complete; the lock makes a second worker wait for the first instead of building too.
    """
    import fcntl

    path = folder / name
    with open(folder / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not path.exists():
            build(path)
    return path


#: Runs ``hbvs demo --out FOLDER`` with its stdout and stderr in files beside FOLDER, then
#: writes its exit code to ``demo.code`` (through a rename: the file exists once the demo
#: has finished).
DEMO_LAUNCHER = """
import subprocess, sys
from pathlib import Path
folder = Path(sys.argv[1])
with open(folder.with_name("demo.stdout"), "wb") as out, open(folder.with_name("demo.stderr"), "wb") as err:
    code = subprocess.run([sys.executable, "-m", "hbvs_cli", "demo", "--out", str(folder)], stdout=out, stderr=err).returncode
partial = folder.with_name("demo.code.partial")
partial.write_text(str(code))
partial.rename(folder.with_name("demo.code"))
"""
_demo_process = None


def start_demo(pipeline_folder: Path) -> None:
    """Start ``hbvs demo`` in the background unless a worker of this session did already.

    Called when the tests are collected, so that the demo runs beside the first test files
    (which need no recording) instead of one worker waiting on the lock while the other
    builds it."""
    import fcntl
    import subprocess

    global _demo_process
    with open(pipeline_folder / "demo.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if (pipeline_folder / "demo.started").exists():
            return
        (pipeline_folder / "demo.started").touch()
        _demo_process = subprocess.Popen([sys.executable, "-c", DEMO_LAUNCHER, str(pipeline_folder / "demo")],
                                         env=dict(os.environ, MPLBACKEND="Agg"), start_new_session=True)


@pytest.fixture(scope="session")
def demo_output(pipeline_dir):
    """``hbvs demo --out FOLDER`` run once, as a user runs it (a process of its own, started
    when the tests were collected): (the folder, its exit code, stdout, stderr). Its teach,
    fit and two image runs are the default scenario's recordings below: the demo runs the
    stages with their default options, as :func:`make_teach`, :func:`make_fit` and
    :func:`make_run` would (only the input paths the files record differ), so the suite
    builds that pipeline once."""
    import time

    start_demo(pipeline_dir)
    done, deadline = pipeline_dir / "demo.code", time.monotonic() + 600
    while not done.exists():
        if time.monotonic() > deadline:
            pytest.fail("hbvs demo did not finish within 600 s")
        time.sleep(0.1)
    code = int(done.read_text())
    return pipeline_dir / "demo", code, (pipeline_dir / "demo.stdout").read_bytes(), (pipeline_dir / "demo.stderr").read_bytes()


def demo_file(demo_output, name: str) -> Path:
    """One of the demo's recordings; the demo's own error if it did not make it."""
    folder, code, _, stderr = demo_output
    if not (folder / name).exists():
        pytest.fail(f"hbvs demo (exit {code}) did not write {name}: {stderr.decode()}")
    return folder / name


@pytest.fixture(scope="session")
def default_teach(demo_output):
    """The default simulated teach: s-curve, 3 dots, 20 s at 30 Hz (the demo's)."""
    return demo_file(demo_output, "teach.mcap")


@pytest.fixture(scope="session")
def short_teach(pipeline_dir):
    """The default scenario's first 6 s (180 frames): for tests of options and bad input,
    which need a real recording but not the whole drive's accuracy."""
    return shared_recording(pipeline_dir, "teach-6s.mcap", lambda path: make_teach(path, duration=6.0))


@pytest.fixture(scope="session")
def small_recordings(pipeline_dir):
    """A folder with a 2 s teach (t.mcap), its fit (f.mcap) and a run of it (r.mcap,
    perception points, made by ``hbvs repeat f.mcap`` in the folder, so the run records
    its input as given): small files for the robustness tests, which copy them."""
    folder = pipeline_dir / "small"
    folder.mkdir(exist_ok=True)

    def build(run):
        make_fit(make_teach(folder / "t.mcap", duration=2.0), folder / "f.mcap")
        here = os.getcwd()
        os.chdir(folder)
        try:
            result = call_hbvs("repeat", "f.mcap", "--sim", "--perception", "points", "-o", run.name, "-q")
        finally:
            os.chdir(here)
        assert result.returncode == 0, result.stderr.decode()

    shared_recording(folder, "r.mcap", build)
    return folder


@pytest.fixture(scope="session")
def teach_8s(pipeline_dir):
    """The default scenario's first 8 s (240 frames), for the report tests' runs. Copy it
    before writing beside it."""
    return shared_recording(pipeline_dir, "teach-8s.mcap", lambda path: make_teach(path, duration=8.0))


@pytest.fixture(scope="session")
def default_fit(demo_output):
    """The default teach's fit with default options (the demo's): (path, model)."""
    from hbvs_cli.io.fit_file import read_fit_file

    path = demo_file(demo_output, "fit.mcap")
    return path, read_fit_file(path).model


@pytest.fixture(scope="session")
def default_image_runs(demo_output):
    """``hbvs repeat --sim`` of the default fit under the lateral-gain and the paper's law
    (images in the loop, seed 0; the demo's): {law: run file}, shared by the files that
    judge them."""
    return {law: demo_file(demo_output, f"run-{law}.mcap") for law in ("lateral-gain", "paper")}


@pytest.fixture(scope="session")
def video_fit(pipeline_dir):
    """A teach from a lossless video of :func:`rendered_s_curve` (seed 1, 600 frames) and
    its fit at the target's metric size, with the drive's truth: (teach path, fit path,
    world, command profile, start pose, frame times)."""

    def teach(path):
        folder = pipeline_dir / "video-build"
        folder.mkdir(exist_ok=True)
        teach_from_rendered_video(folder, seed=1)[0].rename(path)

    from oracles import target_size

    world, profile, start, times, _ = rendered_s_curve(1)
    teach_path = shared_recording(pipeline_dir, "video-teach.mcap", teach)
    fit_path = shared_recording(pipeline_dir, "video-fit.mcap",
                                lambda path: make_fit(teach_path, path, target_size=target_size(world)))
    return teach_path, fit_path, world, profile, start, times


#: Seconds of the heaviest test files (the summed durations of their tests in a run of the
#: whole suite, scaled to a quiet 2-core machine; every file over 2.5 s). xdist (``--dist
#: loadfile``) hands out files in collection order; alphabetically the heaviest come late
#: (test_stage_*, test_sweep*), and one of them running alone at the end made the suite
#: ~14 s longer than its work divided by two. Heaviest first, the last files are short.
HEAVY_FILES = {
    "test_perception_footage.py": 44, "test_sweep.py": 31, "test_stage_repeat.py": 28, "test_report_paper.py": 25,
    "test_io_rosbag_layouts.py": 24, "test_end_to_end.py": 23, "test_robustness_errors.py": 20,
    "test_robustness_fuzz.py": 17, "test_stage_fit.py": 15, "test_live_loop.py": 13, "test_robustness_outputs.py": 13,
    "test_control_filter.py": 13, "test_report_stage.py": 11, "test_stage_options.py": 10, "test_perception_targets.py": 9,
    "test_control_image_noise.py": 8, "test_robustness_surfaces.py": 8, "test_core_closed_loop.py": 8,
    "test_walkthrough.py": 17, "test_live_view.py": 7, "test_robustness_interrupts.py": 6, "test_cli_usage.py": 4,
    "test_perception_chessboard.py": 4, "test_robustness_truncated.py": 4, "test_perception_detectors.py": 4,
    "test_robustness_faults.py": 4, "test_layers.py": 3, "test_foxglove_files.py": 3, "test_control_depth.py": 3,
    "test_core_bundle.py": 3, "test_live_camera.py": 3,
}


def pytest_configure(config):
    """Compile hbvs_cli's bytecode once, before the workers start.

    The suite starts about two hundred ``hbvs`` processes. Where PYTHONDONTWRITEBYTECODE is
    set (as on our CI machines) an editable install never caches its bytecode, and each of
    them compiled the modules it imports again: 0.2 s of CPU of the 0.8 s a short command
    costs. Python still reads bytecode that exists, so writing it once here is enough.
    """
    if hasattr(config, "workerinput"):
        return
    import compileall

    compileall.compile_dir(REPO / "hbvs_cli", quiet=2)


@pytest.hookimpl(trylast=True)  # after -k and -m have deselected
def pytest_collection_modifyitems(session, config, items):
    """Heaviest files first (a stable sort: the tests of a file keep their order); the demo
    started now if a selected test needs its recordings."""
    items.sort(key=lambda item: -HEAVY_FILES.get(item.path.name, 0))
    if any("demo_output" in getattr(item, "fixturenames", ()) for item in items):
        start_demo(shared_pipeline_folder(config._tmp_path_factory))


#: Rows of the real-ROS-2 matrix (tests/test_ros2_real.py), shown after the run.
ROS2_MATRIX = pytest.StashKey[list]()


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    """The real-ROS-2 matrix's figures (a fixture's output would be captured): docs/robot.md quotes them."""
    rows = config.stash.get(ROS2_MATRIX, [])
    if rows:
        terminalreporter.write_sep("-", "ROS 2 middleware matrix (release | case | QoS | started first | received)")
        for row in rows:
            terminalreporter.write_line(row)


def pytest_sessionfinish(session, exitstatus):
    """The demo is waited for (another worker may still need it), or stopped on Ctrl-C."""
    import signal

    if _demo_process is not None and _demo_process.poll() is None:
        if exitstatus == pytest.ExitCode.INTERRUPTED:
            os.killpg(_demo_process.pid, signal.SIGTERM)
        _demo_process.wait()


# --------------------------------------------------------------------------- peak memory
#: Runs a command as its own child and writes "exit-code peak-kB" to a file. Linux keeps a
#: process's peak memory across exec, and a child forked from pytest starts at pytest's
#: size (hundreds of MB in a long session): forked from this small launcher instead, the
#: command's peak is its own. With "1" as its second argument the child's stdin is closed.
PEAK_LAUNCHER = """
import os, sys
report, close_stdin, command = sys.argv[1], sys.argv[2] == "1", sys.argv[3:]
pid = os.fork()
if pid == 0:
    if close_stdin:
        os.close(0)
    os.execv(command[0], command)
_, status, usage = os.wait4(pid, 0)
with open(report, "w") as handle:
    handle.write(f"{os.waitstatus_to_exitcode(status)} {usage.ru_maxrss}")
"""


def run_with_peak_memory(command: list[str], cwd, stderr, env: dict, close_stdin: bool = False,
                         timeout: float = 600) -> tuple[int, int]:
    """Run ``command`` (its first item an executable's path) from :data:`PEAK_LAUNCHER`;
    its exit code and its own peak resident memory (bytes, from wait4). ``stderr`` is an
    open file the command writes its stderr to."""
    import subprocess
    import tempfile

    with tempfile.TemporaryDirectory() as folder:
        report = Path(folder) / "peak.txt"
        subprocess.run([sys.executable, "-c", PEAK_LAUNCHER, str(report), "1" if close_stdin else "0", *command],
                       cwd=cwd, stdout=subprocess.DEVNULL, stderr=stderr, env=env, check=True, timeout=timeout)
        code, peak_kb = (int(word) for word in report.read_text().split())
    return code, peak_kb * 1024
