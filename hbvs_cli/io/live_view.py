"""``hbvs repeat --foxglove [PORT]``: every message of the run file (same bytes, schema and log time)
also served by the Foxglove SDK's WebSocket server on localhost, a simulated run paced to
``--foxglove-speed`` times real time."""

from __future__ import annotations

import threading
import time
from contextlib import contextmanager, suppress
from typing import Any, Iterator

from ..errors import UsageError

#: Foxglove's default WebSocket port (what the app proposes).
DEFAULT_PORT = 8765
INSTALL_HINT = "--foxglove needs the Foxglove SDK: pip install 'hbvs[live]'"
#: Paces a live view may have (times real time): beyond them the sleeps overflow or do nothing.
MIN_SPEED, MAX_SPEED = 1e-3, 1e6


class LiveMirror:
    """An McapWriter look-alike that writes through to ``writer`` and logs on ``context``'s
    server, a message at log time ``t`` no earlier than ``t / speed`` s after the first (0: unpaced)."""

    def __init__(self, writer: Any, context: Any, speed: float = 1.0) -> None:
        self._writer = writer
        self._context = context
        self._speed = float(speed)
        self._channels: dict[str, Any] = {}
        self._start: tuple[float, int] | None = None

    def __getattr__(self, name: str) -> Any:
        # metadata, flush, finish, input_ended_early...: the file's business only.
        return getattr(self._writer, name)

    def write(self, topic: str, schema_name: str, log_time_ns: int, message: Any) -> None:
        self._log(topic, log_time_ns, self._writer.write(topic, schema_name, log_time_ns, message))

    def write_encoded(self, topic: str, schema_name: str, log_time_ns: int, data: bytes) -> None:
        self._writer.write_encoded(topic, schema_name, log_time_ns, data)
        self._log(topic, log_time_ns, data)

    def _log(self, topic: str, log_time_ns: int, data: bytes) -> None:
        channel = self._channels.get(topic)
        if channel is None:
            # The channel as the file declares it (McapWriter.channels).
            _, name, encoding, schema_data, message_encoding = self._writer.channels[topic]
            import foxglove  # there: live_writer made this mirror after importing it
            schema = foxglove.Schema(name=name, encoding=encoding, data=schema_data)
            channel = self._channels[topic] = foxglove.Channel(topic, schema=schema, message_encoding=message_encoding, context=self._context)
        self._pace(int(log_time_ns))
        channel.log(bytes(data), log_time=int(log_time_ns))

    def _pace(self, log_time_ns: int) -> None:
        if self._speed <= 0:
            return
        now = time.monotonic()
        if self._start is None:
            self._start = (now, log_time_ns)
            return
        due = self._start[0] + (log_time_ns - self._start[1]) * 1e-9 / self._speed
        if due > now:
            time.sleep(due - now)


#: Longest wait for the server to stop (s): a client that stopped reading can hold it forever.
STOP_SECONDS = 1.0


def stop_within(stop: Any, seconds: float) -> bool:
    """Call ``stop()`` on a daemon thread and wait at most ``seconds`` (a timed join, which a stop
    signal interrupts); True when it returned in time."""
    def quietly() -> None:
        with suppress(Exception):  # a server that fails to stop cleanly is stopped enough
            stop()

    thread = threading.Thread(target=quietly, name="hbvs-live-stop", daemon=True)
    thread.start()
    thread.join(seconds)
    return not thread.is_alive()


@contextmanager
def live_writer(port: int | None, speed: float = 1.0, announce: Any = None) -> Iterator[Any]:
    """A function that wraps the run file's writer: the identity when ``port`` is None, else in a
    :class:`LiveMirror` of a server started here on 127.0.0.1:``port``; ``announce`` gets where to connect."""
    if port is None:
        yield lambda writer: writer
        return
    try:
        import foxglove
    except ImportError:
        raise UsageError(INSTALL_HINT) from None
    if not 0 <= int(port) <= 65535:
        raise UsageError(f"--foxglove: the port must be 0-65535, got {port}")
    if not (speed == 0 or MIN_SPEED <= speed <= MAX_SPEED):
        raise UsageError(f"--foxglove-speed must be 0 (as fast as it goes) or from {MIN_SPEED:g} to {MAX_SPEED:g} times real time, got {speed}")
    context = foxglove.Context()
    try:
        server = foxglove.start_server(name="hbvs repeat", host="127.0.0.1", port=int(port), context=context)
    except Exception as exc:  # the SDK raises its own error types for a port in use
        raise UsageError(f"--foxglove: cannot serve on 127.0.0.1:{port} ({str(exc).splitlines()[0][:120]})") from None
    try:
        if announce is not None:
            announce(f"live view: connect Foxglove to ws://127.0.0.1:{server.port} (Open connection, Foxglove WebSocket)")
        yield lambda writer: LiveMirror(writer, context, speed)
    finally:
        stop_within(server.stop, STOP_SECONDS)
