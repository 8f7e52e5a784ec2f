"""Where the runs execute (docs/sweeps.md, "Engine"): a Dask cluster, in batches (:class:`BatchSizer`),
at most ``in_flight`` at once; what fails is retried as :func:`run_tasks` says."""

from __future__ import annotations

import itertools
import logging
import os
import re
import time
from collections import Counter, deque
from contextlib import ExitStack, contextmanager
from typing import Any, Callable, Iterable, Iterator, Sequence

from ..errors import OutputError, UsageError

INSTALL_HINT = "pip install 'hbvs[sweep]'"
#: Times a run may be rescheduled after its worker died before it is recorded as failed.
ALLOWED_WORKER_DEATHS = 3


def require_engine() -> None:
    """Raise a one-line :class:`UsageError` when Dask distributed or pyarrow is missing."""
    missing = []
    for module in ("distributed", "pyarrow"):
        try:
            __import__(module)
        except ImportError:
            missing.append({"distributed": "dask[distributed]"}.get(module, module))
    if missing:
        raise UsageError(f"hbvs sweep needs {' and '.join(missing)}: {INSTALL_HINT}")


def default_workers() -> int:
    """One worker per core this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


#: The scheduler's HTTP routes without ``--dashboard``: its health check alone, on loopback.
HEALTH_ONLY = ["distributed.http.health"]


#: A host name: labels of letters, digits and hyphens, at least one letter (all digits would be
#: read as an IPv4 number: "0" is 0.0.0.0).
_HOST_NAME = re.compile(r"(?=.*[A-Za-z])[A-Za-z0-9](?:[A-Za-z0-9-]{0,61}[A-Za-z0-9])?(?:\.[A-Za-z0-9](?:[A-Za-z0-9-]{0,61}[A-Za-z0-9])?)*")


def dashboard_address(text: str | None) -> str | None:
    """``--dashboard``'s address: ``PORT`` is ``127.0.0.1:PORT``, ``HOST:PORT`` as given (HOST an IPv4
    address or a host name); any other spelling a :class:`UsageError` (docs/robustness.md, "dashboard")."""
    if text is None:
        return None
    import ipaddress

    usage = f"--dashboard must be PORT or HOST:PORT with HOST an IPv4 address or a host name (e.g. 8787 or 127.0.0.1:8787), got {text!r}"
    stripped = text.strip()
    if stripped.startswith("[") or re.fullmatch(r"[0-9A-Fa-f:]*::?[0-9A-Fa-f:]*:?\d+", stripped) and stripped.count(":") > 1:
        raise UsageError(f"{usage}: IPv6 addresses are not served; use 127.0.0.1 (or 0.0.0.0 for every interface)")
    host, sep, port = stripped.rpartition(":")
    if not sep:
        host = "127.0.0.1"
    if not port.isdigit() or int(port) > 65535:
        raise UsageError(usage)
    try:
        ipaddress.IPv4Address(host)
    except ValueError:
        if not _HOST_NAME.fullmatch(host):
            reason = " (it would listen on every interface: name 0.0.0.0 for that)" if host in ("0", "*", "") else ""
            raise UsageError(usage + reason) from None
    return f"{host}:{int(port)}"


def check_scheduler_address(address: str | None) -> None:
    """UsageError, before anything is written, for a ``--scheduler`` that is no Dask address."""
    if address is None:
        return
    from distributed.comm.addressing import get_address_host_port, parse_address
    from distributed.comm.registry import backends

    try:
        scheme, _ = parse_address(address, strict=False)
        if scheme not in backends:
            raise ValueError(f"unknown scheme {scheme!r}; known: {', '.join(sorted(backends))}")
        if scheme in ("tcp", "tls", "ws", "wss"):
            get_address_host_port(address)
    except (ValueError, TypeError) as exc:
        raise UsageError(f"--scheduler {address!r}: not a scheduler address such as tcp://HOST:8786 ({exc})") from None


@contextmanager
def dask_client(scheduler: str | None, cluster: str | None, workers: int | None,
                allowed_worker_deaths: int = ALLOWED_WORKER_DEATHS, dashboard: str | None = None) -> Iterator[Any]:
    """A connected ``distributed.Client``; the cluster it started (if any) is closed after."""
    import dask
    from distributed import Client, LocalCluster

    if scheduler is not None and cluster is not None:
        raise UsageError("--scheduler and --cluster exclude each other: connect to a running cluster, or start one")
    # worker-saturation 1: a run that kills its worker takes no queued batch with it. No
    # profiler, slow ticks (each takes the GIL from the run), glibc's malloc trimming.
    spawn_environ = {name: value for name, value in dask.config.get("distributed.nanny.pre-spawn-environ", {}).items()
                     if name != "MALLOC_TRIM_THRESHOLD_"}
    # A restarted worker must connect within the timeout, also on a loaded machine.
    with dask.config.set({"distributed.nanny.pre-spawn-environ": spawn_environ,
                          "distributed.scheduler.allowed-failures": allowed_worker_deaths,
                          "distributed.scheduler.worker-saturation": 1.0, "distributed.worker.profile.enabled": False,
                          "distributed.admin.tick.interval": "1s", "distributed.admin.system-monitor.interval": "1s",
                          "distributed.worker.memory.monitor-interval": "1s", "distributed.comm.timeouts.connect": "120s",
                          **({} if dashboard else {"distributed.scheduler.http.routes": HEALTH_ONLY})}):
        with ExitStack() as stack:  # the client closed first, then the cluster started
            if scheduler is not None:
                try:
                    client = Client(scheduler, timeout="20s")
                except (OSError, TimeoutError) as exc:
                    raise UsageError(f"--scheduler {scheduler}: cannot connect ({exc})") from None
                except (ValueError, TypeError) as exc:  # not an address: "missing port number", an unknown protocol
                    raise UsageError(f"--scheduler {scheduler!r}: not a scheduler address such as tcp://HOST:8786 ({exc})") from None
            else:
                started = _jobqueue_cluster(cluster, workers or 1) if cluster is not None else LocalCluster(
                    n_workers=workers or default_workers(), threads_per_worker=1, processes=True,
                    protocol="tcp://", host="127.0.0.1", dashboard_address=dashboard or "127.0.0.1:0",
                    scheduler_kwargs={"dashboard": dashboard is not None}, silence_logs=logging.ERROR,
                )
                stack.callback(started.close)
                client = Client(started)
            stack.callback(client.close)
            yield client


def _jobqueue_cluster(kind: str, jobs: int) -> Any:
    try:
        import dask_jobqueue
    except ImportError:
        raise UsageError(f"--cluster {kind} needs dask-jobqueue: pip install 'hbvs[sweep-cluster]'") from None
    cluster_class = {"slurm": dask_jobqueue.SLURMCluster, "pbs": dask_jobqueue.PBSCluster}[kind]
    # The rest (queue, account, walltime, memory) from ~/.config/dask/jobqueue.yaml.
    cluster = cluster_class(cores=1, processes=1)
    cluster.scale(jobs=jobs)
    return cluster


#: CPU time (s) a batch aims at: the per-task overhead paid rarely, a killed batch cheap.
BATCH_CPU_SECONDS = 1.0
#: ... and at most this much wall time (runs that wait rather than compute).
BATCH_WALL_SECONDS = 5.0
#: Most runs in one batch (short runs: a lost batch re-runs at most this many).
MAX_BATCH = 64


def run_batch(function: Callable[[Any], dict[str, Any]], tasks: Sequence[Any],
              started: str | None = None) -> tuple[list[dict[str, Any]], float, float]:
    """On a worker: ``function(task)`` for each task; the rows and the batch's wall and CPU
    time (s). ``started``: a metadata key set first (a worker death before it is not the run's)."""
    if started is not None:
        from distributed import get_client

        get_client().set_metadata(started, True)
    wall, cpu = time.perf_counter(), time.process_time()
    rows = [function(task) for task in tasks]
    return rows, time.perf_counter() - wall, time.process_time() - cpu


class BatchSizer:
    """How many runs the next batch gets: one until a batch came back, then about
    :data:`BATCH_CPU_SECONDS` at the mean so far, at most ``left / (2 x workers)`` (guided
    self-scheduling: the workers finish together)."""

    def __init__(self, total: int | None, workers: int) -> None:
        self.left, self.workers = total, max(1, workers)
        self.runs, self.wall, self.cpu = 0, 0.0, 0.0

    def observe(self, runs: int, wall: float, cpu: float) -> None:
        self.runs += runs
        self.wall += wall
        self.cpu += cpu

    def next_size(self) -> int:
        size = 1
        if self.runs:
            aims = ((BATCH_CPU_SECONDS, self.cpu), (BATCH_WALL_SECONDS, self.wall))
            size = max(1, int(min([MAX_BATCH] + [aim * self.runs / spent for aim, spent in aims if spent > 0])))
        if self.left is not None:
            size = max(1, min(size, self.left // (2 * self.workers)))
        return size

    def take(self, size: int) -> None:
        if self.left is not None:
            self.left = max(0, self.left - size)


#: Isolated attempts of a run whose workers keep dying before it starts, then recorded as failed.
MAX_UNSTARTED_ATTEMPTS = 5
#: Longest time (s) a sweep waits on a cluster without a worker before it stops (resumable).
NO_WORKER_SECONDS = 120.0


def _finished(completed: Any, client: Any, no_worker_seconds: float) -> Iterator[Any]:
    """``(future, result)`` as they complete; OutputError once the cluster had no worker for ``no_worker_seconds``."""
    without_workers: float | None = None
    while True:
        if completed.has_ready() or completed.is_empty():
            try:
                yield next(completed)
            except StopIteration:
                return
            without_workers = None
            continue
        time.sleep(0.1)
        if client.scheduler_info().get("workers"):
            without_workers = None
            continue
        now = time.monotonic()
        without_workers = without_workers if without_workers is not None else now
        if now - without_workers > no_worker_seconds:
            raise OutputError(
                f"the Dask cluster has had no worker for {no_worker_seconds:g} s (its workers died and were not restarted); "
                "the finished rows are kept: the same command resumes"
            )


def run_tasks(
    client: Any,
    tasks: Iterable[Any],
    function: Callable[[Any], dict[str, Any]],
    on_row: Callable[[dict[str, Any]], None],
    on_lost: Callable[[Any, str], dict[str, Any]],
    in_flight: int,
    key_prefix: str,
    total: int | None = None,
    no_worker_seconds: float = NO_WORKER_SECONDS,
) -> int:
    """Run ``function(task)`` for every task, ``on_row`` getting each row as it completes;
    returns the number of rows. A task that fails alone, then again in isolation after it
    started, gets ``on_lost(task, error)``. Worker deaths are counted, never time."""
    from distributed import as_completed

    pending = iter(tasks)
    alone: deque[Any] = deque()  # tasks of a failed batch, each to be run by itself
    suspects: deque[Any] = deque()  # tasks that failed alone, to be run once more in isolation
    waiting: dict[str, tuple[list[Any], bool]] = {}  # future key -> (its tasks, run in isolation)
    completed = as_completed(with_results=True, raise_errors=False)
    sizer = BatchSizer(total, len(client.scheduler_info().get("workers", {})))

    attempts: Counter[int] = Counter()  # isolated attempts per task index

    def submit(batch: list[Any], key: str, isolated: bool = False) -> None:
        if isolated:
            attempts[batch[0].index] += 1
            key = f"{key}{attempts[batch[0].index]}"
        future = client.submit(run_batch, function, batch, key if isolated else None, key=key, pure=False, retries=0)
        waiting[future.key] = (batch, isolated)
        completed.add(future)

    def submit_next() -> bool:
        if any(isolated for _, isolated in waiting.values()):
            return False  # nothing joins a run that has the cluster to itself
        if suspects:
            # A suspect runs alone: a worker death then is its doing.
            if waiting:
                return False
            task = suspects.popleft()
            submit([task], f"{key_prefix}-{task.index}-isolated", isolated=True)
            return True
        if alone:
            task = alone.popleft()
            # Alone on an idle cluster it is isolated already (one batch in flight at a time).
            submit([task], f"{key_prefix}-{task.index}-alone", isolated=not waiting)
            return True
        batch = list(itertools.islice(pending, sizer.next_size()))
        if not batch:
            return False
        sizer.take(len(batch))
        submit(batch, f"{key_prefix}-{batch[0].index}" + (f"+{len(batch) - 1}" if len(batch) > 1 else ""))
        return True

    def fill() -> None:
        while len(waiting) < max(1, in_flight) and submit_next():
            pass

    fill()
    produced = 0
    for future, result in _finished(completed, client, no_worker_seconds):
        batch, isolated = waiting.pop(future.key)
        failed = future.status != "finished"
        future.release()
        if failed and len(batch) > 1:
            alone.extend(batch)
        elif failed and not isolated:
            # Other runs were on the cluster: try it once more in isolation.
            suspects.append(batch[0])
        elif failed and not client.get_metadata(future.key, False) and attempts[batch[0].index] < MAX_UNSTARTED_ATTEMPTS:
            # Its workers died before it started: not its doing.
            suspects.appendleft(batch[0])
        else:
            if failed:  # killed its worker again with the cluster to itself: record, go on
                error = result[1] if isinstance(result, tuple) else result
                rows = [on_lost(batch[0], f"{type(error).__name__}: {error}")]
            else:
                rows, wall, cpu = result
                sizer.observe(len(rows), wall, cpu)
            for row in rows:
                on_row(row)
                produced += 1
        fill()
    return produced
