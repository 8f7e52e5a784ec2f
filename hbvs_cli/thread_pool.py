"""A thread pool that a stop signal cannot leave with a thread running unjoined: a signal's
exception inside ``Thread.join`` makes CPython mark a running thread finished (bpo-45274),
and the interpreter's exit then kills it in native code (OpenCV): the process aborts. Waiting
on the futures first, which a signal interrupts harmlessly, leaves the join finished threads.
"""

from __future__ import annotations

import threading
from concurrent.futures import Future, ThreadPoolExecutor, wait
from typing import Any


class StopSafePool(ThreadPoolExecutor):
    """``ThreadPoolExecutor`` whose ``with`` exit waits for the work not yet done, then joins."""

    def __init__(self, max_workers: int, thread_name_prefix: str) -> None:
        super().__init__(max_workers=max_workers, thread_name_prefix=thread_name_prefix)
        self._unfinished: set[Future[Any]] = set()
        self._lock = threading.Lock()

    def submit(self, fn: Any, /, *args: Any, **kwargs: Any) -> Future[Any]:
        future = super().submit(fn, *args, **kwargs)
        with self._lock:
            self._unfinished.add(future)
        future.add_done_callback(self._finished)  # only the unfinished are held: not their results
        return future

    def _finished(self, future: Future[Any]) -> None:
        with self._lock:
            self._unfinished.discard(future)

    def __exit__(self, *exc_info: Any) -> Any:
        with self._lock:
            unfinished = list(self._unfinished)
        wait(unfinished)
        return super().__exit__(*exc_info)
