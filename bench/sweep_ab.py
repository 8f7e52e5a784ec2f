"""``python bench/sweep_ab.py TREE [RUNS]``: one round of S1 in CPU time with the hbvs of ``TREE``.

Compares two versions of the sweep engine on a machine shared with other work: run it
alternately with two checkouts (e.g. ``git archive COMMIT | tar -x -C /tmp/old``), so that
both meet the same load. One round: the runs in a serial loop in this process, then the
same runs through the engine on a LocalCluster of 2 workers; prints one JSON line with the
wall ratio, the CPU-time ratio ``serial CPU / (sweep CPU of all processes / 2)`` and the CPU
time per run of the serial loop, of the workers and of the driving process (``psutil``).
The engine's ``run_tasks`` is called with ``total`` when the version has it.
"""

from __future__ import annotations

import inspect
import json
import os
import sys
import tempfile
import time
from pathlib import Path


def _cpu_seconds(process) -> float:
    times = process.cpu_times()
    return times.user + times.system


def main() -> None:
    root = str(Path(sys.argv[1]).resolve())
    runs = int(sys.argv[2]) if len(sys.argv) > 2 else 200
    sys.path.insert(0, root)
    import psutil

    import hbvs_cli
    from bench.sweep import _options
    from hbvs_cli.stages.sweep import prepare
    from hbvs_cli.sweep.engine import dask_client, run_tasks
    from hbvs_cli.stages.sweep_run import execute_run
    from hbvs_cli.io.sweep_table import failed_row

    assert hbvs_cli.__file__.startswith(root), f"hbvs_cli imported from {hbvs_cli.__file__}, not {root}"
    with tempfile.TemporaryDirectory() as scratch:
        _, _, table, tasks = prepare(_options(Path(scratch) / "results", runs, short=False))
        task_list = list(tasks)
        execute_run(task_list[0])  # warm: imports, the fit read once
        me = psutil.Process()
        with dask_client(None, None, 2) as client:
            client.wait_for_workers(2)
            client.run(lambda: execute_run(task_list[0]) and None)
            workers = [p for p in me.children(recursive=True) if "--multiprocessing-fork" in " ".join(p.cmdline())]
            load = os.getloadavg()[0]
            cpu, started = time.process_time(), time.perf_counter()
            for task in task_list:
                execute_run(task)
            serial, serial_cpu = time.perf_counter() - started, time.process_time() - cpu
            extra = {"total": len(task_list)} if "total" in inspect.signature(run_tasks).parameters else {}
            before = [_cpu_seconds(p) for p in [me, *workers]]
            started = time.perf_counter()
            run_tasks(client, iter(task_list), execute_run, table.append, failed_row, 8, "ab", **extra)
            table.flush()
            wall = time.perf_counter() - started
            driver, *worker = [_cpu_seconds(p) - b for p, b in zip([me, *workers], before)]
    per_run = 1000 / len(task_list)
    print(json.dumps({
        "tree": root, "load": round(load, 1), "wall_ratio": round(serial / wall, 2),
        "cpu_ratio": round(serial_cpu / ((driver + sum(worker)) / 2), 3), "serial_ms": round(per_run * serial_cpu, 1),
        "workers_ms": round(per_run * sum(worker), 1), "driver_ms": round(per_run * driver, 2),
    }), flush=True)


if __name__ == "__main__":
    main()
