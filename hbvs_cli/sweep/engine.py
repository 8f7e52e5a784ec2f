"""Where the runs execute: a Dask distributed cluster (local, remote, or batch jobs).

* default: a ``LocalCluster`` of single-threaded worker processes, one per core, talking
  TCP on localhost (the runs are CPU-bound Python: processes, not threads);
* ``--scheduler tcp://HOST:8786``: an existing cluster (``dask scheduler`` and
  ``dask worker`` started by hand; the workers need hbvs installed);
* ``--cluster slurm|pbs``: workers submitted as batch jobs through dask-jobqueue (the queue,
  account and walltime come from dask's jobqueue configuration file).

Runs are submitted in bounded batches: never more than ``in_flight`` futures exist, a new
one is submitted as one finishes, so memory stays flat however many runs a sweep has. A
worker that dies has its runs rescheduled by the Dask scheduler (up to
``distributed.scheduler.allowed-failures`` times); a run that keeps killing workers is
recorded as failed with the error, like any run that raises.
"""

from __future__ import annotations

import logging
import os
from contextlib import contextmanager
from typing import Any, Callable, Iterable, Iterator

from ..errors import UsageError

#: Installing the engine: named by every error about a missing piece.
INSTALL_HINT = "pip install 'hbvs[sweep]'"
CLUSTER_KINDS = ("slurm", "pbs")
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


@contextmanager
def dask_client(scheduler: str | None, cluster: str | None, workers: int | None,
                allowed_worker_deaths: int = ALLOWED_WORKER_DEATHS) -> Iterator[Any]:
    """A connected ``distributed.Client``; the cluster it started (if any) is closed after.

    ``allowed_worker_deaths``: how often a run is rescheduled after its worker died (a
    cluster started here; a running scheduler keeps its own configuration).

    Raises
    ------
    UsageError
        Clashing options, an unknown cluster kind, dask-jobqueue missing, or a scheduler
        that cannot be reached.
    """
    import dask
    from distributed import Client, LocalCluster

    if scheduler is not None and cluster is not None:
        raise UsageError("--scheduler and --cluster exclude each other: connect to a running cluster, or start one")
    if workers is not None and workers < 1:
        raise UsageError(f"--workers must be >= 1, got {workers}")
    # worker-saturation 1: a worker holds only the run it is running, so a run that kills
    # its worker takes no queued innocent run down with it (each costs ~1 ms of idle time).
    # The workers' statistical profiler (for the dashboard, which hbvs does not open) keeps
    # up to 1000 profile trees per worker: tens of MB that grew with the sweep's length.
    # The event loop's 20 ms latency tick and the 100 ms memory monitor wake each worker's
    # main thread, which then takes the interpreter lock from the run: a run took 91 ms on
    # a worker against 81 ms in a plain process, 86 ms with these once a second.
    with dask.config.set({"distributed.scheduler.allowed-failures": allowed_worker_deaths,
                          "distributed.scheduler.worker-saturation": 1.0,
                          "distributed.worker.profile.enabled": False,
                          "distributed.admin.tick.interval": "1s",
                          "distributed.admin.system-monitor.interval": "1s",
                          "distributed.worker.memory.monitor-interval": "1s"}):
        started = None
        try:
            if scheduler is not None:
                try:
                    client = Client(scheduler, timeout="20s")
                except (OSError, TimeoutError) as exc:
                    raise UsageError(f"--scheduler {scheduler}: cannot connect ({exc})") from None
            elif cluster is not None:
                started = _jobqueue_cluster(cluster, workers or 1)
                client = Client(started)
            else:
                started = LocalCluster(
                    n_workers=workers or default_workers(), threads_per_worker=1, processes=True,
                    protocol="tcp://", host="127.0.0.1", dashboard_address=":0", silence_logs=logging.ERROR,
                )
                client = Client(started)
            try:
                yield client
            finally:
                client.close()
        finally:
            if started is not None:
                started.close()


def _jobqueue_cluster(kind: str, jobs: int) -> Any:
    if kind not in CLUSTER_KINDS:
        raise UsageError(f"--cluster must be one of {', '.join(CLUSTER_KINDS)}, got {kind!r}")
    try:
        import dask_jobqueue
    except ImportError:
        raise UsageError(f"--cluster {kind} needs dask-jobqueue: pip install 'hbvs[sweep-cluster]'") from None
    cluster_class = {"slurm": dask_jobqueue.SLURMCluster, "pbs": dask_jobqueue.PBSCluster}[kind]
    # One single-threaded worker per job slot; the rest (queue, account, walltime,
    # memory) from the user's ~/.config/dask/jobqueue.yaml.
    cluster = cluster_class(cores=1, processes=1)
    cluster.scale(jobs=jobs)
    return cluster


def run_tasks(
    client: Any,
    tasks: Iterable[Any],
    function: Callable[[Any], dict[str, Any]],
    on_row: Callable[[dict[str, Any]], None],
    on_lost: Callable[[Any, str], dict[str, Any]],
    in_flight: int,
    key_prefix: str,
) -> int:
    """Run ``function(task)`` for every task on the cluster; ``on_row`` gets each row as it
    finishes (in completion order). At most ``in_flight`` runs are submitted at a time.

    Returns the number of rows produced. A task whose future fails (its worker died too
    often, or the function raised despite catching everything) gets ``on_lost(task, error)``.
    """
    from distributed import as_completed

    pending = iter(tasks)
    waiting: dict[str, Any] = {}
    completed = as_completed()

    def submit_next() -> bool:
        task = next(pending, None)
        if task is None:
            return False
        future = client.submit(function, task, key=f"{key_prefix}-{task.index}", pure=False, retries=0)
        waiting[future.key] = task
        completed.add(future)
        return True

    for _ in range(max(1, in_flight)):
        if not submit_next():
            break
    produced = 0
    for future in completed:
        task = waiting.pop(future.key)
        try:
            row = future.result()
        except Exception as exc:  # noqa: BLE001 - KilledWorker and the like: record, go on
            row = on_lost(task, f"{type(exc).__name__}: {exc}")
        future.release()
        on_row(row)
        produced += 1
        submit_next()
    return produced
