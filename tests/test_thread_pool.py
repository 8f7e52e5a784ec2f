"""``hbvs_cli.thread_pool.StopSafePool``: a stop signal during its exit leaves its threads
truthfully alive and joinable, where ``ThreadPoolExecutor``'s join marked a running thread
finished (bpo-45274; the interpreter's exit then aborted the process)."""

from __future__ import annotations

import signal
import threading
from concurrent.futures import ThreadPoolExecutor

import pytest

from hbvs_cli.thread_pool import StopSafePool


def interrupted_exit(pool_class) -> tuple[bool, threading.Thread]:
    """Whether the pool's worker was alive after a signal (SIGALRM raising KeyboardInterrupt)
    cut short the pool's ``with`` exit while it was busy; the worker, let finish and shut down."""
    release = threading.Event()

    def on_alarm(signum, frame):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGALRM, on_alarm)
    try:
        signal.setitimer(signal.ITIMER_REAL, 0.2)
        with pytest.raises(KeyboardInterrupt):
            with pool_class(max_workers=1, thread_name_prefix="hbvs-test") as pool:
                pool.submit(release.wait, 10.0)
                worker = next(iter(pool._threads))
        alive_after_the_signal = worker.is_alive()
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
        release.set()
    pool.shutdown(wait=True)
    return alive_after_the_signal, worker


def test_a_signal_during_the_exit_leaves_the_busy_worker_alive_and_joinable():
    alive, worker = interrupted_exit(StopSafePool)
    assert alive and not worker.is_alive()


def test_the_plain_pool_calls_its_busy_worker_finished():
    """What StopSafePool avoids: the join that the signal interrupts marks the worker stopped."""
    alive, _ = interrupted_exit(ThreadPoolExecutor)
    assert not alive


def test_results_are_not_held_after_their_futures_finish():
    with StopSafePool(max_workers=1, thread_name_prefix="hbvs-test") as pool:
        futures = [pool.submit(pow, 2, k) for k in range(50)]
        assert [f.result() for f in futures] == [2**k for k in range(50)]
        assert not pool._unfinished
