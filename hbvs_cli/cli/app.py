"""The ``hbvs`` command line: parse options, call a stage (imported lazily, so that ``hbvs
--help`` stays fast), map errors to exit codes."""

from __future__ import annotations

import errno
import importlib
import inspect
import math
import os
import signal
import stat
import sys
import traceback
import warnings
from contextlib import suppress
from pathlib import Path
from typing import Annotated, Any, List, Optional

import typer

from .. import __version__, stop_signals
from ..errors import HbvsError, InputError, OutputError, UpstreamFailedError
from ..io.limits import set_limits
from ..io.native_log import capture
from ..io.output_target import file_identity
from ..io.shipped import shipped_root
from ..stages.console import Console
from ..sweep.parameters import parameter_names_text
from ..settings.commands import (
    ExportOptions, FitOptions, InfoOptions, RepeatOptions, ReportOptions, RobotSimOptions, SweepOptions, TeachOptions,
)
from ..settings.option import options_from_command_line, settings_of
from .parsing import HbvsGroup, one_line_usage_error, split_debug, unquoted_glob_hint
from .signature import with_settings

app = typer.Typer(
    cls=HbvsGroup,
    name="hbvs",
    help=(
        "Teach-and-repeat for a wheeled robot with one camera: the homography-based adaptive "
        "visual servo tracking controller of Chen, Dixon, Dawson and McIntyre (IROS 2003).\n\n"
        "Pipeline: hbvs teach -o - | hbvs fit - -o - | hbvs repeat - --sim -o - | hbvs report -\n\n"
        "Method and metrics: docs/method.md, docs/report.md. Default gains: samples/gains.toml. "
        f"These docs/ and samples/ files are installed in {shipped_root()}."
    ),
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode="rich",
    context_settings={"help_option_names": ["-h", "--help"]},
)

def _quiet(what: str) -> inspect.Parameter:
    """A stage's ``-q``: no ``what`` on stderr."""
    return inspect.Parameter("quiet", inspect.Parameter.KEYWORD_ONLY, default=False,
                             annotation=Annotated[bool, typer.Option("--quiet", "-q", help=f"No {what} on stderr.")])


def _version(value: bool) -> None:
    if value:
        typer.echo(f"hbvs {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version and exit.")] = False,
    debug: Annotated[bool, typer.Option("--debug", help="Show the full traceback of an error (also after the command; the exit code stays the same).")] = False,
    limit: Annotated[Optional[List[str]], typer.Option("--limit", metavar="NAME=N", help="Raise a size limit: steps, messages, chunk-messages, input-bytes, decompressed-bytes, sweep-runs (see docs/robustness.md); repeatable.")] = None,
) -> None:
    """hbvs: teach, fit, repeat, report."""
    if limit:
        set_limits(list(limit))


#: The options through which a stage reads a file, ``-`` meaning stdin.
INPUT_OPTIONS = ("input", "runs", "fit")


def _stdin_is_an_empty_pipe() -> bool:
    """True when stdin is a pipe closed before its first byte (peeked at): the stage before this one failed."""
    try:
        # sys.stdin's own descriptor: a stand-in stdin (a test's bytes) has none and is no pipe.
        return stat.S_ISFIFO(os.fstat(sys.stdin.fileno()).st_mode) and sys.stdin.buffer.peek(1) == b""
    except (OSError, ValueError, AttributeError, HbvsError):
        return False


def _run_stage(stage: str, options_class: type, values: dict[str, Any]) -> None:
    """``run_<stage>`` of ``hbvs_cli.stages.<stage>``, imported only now; a non-zero int return is the exit code.
    A stage whose stdin input is an empty pipe stops with :class:`UpstreamFailedError` (one error line per pipeline)."""
    reads_stdin = any(value == "-" or (isinstance(value, (list, tuple)) and "-" in value)
                      for value in map(values.get, INPUT_OPTIONS))
    if reads_stdin and _stdin_is_an_empty_pipe():
        raise UpstreamFailedError("stdin: the pipe closed without data: the command before this one failed")
    module = importlib.import_module(f"hbvs_cli.stages.{stage}")
    quiet = values.pop("quiet", False)
    options = options_from_command_line(options_class, values)
    code = getattr(module, f"run_{stage}")(options, Console(quiet))
    if isinstance(code, int) and code:
        raise typer.Exit(code)


#: Each stage's command: name, help panel, its options class, extra options, help.
STAGE_COMMANDS = (
    ("teach", "Pipeline", TeachOptions, (_quiet("progress or messages"),),
     "Record a taught run into MCAP: images, calibration, commands, ground truth (sim)."),
    ("fit", "Pipeline", FitOptions, (_quiet("progress or summary"),),
     "Fit the desired trajectory (Remark 1): H_d per frame, (theta_d, x_hd), splines, n*, d*."),
    ("repeat", "Pipeline", RepeatOptions, (_quiet("progress or summary"),),
     "Track the fitted trajectory: closed loop with a robot (--live) or in simulation (--sim), or open loop on a recording (--replay)."),
    ("robot-sim", "Robot", RobotSimOptions, (_quiet("progress or messages"),),
     "A stand-in robot in its own process: ROS 2 camera and /cmd_vel, for trying repeat --live."),
    ("report", "Pipeline", ReportOptions, (),
     "How well did the repeat follow the taught path, and did it converge?"),
    ("export", "Pipeline", ExportOptions, (_quiet("summary"),),
     "Write an hbvs file as a ROS 2 bag: /cmd_vel, poses, the taught path, /tf, images and CameraInfo."),
    ("info", "Files", InfoOptions, (),
     "What a file holds: kind, duration, frames, target, settings, and every topic with its message count and schema."),
    ("sweep", "Studies", SweepOptions, (_quiet("progress or messages"),),
     "Run many closed-loop repeats over a grid or samples of parameters, on Dask; summarize convergence.\n\n"
     f"Parameters of --vary and --set (unit or values): {parameter_names_text()}."),
)


def _add_stage_command(name: str, panel: str, options_class: type, extra: tuple[inspect.Parameter, ...], help_text: str) -> None:
    stage = name.replace("-", "_")

    def command(**values: Any) -> None:
        _run_stage(stage, options_class, values)

    command.__name__, command.__doc__ = stage, help_text
    app.command(name, rich_help_panel=panel)(with_settings(command, settings_of(options_class), *extra))


for _command in STAGE_COMMANDS:
    _add_stage_command(*_command)


@app.command()
def demo(
    output: Annotated[Path, typer.Option("-o", "--output", help="Folder for every file the demo writes.")] = Path("hbvs-demo"),
    out: Annotated[Optional[Path], typer.Option("--out", hidden=True, help="Old name of --output.")] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="Only the final report.")] = False,
) -> None:
    """Teach, fit, repeat under both laws and report: the whole method in one command."""
    from ..stages.demo import run_demo

    code = run_demo(out if out is not None else output, Console(quiet))
    if code:
        raise typer.Exit(code)


_STOP_SIGNALS = {signal.SIGINT: (130, "interrupted"), signal.SIGTERM: (143, "terminated")}
#: True when a stop signal's exception was raised inside a finaliser and dropped there.
_swallowed = False


#: How long a process that spoke DDS may take to end (s) once its command returned (three times this after a stop
#: signal); past it, SIGALRM ends it (exit status 142). A backstop: :func:`_end_without_dds_teardown`.
DDS_EXIT_GRACE_S = 10.0


#: True when :func:`main` is the process's entry point (not called by a test with its arguments).
_owns_process = False


def _spoke_dds() -> bool:
    """Whether this process is hbvs's own (not a test calling :func:`main`) and loaded Cyclone DDS."""
    return _owns_process and "cyclonedds" in sys.modules


def _bound_dds_exit(grace_s: float) -> None:
    """End this process ``grace_s`` from now, whatever it waits for, if it spoke DDS."""
    if _spoke_dds():
        # A kernel timer, not a watchdog thread: faulthandler's made that teardown hang in 7 runs of 8.
        signal.signal(signal.SIGALRM, signal.SIG_DFL)
        signal.alarm(math.ceil(grace_s))


def _end_without_dds_teardown(code: int) -> None:
    """End a process of hbvs's that loaded Cyclone DDS now, with ``code``: the interpreter's teardown deletes the DDS
    domain, where Cyclone DDS 11 can wait without end (ddsi_stop waiting for its delivery queue). The command has
    returned, its files closed and its last zero acknowledged: nothing is left for the teardown to do."""
    if not _spoke_dds():
        return
    _bound_dds_exit(DDS_EXIT_GRACE_S)  # a flush into a pipe nobody reads
    for stream in (sys.stdout, sys.stderr, sys.__stdout__, sys.__stderr__):
        with suppress(OSError, ValueError, AttributeError):
            stream.flush()
    os._exit(code)


def _on_signal(signum: int, frame: object) -> None:
    """Stop the command by raising, so that partial files are removed; later signals are ignored."""
    _set_stop_handlers(signal.SIG_IGN)
    _bound_dds_exit(3 * DDS_EXIT_GRACE_S)  # the command's own cleanup first: zero commands, files closed
    stop_signals.stop(signum)


def _set_stop_handlers(handler: Any) -> None:
    for signum in _STOP_SIGNALS:
        with suppress(ValueError):  # not in the main thread: the signals keep their handlers
            signal.signal(signum, handler)


def _on_unraisable(unraisable: Any) -> None:
    """Keep quiet about a stop signal dropped inside a finaliser (:func:`main` reports it)."""
    global _swallowed
    if isinstance(unraisable.exc_value, (KeyboardInterrupt, stop_signals.Terminated)):
        _swallowed = True
        return
    sys.__unraisablehook__(unraisable)


def _stopped(signum: int) -> int:
    code, what = _STOP_SIGNALS[signum]
    _say(f"hbvs: {what}")
    return code


def _silence_stdout() -> None:
    """After a broken pipe, point stdout at /dev/null so interpreter shutdown stays quiet."""
    with suppress(OSError, ValueError, AttributeError):
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())


_stdout_at_start: tuple[int, int] | None = None


def _stdout_became_devnull() -> bool:
    now = file_identity(1)
    return now is not None and now == file_identity(os.devnull) and now != _stdout_at_start


def _say(line: str) -> None:
    """One line on stderr; a closed or broken stderr is no reason for a traceback."""
    with suppress(OSError, ValueError, AttributeError):
        sys.stderr.write(line + "\n")
        sys.stderr.flush()


def _pipe_closed() -> int:
    """The reader of stdout went away (``| head``): exit 141 without a word, as a process killed by SIGPIPE would."""
    _silence_stdout()
    return 141


#: errno values that mean "the output could not be written" (exit 6).
_WRITE_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO, errno.EBADF, errno.EROFS}


def _live_port_given(args: list[str]) -> list[str]:
    """``--foxglove`` without a port means Foxglove's default (typer has no optional values)."""
    if "--foxglove" not in args:
        return args
    from ..io.live_view import DEFAULT_PORT

    args = list(args)
    for index, token in enumerate(args):
        if token == "--":
            break
        if token == "--foxglove" and not (index + 1 < len(args) and args[index + 1].isdigit()):
            args.insert(index + 1, str(DEFAULT_PORT))
            break
    return args


def _run(args: list[str], debug: bool) -> int:
    """Run the app; every error but a stop signal becomes one line and its exit code."""
    try:
        result = app(args=_live_port_given(args), prog_name="hbvs", standalone_mode=False)
        return result if isinstance(result, int) else 0
    except typer.Abort:
        _say("hbvs: interrupted")
        return 130
    except typer.TyperException as exc:  # usage errors (typer's vendored click)
        if type(exc).__name__ == "NoArgsIsHelpError":  # `hbvs` alone: the help is what was asked for
            exc.show()
            return int(getattr(exc, "exit_code", 2))
        if debug:
            traceback.print_exc()
        if hasattr(exc, "format_message"):
            _say(unquoted_glob_hint(args) or one_line_usage_error(exc))
        else:
            _say("hbvs: error: " + " ".join(str(exc).split()))
        return int(getattr(exc, "exit_code", 2))
    except SystemExit as exc:
        # typer and rich answer a broken pipe with status 1, after wrapping or redirecting stdout.
        if exc.code == 1 and (type(sys.stdout).__name__ == "PacifyFlushWrapper" or _stdout_became_devnull()):
            return _pipe_closed()
        raise
    except BrokenPipeError:
        return _pipe_closed()
    except MemoryError:
        if debug:
            traceback.print_exc()
        _say("hbvs: error: out of memory (a limit is set too high for this machine? see hbvs --limit)")
        return 7
    except Exception as exc:  # noqa: BLE001 - the last line of defence: no traceback for users
        stop_signals.raise_if_stopped()
        if debug:
            traceback.print_exc()
        return _error_exit(exc, debug)


def _error_exit(exc: Exception, debug: bool) -> int:
    """The exit code of an error that reached :func:`_run` (an :class:`HbvsError`'s own), after its line on stderr."""
    if isinstance(exc, HbvsError):
        if exc.exit_code == 141:
            return _pipe_closed()
        if debug or not isinstance(exc, UpstreamFailedError):  # else the stage before said why: a line would repeat it
            _say(f"hbvs: error: {exc}")
        return exc.exit_code
    if isinstance(exc, OSError) and exc.errno == errno.EPIPE:
        return _pipe_closed()
    if isinstance(exc, OSError) and exc.errno in _WRITE_ERRNOS:
        _say(f"hbvs: error: {exc.filename or 'the output'}: cannot write ({exc.strerror})")
        return 6
    if debug and not isinstance(exc, OSError):
        return 70
    text = str(exc) if isinstance(exc, OSError) else " ".join(str(exc).split())[:300]
    _say(f"hbvs: internal error: {type(exc).__name__}: {text} (run with --debug for the traceback, and please report it)")
    return 70


class _ClosedStream:
    """What sys.stdin or sys.stdout (``fd`` 1: its descriptor, which holds /dev/null) is when hbvs was started with
    it closed: reading or writing it raises ``error`` saying ``message``."""

    encoding = "utf-8"

    def __init__(self, error: type[HbvsError], message: str, fd: int | None = None) -> None:
        self.error, self.message, self.fd = error, message, fd

    def _closed(self, *args: Any) -> Any:
        raise self.error(self.message)

    read = readline = write = _closed
    buffer = property(_closed)

    def fileno(self) -> int:
        return self._closed() if self.fd is None else self.fd

    def isatty(self) -> bool:
        return False

    def flush(self) -> None:
        pass


def _occupy_closed_stdio() -> set[int]:
    """Occupy closed standard descriptors with ``/dev/null`` (else the next file opened would
    become "stdout"); returns them."""
    closed = set()
    for fd in (0, 1, 2):
        try:
            os.fstat(fd)
        except OSError:
            try:
                opened = os.open(os.devnull, os.O_RDWR)
            except OSError:
                continue
            if opened != fd:
                os.dup2(opened, fd)
                os.close(opened)
            closed.add(fd)
    return closed


def _prepare_stdio(debug: bool) -> None:
    """Before any command: closed stdio made safe; unless ``--debug``, native stderr captured and warnings hidden."""
    global _stdout_at_start
    closed = _occupy_closed_stdio()
    _stdout_at_start = file_identity(1)
    if sys.stdin is None or 0 in closed:
        sys.stdin = _ClosedStream(InputError, "stdin: it is closed; give the input as a file instead of -")
    if sys.stdout is None or 1 in closed:
        sys.stdout = _ClosedStream(OutputError, "stdout: it is closed; give a file with -o, or redirect stdout", 1)
    if sys.stderr is None or 2 in closed:
        sys.stderr = open(os.devnull, "w", encoding="utf-8")  # noqa: SIM115
    if not debug:
        warnings.simplefilter("ignore")
        capture()


def main(argv: list[str] | None = None) -> None:
    """Console-script entry point; always raises SystemExit. SIGINT and SIGTERM exit 130 and 143; after the command they are ignored."""
    global _owns_process
    _owns_process = argv is None
    # OpenBLAS on one thread unless the user set it (hbvs's matrices are small): before numpy is imported.
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    # --debug may stand anywhere (hbvs teach ... --debug): the parser never sees it.
    args, debug = split_debug(list(sys.argv[1:] if argv is None else argv))
    _prepare_stdio(debug)
    sys.unraisablehook = _on_unraisable
    _set_stop_handlers(_on_signal)
    try:
        try:
            code = _run(args, debug)
        finally:
            _set_stop_handlers(signal.SIG_IGN)
    except KeyboardInterrupt:
        code = _stopped(signal.SIGINT)
    except stop_signals.Terminated:
        code = _stopped(signal.SIGTERM)
    else:
        # typer turns a KeyboardInterrupt into exit code 130 without a word.
        received = stop_signals.received
        if received is not None and (_swallowed or (received == signal.SIGINT and code == 130)):
            code = _stopped(received)
    try:
        sys.stdout.flush()
    except BrokenPipeError:
        if code == 0:
            code = _pipe_closed()
        else:
            _silence_stdout()
    except (OSError, ValueError, AttributeError):
        pass
    _end_without_dds_teardown(code)
    sys.exit(code)
