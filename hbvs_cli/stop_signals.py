"""Stop signals (SIGINT, SIGTERM) as exceptions, raised again where native code swallowed them.

The CLI's handler raises at once (:func:`stop`), so that partial files are removed and a robot
is sent its zero commands. A native extension that clears Python's errors (some do, between
attempts) can swallow that exception, and the command would run on to its end: the long
loops call :func:`raise_if_stopped` once a step to raise it again (those with a progress bar
through its step, :meth:`~hbvs_cli.stages.console.ProgressTask.advance`).
"""

from __future__ import annotations

import signal


class Terminated(BaseException):
    """Raised for SIGTERM, so that cleanup (partial files) runs."""


class Interrupted(KeyboardInterrupt):
    """Raised for SIGINT (CPython ends the process when exactly KeyboardInterrupt escapes some
    of its C entry points, even if handled later)."""


#: The stop signal received, or None.
received: int | None = None


def stop(signum: int) -> None:
    """Record the stop signal ``signum`` and raise its exception (:func:`raise_if_stopped`)."""
    global received
    received = signum
    raise_if_stopped()


def raise_if_stopped() -> None:
    """Raise the exception of a stop signal received, if one was (also where native code
    turned it into another exception)."""
    if received == signal.SIGINT:
        raise Interrupted
    if received is not None:
        raise Terminated
