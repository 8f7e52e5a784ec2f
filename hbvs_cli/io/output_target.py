"""How every output of hbvs is written, so that what a user points hbvs at is never lost: a regular file
is written as ``NAME.<pid>-<random>.partial``, fsynced and renamed over ``NAME`` only when complete;
``-`` is stdout; a device, FIFO or socket is written in place."""

from __future__ import annotations

import codecs
import errno
import fcntl
import os
import re
import shutil
import stat
import sys
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import IO, Any, Callable, Iterator, Sequence

from . import ClosedOnExit
from ..errors import HbvsError, InputError, OutputError, PipeClosedError, TruncatedInputError, UsageError

#: hbvs's partial names: the final name, the writer's pid and 8 hex digits (:func:`partial_name_of`).
_PARTIAL_NAME = re.compile(r"^(?P<final>.+)\.(?P<pid>\d+)-[0-9a-f]{8}\.partial$")
#: Linux's largest pid when /proc/sys/kernel/pid_max cannot be read (2^22).
PID_MAX_FALLBACK = 1 << 22


def resolve_output(spec: str | os.PathLike[str], what: str = "output") -> tuple[str, Path | None]:
    """How ``spec`` is written (nothing is opened): ``("stdout", None)``, ``("file", the file finally written)``
    (atomically) or ``("stream", path)`` (in place); :class:`InputError` for a directory, :class:`OutputError`
    for a missing folder."""
    text = os.fspath(spec)
    if text == "-":
        return "stdout", None
    given = Path(text)
    try:
        status = os.stat(given)  # follows every symbolic link, /dev/stdout's magic one too
    except FileNotFoundError:
        # A new file, or a dangling symbolic link whose target will be created.
        path = Path(os.path.realpath(given))
        if not path.parent.is_dir():
            raise OutputError(f"{given}: the folder {path.parent} does not exist") from None
        return "file", path
    except OSError as exc:
        raise InputError(f"{given}: cannot write the {what} ({exc.strerror})") from None
    if stat.S_ISDIR(status.st_mode):
        raise InputError(f"{given}: is a directory; give a file name for the {what}")
    path = Path(os.path.realpath(given))
    # /dev/stdout, /dev/fd/N and /proc/self/fd/N name an open descriptor: written in place, whatever they lead to.
    through_proc = path.parts[1:2] == ("proc",)
    if stat.S_ISREG(status.st_mode) and not through_proc:
        return "file", path
    return "stream", given


def partial_name_of(final: Path) -> Path:
    """A fresh partial name beside ``final``, unique to this process and call."""
    return final.with_name(f"{final.name}.{os.getpid()}-{os.urandom(4).hex()}.partial")


def replace_through_partial(path: Path, write: Callable[[Path], Any]) -> None:
    """Write ``path`` whole or not at all: ``write(partial)`` on a partial file of this process, then a rename."""
    partial = partial_name_of(path)
    try:
        write(partial)
        os.replace(partial, path)
    except BaseException:
        partial.unlink(missing_ok=True)
        raise


@contextmanager
def atomic_folder(final: Path, what: str, before_swap: Callable[[Path], None] = lambda work: None) -> Iterator[Path]:
    """A fresh path named as ``final`` (its suffix kept) in a partial folder beside it; renamed over ``final``
    when the body succeeds, under the parent folder's lock, after ``before_swap(partial folder)`` (which may
    refuse, or move an old ``final`` aside into it). ``what`` names the output in the errors."""
    work = partial_name_of(final)
    try:
        work.mkdir()
    except OSError as exc:
        raise InputError(f"{final}: cannot write the {what} ({exc.strerror})") from None
    try:
        yield work / final.name
        with directory_lock(final.parent):
            before_swap(work)
            try:
                os.replace(work / final.name, final)
            except OSError as exc:
                raise OutputError(f"{final}: cannot write the {what} ({exc.strerror})") from None
    finally:
        shutil.rmtree(work, ignore_errors=True)


def stale_partial(path: Path) -> bool:
    """True when ``path`` is a partial file or folder of hbvs whose process is gone: its name is
    one :func:`partial_name_of` gives (8 hex digits), its pid one this system can give (at most
    /proc/sys/kernel/pid_max) and not alive, this user owns it, and a folder (an export's) holds
    nothing but the bag it was writing and the bag it replaced. A user's folder named alike
    (``P.99999-cafe.partial``, ``P.4000000-ab.partial``) is kept."""
    match = _PARTIAL_NAME.match(path.name)
    if match is None:
        return False
    pid_max = PID_MAX_FALLBACK
    with suppress(OSError, ValueError):
        pid_max = int(Path("/proc/sys/kernel/pid_max").read_text().strip())
    if int(match.group("pid")) == os.getpid() or not 0 < int(match.group("pid")) <= pid_max:
        return False
    try:
        status = os.lstat(path)
        if status.st_uid != os.getuid():
            return False
        if stat.S_ISDIR(status.st_mode):
            if not all(entry.name in (match.group("final"), "replaced") for entry in path.iterdir()):
                return False
        elif not stat.S_ISREG(status.st_mode):
            return False
        os.kill(int(match.group("pid")), 0)
    except ProcessLookupError:
        return True
    except (OverflowError, OSError):
        pass  # unreadable, alive under another user, or not a pid this system has: keep it
    return False


def remove_stale_partials(paths: Any) -> list[Path]:
    """Remove the stale partial files and folders (:func:`stale_partial`) among ``paths``."""
    removed = []
    for path in paths:
        path = Path(path)
        if not stale_partial(path):
            continue
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            _remove_quietly(path)
        removed.append(path)
    return removed


@contextmanager
def directory_lock(folder: Path) -> Iterator[None]:
    """Hold an advisory ``flock`` on ``folder`` itself for a short critical section."""
    fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_CLOEXEC", 0))
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


class FolderLock(ClosedOnExit):
    """One writer at a time for an output folder: a ``flock`` on ``lock_path`` (never deleted, so
    that two processes never lock different files); :class:`OutputError` naming the holder's pid."""

    def __init__(self, lock_path: Path, what: str) -> None:
        self.path = Path(lock_path)
        try:
            self._fd: int | None = os.open(self.path, os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), 0o644)
        except OSError as exc:
            raise OutputError(f"{self.path}: cannot create the lock of {what} ({exc.strerror})") from None
        try:
            fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            holder = ""
            with suppress(OSError):  # the holder's pid, as it wrote it below
                holder = os.pread(self._fd, 32, 0).decode("ascii", "replace").strip()
            os.close(self._fd)
            self._fd = None
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                by = f" (pid {holder})" if holder else ""
                raise OutputError(f"{what} is being written by another hbvs process{by}; wait for it to end, or give another output") from None
            raise OutputError(f"{self.path}: cannot lock {what} ({exc.strerror})") from None
        os.ftruncate(self._fd, 0)
        os.write(self._fd, f"{os.getpid()}\n".encode())

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing the descriptor drops the lock
            self._fd = None


def file_identity(file: int | str, regular: bool = False) -> tuple[int, int] | None:
    """(device, inode) of a path or descriptor (``regular``: only when it is a regular file); None if it cannot be looked at."""
    try:
        status = os.stat(file)
    except OSError:
        return None
    return (status.st_dev, status.st_ino) if not regular or stat.S_ISREG(status.st_mode) else None


def refuse_overwriting_inputs(
    outputs: Sequence[tuple[str, str | os.PathLike[str] | None]],
    inputs: Sequence[tuple[str, str | os.PathLike[str] | None]],
) -> None:
    """:class:`UsageError` for an output (a (label, path or None) pair) that is the same file as an input
    (stdout redirected included), the final file of an input's partial file, or another output."""
    known: dict[tuple[int, int], str] = {}
    recovering: dict[Path, str] = {}
    for label, spec in inputs:
        if spec is None or os.fspath(spec) == "-":
            continue
        text = os.fspath(spec)
        identity = file_identity(text)
        if identity is not None:
            known.setdefault(identity, f"the {label} {text}")
        # A partial file (a.mcap.<pid>-<hex>.partial) belongs to its final file (a.mcap).
        real = Path(os.path.realpath(text))
        match = _PARTIAL_NAME.match(real.name)
        if match is not None:
            recovering[real.with_name(match.group("final"))] = f"the {label} {text}"
    written: dict[Any, str] = {}
    for label, spec in outputs:
        if spec is None:
            continue
        text = os.fspath(spec)
        identity = file_identity(1, regular=True) if text == "-" else file_identity(text)  # stdout redirected to a file
        real = Path(os.path.realpath(text))
        key: Any = ("stdout",) if text == "-" else identity or real
        if identity is not None and identity in known:
            where = "stdout" if text == "-" else f"{label} {text}"
            raise UsageError(f"{where} is the same file as {known[identity]}: hbvs would overwrite its own input; write to another file")
        if text != "-" and real in recovering:
            raise UsageError(
                f"{label} {text} is the file that {recovering[real]} (a partial file of an interrupted run) "
                "belongs to; write the result to another name"
            )
        if key in written:
            raise UsageError(f"{label} {text} and {written[key]} are the same file; give them different names")
        written[key] = f"{label} {text}"


#: Bytes a stage's stdout holds back until it flushes or writes more: a stage that fails
#: before (a missing input) writes nothing, so the next stage in a pipeline sees an empty
#: pipe and stays silent (exit 9) instead of adding a second error line.
STDOUT_HOLD_BYTES = 1 << 16


class GuardedStream(ClosedOnExit):
    """A binary write stream reporting OS errors as hbvs errors; ``tell()`` counts bytes (a pipe cannot seek).
    With ``hold`` the first bytes wait in memory until more than :data:`STDOUT_HOLD_BYTES` are written or
    :meth:`flush` is called; :meth:`discard` drops them (the stage failed)."""

    def __init__(self, raw: IO[bytes], what: str, owned: bool, atomic: bool = False, hold: bool = False) -> None:
        self.closed = False
        self._atomic = atomic
        self._raw = raw
        self._what = what
        self._owned = owned
        self._count = 0
        self._held: bytearray | None = bytearray() if hold else None

    @contextmanager
    def reported(self) -> Iterator[None]:
        """OS errors of the underlying stream (or its descriptor) as hbvs errors."""
        try:
            yield
        except OSError as exc:
            if exc.errno == errno.EPIPE or isinstance(exc, BrokenPipeError):
                raise PipeClosedError(f"{self._what}: the reader closed the pipe") from None
            if exc.errno == errno.EBADF:
                raise OutputError(f"{self._what}: the stream is closed") from None
            reason = exc.strerror or str(exc) or type(exc).__name__
            if exc.errno in (errno.ENOSPC, errno.EDQUOT):
                reason = "no space left on the device"
            kept = "; an earlier file of that name is left as it was" if self._atomic else ""
            raise OutputError(f"{self._what}: cannot write ({reason}){kept}") from None
        except ValueError:  # the underlying stream was closed (stdout closed by a library)
            raise OutputError(f"{self._what}: the stream is closed") from None

    def _write_raw(self, view: Any) -> None:
        with self.reported():
            self._raw.write(view)

    def _release(self) -> None:
        held, self._held = self._held, None
        if held:
            self._write_raw(memoryview(held))

    def discard(self) -> None:
        """Drop the bytes still held back (nothing of a failed stage reaches the reader)."""
        if self._held is not None:
            self._held = bytearray()

    def write(self, data: Any) -> int:
        view = memoryview(data).cast("B")
        if self._held is not None:
            self._held += view
            if len(self._held) > STDOUT_HOLD_BYTES:
                self._release()
        else:
            self._write_raw(view)
        self._count += len(view)
        return len(view)

    def tell(self) -> int:
        return self._count

    def flush(self) -> None:
        self._release()
        with self.reported():
            self._raw.flush()

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            self.flush()
        finally:
            if self._owned:
                with self.reported():
                    self._raw.close()


class OutputSink:
    """What :func:`open_output_stream` yields: the stream, and whether it may be committed."""

    def __init__(self, stream: GuardedStream, spec: str, replaces: Path | None) -> None:
        self.stream = stream
        self._spec = spec
        self._replaces = replaces  # the file an atomic write replaces (None: stdout, a stream)
        self._truncated_input: str | None = None

    def input_ended_early(self, name: str, allow: bool) -> None:
        """Record that an input ended before its end record: its result then replaces an
        existing file only with ``allow`` (:class:`TruncatedInputError` at once otherwise)."""
        self._truncated_input = None if allow else name
        self.check_commit()  # fail now, before the work, when the output is there already

    def check_commit(self) -> None:
        """Raise :class:`TruncatedInputError` when the output must not replace what is there."""
        if self._truncated_input and self._replaces is not None and self._replaces.exists():
            raise TruncatedInputError(
                f"{self._truncated_input} ended before its end record (the writer upstream stopped?), so its "
                f"result did not replace the existing {self._spec}; pass --allow-truncated to replace it"
            )


@contextmanager
def open_output_stream(spec: str | os.PathLike[str], what: str = "output",
                       keep_on_error: bool = False) -> Iterator[OutputSink]:
    """Yield an :class:`OutputSink` on ``spec``, committed when the body succeeds; ``what`` names the output
    in messages. ``keep_on_error``: committed also when the body fails (a record of what a robot was sent
    outlives the run's failure), then the failure raised."""
    kind, final = resolve_output(spec, what)
    label = "stdout" if kind == "stdout" else os.fspath(spec)
    if kind == "stdout":
        # A closed stdout is the command line's stand-in (cli.app), which says so.
        sink = OutputSink(GuardedStream(sys.stdout.buffer, "stdout", owned=False, hold=True), "-", None)
        try:
            yield sink
        except HbvsError:
            # The stage failed (and says why): the little it held back is no file, unless it is
            # kept on errors (a live run's record). A stop signal keeps what was written, the
            # start of a recording.
            if keep_on_error:
                sink.stream.flush()
            else:
                sink.stream.discard()
            raise
        sink.stream.flush()
        return
    assert final is not None
    atomic = kind == "file"
    mode = None  # an earlier file's, which the new one keeps
    if atomic:
        with suppress(OSError):
            mode = stat.S_IMODE(os.stat(final).st_mode)
        temporary = partial_name_of(final)
        try:
            fd = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), 0o666)
        except OSError as exc:
            raise InputError(f"{label}: cannot write ({exc.strerror})") from None
        except BaseException:
            # A signal can land after the file was created but before `fd` was bound.
            _remove_quietly(temporary)
            raise
    else:
        try:
            # A regular file reached through /proc/self/fd is truncated, as a shell's > would.
            regular = stat.S_ISREG(os.stat(final).st_mode)
            fd = os.open(final, os.O_WRONLY | getattr(os, "O_CLOEXEC", 0) | (os.O_TRUNC if regular else 0))
        except OSError as exc:
            raise OutputError(f"{label}: cannot write the {what} ({exc.strerror})") from None
    try:
        handle = os.fdopen(fd, "wb")
        sink = OutputSink(GuardedStream(handle, label, owned=True, atomic=atomic), label, final if atomic else None)
        failure: BaseException | None = None
        with sink.stream:  # closing flushes
            try:
                yield sink
                sink.check_commit()
            except BaseException as exc:
                if not keep_on_error:
                    raise
                failure = exc
            sink.stream.flush()
            with sink.stream.reported():
                if mode is not None:
                    os.fchmod(handle.fileno(), mode)
                if atomic:
                    os.fsync(handle.fileno())
        if atomic:
            try:
                os.replace(temporary, final)
            except OSError as exc:
                raise OutputError(f"{label}: cannot put the finished {what} in place ({exc.strerror})") from None
        if failure is not None:
            raise failure
    except BaseException:
        if atomic:
            _remove_quietly(temporary)
        raise


def _remove_quietly(path: Path) -> None:
    with suppress(OSError):
        path.unlink()


@contextmanager
def open_text_output(spec: str | os.PathLike[str] | None, what: str, keep_on_error: bool = False) -> Iterator[Any]:
    """A UTF-8 text stream on :func:`open_output_stream` (None yields None): for JSON lines."""
    if spec is None:
        yield None
        return
    with open_output_stream(spec, what, keep_on_error=keep_on_error) as sink:
        yield codecs.getwriter("utf-8")(sink.stream)


def write_output_bytes(spec: str | os.PathLike[str], data: bytes, what: str) -> None:
    """Write ``data`` whole to ``spec`` with :func:`open_output_stream`."""
    with open_output_stream(spec, what) as sink:
        sink.stream.write(data)
