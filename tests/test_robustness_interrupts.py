"""SIGINT and SIGTERM at random moments of ``teach``, ``fit`` and ``repeat``.

Each command runs as a user runs it (``python -m hbvs_cli``) and gets a signal after a
seeded random delay. Afterwards the output is either absent, or (when a file was there
before) exactly the bytes it had, or a finished MCAP that the official ``mcap`` reader
accepts whole; never anything else. No ``.partial`` file is left, the exit code is 130
(SIGINT) or 143 (SIGTERM), and stderr holds one line and no traceback. A signal that
arrives after the command has finished changes nothing (exit 0 with a valid file).

Delays count from the moment hbvs's ``main()`` has installed its signal handlers (seen
in ``/proc/PID/status``): before that, in the first ~60 ms of the process, the interpreter
is still starting and importing the command line module, Python's own defaults apply,
and nothing has been written.
"""

from __future__ import annotations

import os
import random
import signal
import socket
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import pytest

from conftest import SUITE_OR_CAMPAIGN, campaign_extent, gray_footage_teach, make_fit

pytestmark = pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs Linux's /proc")

#: Seed of the delays.
SEED = 20031027
#: Bytes of an output file that exists before the command runs.
PRECIOUS = b"a good output from an earlier run, which a broken file must never replace\n"
SIGNAL_CODES = {signal.SIGINT: (130, "hbvs: interrupted"), signal.SIGTERM: (143, "hbvs: terminated")}


@dataclass
class Outcome:
    returncode: int
    stderr: str
    stdout: bytes
    delay: float


def handles_sigterm(pid: int) -> bool:
    """Whether the process has a SIGTERM handler: hbvs's main() has started."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    caught = next((line.split()[1] for line in status.splitlines() if line.startswith("SigCgt:")), "0")
    return bool(int(caught, 16) >> (signal.SIGTERM - 1) & 1)


def start(args: list[str]) -> subprocess.Popen:
    """``python -m hbvs_cli ARGS``, returned once hbvs's signal handlers are in place."""
    env = dict(os.environ, MPLBACKEND="Agg")
    process = subprocess.Popen([sys.executable, "-m", "hbvs_cli", *args], stdin=subprocess.DEVNULL,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    deadline = time.monotonic() + 30.0
    while not handles_sigterm(process.pid) and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.002)
    return process


def run_and_signal(args: list[str], signum: int, delay: float) -> Outcome:
    """Start ``python -m hbvs_cli ARGS``, send ``signum`` ``delay`` s after hbvs started
    handling signals, wait for it to end."""
    process = start(args)
    time.sleep(delay)
    if process.poll() is None:
        process.send_signal(signum)
    stdout, stderr = process.communicate(timeout=120)
    return Outcome(process.returncode, stderr.decode(errors="replace"), stdout, delay)


def assert_valid_mcap(path: Path) -> None:
    """The official reader finds a summary and every message it counts."""
    from mcap.reader import make_reader

    with open(path, "rb") as handle:
        reader = make_reader(handle)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None, f"{path}: no summary"
        read = sum(1 for _ in reader.iter_messages())
    assert read == summary.statistics.message_count > 0, f"{path}: {read} messages read of {summary.statistics.message_count}"


def stop_lines(stderr: str) -> list[str]:
    """What stderr says besides the warnings a stage printed before the signal came (a
    short s-curve does not tell the homography branches apart, and fit says so)."""
    return [line for line in stderr.strip().splitlines() if not line.startswith("hbvs: warning:")]


def check_outcome(outcome: Outcome, signum: int, output: Path, had_file: bool) -> bool:
    """Assert what an interrupted (or finished) run may leave; True if it was interrupted."""
    assert "Traceback" not in outcome.stderr, outcome.stderr
    assert not list(output.parent.glob(output.name + "*.partial")), f"a .partial file was left (delay {outcome.delay:.2f} s)"
    code, line = SIGNAL_CODES[signum]
    if outcome.returncode == 0:  # the signal came after the command had finished
        assert_valid_mcap(output)
        return False
    assert outcome.returncode == code, (outcome.returncode, outcome.stderr, outcome.delay)
    assert stop_lines(outcome.stderr) == [line], outcome.stderr
    if output.exists() and not (had_file and output.read_bytes() == PRECIOUS):
        # Only a complete file is ever renamed into place (the signal came after that).
        assert_valid_mcap(output)
    return True


@pytest.fixture(scope="module")
def inputs(short_teach, tmp_path_factory):
    """A 6 s teach and its fit, and gray footage of a chessboard without a world (its fit
    picks the target while a second thread reads frames): each command below runs for one
    to two seconds."""
    folder = tmp_path_factory.mktemp("interrupt_inputs")
    make_fit(short_teach, folder / "fit.mcap")
    return {"teach": short_teach, "fit": folder / "fit.mcap", "footage": gray_footage_teach(folder / "footage")}


COMMANDS = {
    "teach": lambda inputs, out: ["teach", "--duration", "6", "-q", "-o", str(out)],
    "fit": lambda inputs, out: ["fit", str(inputs["teach"]), "-q", "-o", str(out)],
    "fit-footage": lambda inputs, out: ["fit", str(inputs["footage"]), "-q", "-o", str(out)],
    "repeat": lambda inputs, out: ["repeat", str(inputs["fit"]), "--sim", "--rate", "60", "-q", "-o", str(out)],
}


@SUITE_OR_CAMPAIGN
def test_signals_at_random_moments_leave_no_broken_output(inputs, tmp_path, request, extent):
    rng = random.Random(SEED)
    runs = []
    # Each command and signal with and without an earlier output file; the default suite
    # runs one of the two for each pair (both, for each command), ``-m campaign`` all 16.
    campaign = campaign_extent(request, extent)
    for k, (command, signum) in enumerate((c, s) for c in COMMANDS for s in SIGNAL_CODES):
        for attempt in range(2):
            delay = rng.uniform(0.0, 1.2)
            # (The footage's fit has its own sweep of signals below; here, in the campaign only.)
            if not campaign and (attempt != k % 2 or command == "fit-footage"):
                continue
            output = tmp_path / f"{command}-{signum.name}-{attempt}.mcap"
            had_file = attempt == 1
            if had_file:
                output.write_bytes(PRECIOUS)
            runs.append((COMMANDS[command](inputs, output), signum, delay, output, had_file))
    # Two at a time (CI has two cores); each run is its own process.
    with ThreadPoolExecutor(max_workers=2) as pool:
        outcomes = list(pool.map(lambda run: run_and_signal(*run[:3]), runs))
    interrupted = [check_outcome(outcome, run[1], run[3], run[4]) for outcome, run in zip(outcomes, runs)]
    # Most signals land while the command runs (a fast machine may finish a few first).
    assert sum(interrupted) >= len(runs) // 2, [(o.returncode, round(o.delay, 2)) for o in outcomes]


@SUITE_OR_CAMPAIGN
def test_signals_through_the_target_pick_of_footage_stop_cleanly(inputs, tmp_path, request, extent):
    """Footage without a world: fit picks its target (here most of its first second) while a
    second thread reads frames. A signal every 0.3 s from 0.1 s in (``-m campaign``: every
    0.03 s): each run stops with its code and one line (a thread left running unjoined used
    to abort the interpreter's exit, code -6, when the signal cut short the wait for the pick)."""
    step = 0.03 if campaign_extent(request, extent) else 0.3
    delays = [0.1 + step * k for k in range(int(1.1 / step) + 1)]
    runs = [(COMMANDS["fit-footage"](inputs, tmp_path / f"footage-{k}.mcap"), (signal.SIGINT, signal.SIGTERM)[k % 2], delay)
            for k, delay in enumerate(delays)]
    with ThreadPoolExecutor(max_workers=2) as pool:
        outcomes = list(pool.map(lambda run: run_and_signal(*run), runs))
    for outcome, (args, signum, _) in zip(outcomes, runs):
        check_outcome(outcome, signum, Path(args[-1]), had_file=False)


@pytest.mark.parametrize("signum", list(SIGNAL_CODES), ids=lambda s: s.name)
def test_a_signal_while_writing_to_stdout_prints_no_traceback(inputs, signum):
    """The signal comes once the MCAP stream is flowing (two teach chunks have arrived)."""
    process = start(["teach", "--duration", "6", "-q", "-o", "-"])
    received = bytearray()
    while len(received) < 2 * 512 * 1024:
        data = process.stdout.read1(65536)
        if not data:
            break
        received += data
    process.send_signal(signum)
    rest, stderr = process.communicate(timeout=60)
    code, line = SIGNAL_CODES[signum]
    assert process.returncode == code, (process.returncode, stderr)
    assert stop_lines(stderr.decode()) == [line], stderr
    # What reached the pipe is the start of an MCAP file, cut where the signal came.
    assert bytes(received + rest).startswith(b"\x89MCAP0\r\n")


def test_a_second_signal_during_cleanup_is_ignored(inputs, tmp_path):
    """Ctrl-C twice in quick succession: still one clean stop, no partial file."""
    output = tmp_path / "twice.mcap"
    process = start(["fit", str(inputs["teach"]), "-o", str(output)])
    time.sleep(0.8)
    process.send_signal(signal.SIGINT)
    time.sleep(0.002)
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 130 and stop_lines(stderr.decode()) == ["hbvs: interrupted"], stderr
    assert not output.exists() and not list(output.parent.glob(output.name + "*.partial"))


@pytest.mark.parametrize("signum", list(SIGNAL_CODES))
def test_a_signal_wrapped_by_native_code_is_reported_as_the_stop(monkeypatch, capsys, signum):
    """A SIGTERM that lands in a C extension's initialisation comes back as ImportError
    ("initialization failed"); it is still the stop, not an internal error (exit 70)."""
    from hbvs_cli import stop_signals
    from hbvs_cli.cli import app as cli_app

    def wrapped_by_native_code(*args, **kwargs):
        monkeypatch.setattr(stop_signals, "received", signum)
        raise ImportError("initialization failed")

    monkeypatch.setattr(cli_app, "app", wrapped_by_native_code)
    monkeypatch.setattr(signal, "signal", lambda signum, handler: None)  # the test process keeps its handlers
    monkeypatch.setattr(sys, "unraisablehook", sys.unraisablehook)  # and its hook, which main replaces
    monkeypatch.setattr(cli_app, "_prepare_stdio", lambda debug: None)
    with pytest.raises(SystemExit) as stop:
        cli_app.main(["fit", "t.mcap"])
    code, line = SIGNAL_CODES[signum]
    assert stop.value.code == code
    assert capsys.readouterr().err.strip().splitlines() == [line]


#: Runs hbvs with a stop signal swallowed at the 20th progress step, as a native extension
#: that clears Python's errors swallows the handler's exception (the handler has already set
#: the signals to be ignored, so no second signal would come); says on stderr if a later step ran.
SWALLOWING_RUN = """
import os, signal, sys, time
from hbvs_cli.stages import console
advance, steps = console.ProgressTask.advance, [0]
def swallowing_advance(self, *args, **kwargs):
    steps[0] += 1
    if steps[0] == 20:
        try:
            os.kill(os.getpid(), {signum})
            time.sleep(1.0)  # the handler runs here and raises
        except BaseException:
            pass
    if steps[0] > 21:
        sys.stderr.write("a step after the stop\\n")
    return advance(self, *args, **kwargs)
console.ProgressTask.advance = swallowing_advance
from hbvs_cli.cli.app import main
main(sys.argv[1:])
"""


@pytest.mark.parametrize("signum", list(SIGNAL_CODES))
@pytest.mark.parametrize("command", ["teach", "fit", "repeat"])
def test_a_stop_signal_swallowed_by_native_code_stops_the_loop_at_its_next_step(inputs, tmp_path, command, signum):
    """The loops of teach, fit and repeat check for a stop signal once a step: one whose
    exception native code swallowed still stops the command at the next step, with its exit
    code and line and no output (it used to run on to the end and exit 0)."""
    output = tmp_path / "out.mcap"
    args = {"teach": ["teach", "--duration", "6"], "fit": ["fit", str(inputs["teach"])],
            "repeat": ["repeat", str(inputs["fit"]), "--sim"]}[command]
    process = subprocess.run([sys.executable, "-c", SWALLOWING_RUN.format(signum=int(signum)), *args, "-q", "-o", str(output)],
                             capture_output=True, text=True, timeout=120, env=dict(os.environ, MPLBACKEND="Agg"))
    code, line = SIGNAL_CODES[signum]
    assert process.returncode == code and stop_lines(process.stderr) == [line], process.stderr
    assert "a step after the stop" not in process.stderr
    assert not output.exists() and not list(tmp_path.glob("*.partial"))


@pytest.mark.parametrize("step", ["wait_for_start", "drive"])
def test_the_live_loop_checks_for_a_stop_signal_before_each_frame(monkeypatch, step):
    """``repeat --live``'s loops raise a received stop signal before taking a frame, so one
    whose exception native code swallowed still stops the robot (its zeros are sent on the
    way out, ``tests/test_live_loop.py``)."""
    from hbvs_cli import stop_signals
    from hbvs_cli.stages.live import LiveLoop

    class Source:
        taken = 0

        def latest(self, timeout):
            Source.taken += 1
            raise AssertionError("a frame was taken after the stop")

    monkeypatch.setattr(stop_signals, "received", signal.SIGTERM)
    trajectory = SimpleNamespace(t_start=0.0, t_end=10.0, evaluate=lambda t: None)
    loop = LiveLoop(Source(), trajectory, None, None, None, None, None, None,
                    SimpleNamespace(stale_timeout=0.5), SimpleNamespace(rate=30.0, lost_timeout=1.0))
    with pytest.raises(stop_signals.Terminated):
        getattr(loop, step)()
    assert Source.taken == 0



def serving(port: int) -> bool:
    with socket.socket() as probe:
        return probe.connect_ex(("127.0.0.1", port)) == 0


#: A process that loaded Cyclone DDS (a stand-in module here) with the grace shortened to 1 s,
#: whose teardown never ends (an exit handler that sleeps) and, with ``{hang_on_close}``, whose
#: stand-in robot never finishes closing its transport after a stop signal; ``{argv}``: hbvs's arguments.
HANGING_TEARDOWN = """
import atexit, sys, time, types
sys.modules.setdefault("cyclonedds", types.ModuleType("cyclonedds"))
from hbvs_cli.cli import app
from hbvs_cli.stages import robot_sim
app.DDS_EXIT_GRACE_S = 1.0
atexit.register(time.sleep, 120)
if {hang_on_close}:
    robot_sim._PlainRobot.close = lambda self: time.sleep(120)
sys.argv = ["hbvs", *{argv}]
app.main()
"""


@pytest.mark.parametrize("hang_on_close", [False, True], ids=["in-its-teardown", "in-its-cleanup-after-ctrl-c"])
def test_a_process_that_spoke_dds_ends_within_its_grace_whatever_it_waits_for(hang_on_close, tmp_path):
    """Cyclone DDS's teardown can wait without end (a stand-in robot outlived two Ctrl-C's by 40 s
    in CI): a process that loaded it skips the interpreter's teardown once its command returned
    (an exit handler that never ends is never run: robot-sim's Ctrl-C exit 0 at once), and a
    cleanup of its own that never ends is cut by SIGALRM three times DDS_EXIT_GRACE_S after a stop
    signal."""
    from test_live_loop import FIT
    from test_route_live import free_port

    (tmp_path / "none.jsonl").write_text("")
    port = free_port()
    argv = ["robot-sim", str(FIT), "--mjpeg", str(port), "--cmd-in", str(tmp_path / "none.jsonl"), "--duration", "60", "-q"]
    process = subprocess.Popen([sys.executable, "-c", HANGING_TEARDOWN.format(argv=argv, hang_on_close=hang_on_close)],
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 30.0
    while not serving(port):  # robot-sim is running once its camera serves
        assert process.poll() is None and time.monotonic() < deadline
        time.sleep(0.1)
    process.send_signal(signal.SIGINT)
    began = time.monotonic()
    _, stderr = process.communicate(timeout=30)
    took = time.monotonic() - began
    print(f"ended {took:.2f} s after Ctrl-C, exit {process.returncode}: {stderr.splitlines()[:2]}")
    if hang_on_close:
        assert process.returncode == -signal.SIGALRM, stderr
        assert 3.0 <= took < 5.0
    else:
        assert process.returncode == 0, stderr
        assert took < 1.0
