"""``python -m bench.sweep [--quick]``: the sweep engine's throughput, overhead and memory.

Figures (targets from issue 15):

* **S1 throughput**: the same runs (``hbvs repeat --sim --perception points`` on the
  sample fit, 20 s at 10 Hz, 0.2 px noise, four laws x lateral offsets) through
  ``hbvs sweep``'s engine on a LocalCluster of 2 single-threaded worker processes, against
  a serial loop of :func:`hbvs_cli.sweep.runner.execute_run` in this process; target
  >= 1.7x. Both sides are warm (imports done and the fit read) before the clock starts;
  the cluster's start-up is reported separately (a fixed cost, not a per-run one).
* **S2 engine overhead per run**: ``(workers x wall - sum of the runs' own times) /
  sum of the runs' own times``, where a run's own time is measured inside the worker
  (``run_time_s`` of its row); it counts scheduling, transfer, idle workers and writing
  the table; target <= 10 %.
* **S3 peak memory**: peak RSS of the process driving a 20 000-run sweep against a
  2 000-run one (each in a fresh process, short runs: ``--speed 10``, 2 s of simulated
  time); target <= 1.2x. The workers' own peaks are reported too.

Results are printed and written to ``bench/SWEEP_RESULTS.md``. On a machine shared with
other work the absolute times move; the ratios are what is compared.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
RESULTS = HERE / "SWEEP_RESULTS.md"
FIT = REPO / "samples" / "fit.mcap"


def _options(folder: Path, runs: int, short: bool):
    from hbvs_cli.stages.sweep import SweepOptions

    laws = "law=lateral-gain,paper,non-adaptive,kanayama"
    offsets = max(1, runs // 4)
    fixed = ["perception=points", "pixel_noise=0.2"] + (["speed=10"] if short else [])
    return SweepOptions(fit=str(FIT), output=folder, vary=[laws, f"offset_y=-0.15:0.15:{offsets}"], fixed=fixed,
                        seed=1, workers=2, keep_runs="none", plots=False)


def throughput(runs: int) -> dict:
    """S1 and S2: the engine on 2 workers against a serial loop, the same runs."""
    from hbvs_cli.stages.sweep import prepare
    from hbvs_cli.sweep.engine import dask_client, run_tasks
    from hbvs_cli.sweep.runner import execute_run
    from hbvs_cli.sweep.table import failed_row

    with tempfile.TemporaryDirectory() as scratch:
        plan, spec, table, tasks = prepare(_options(Path(scratch) / "parallel", runs, short=False))
        task_list = list(tasks)
        execute_run(task_list[0])  # warm: imports, the fit read once
        started = time.perf_counter()
        serial_rows = [execute_run(task) for task in task_list]
        serial = time.perf_counter() - started
        rows: list[dict] = []

        def on_row(row: dict) -> None:
            table.append(row)
            rows.append(row)

        cluster_started = time.perf_counter()
        with dask_client(None, None, 2) as client:
            client.wait_for_workers(2)
            startup = time.perf_counter() - cluster_started
            client.run(lambda: execute_run(task_list[0]) and None)  # warm, as the serial side
            started = time.perf_counter()
            run_tasks(client, iter(task_list), execute_run, on_row, failed_row, 8, "bench")
            table.flush()
            wall = time.perf_counter() - started
        own = sum(r["run_time_s"] for r in rows)
        assert len(rows) == len(task_list) and all(r["status"] != "failed" for r in rows)
        same = all(
            {k: v for k, v in a.items() if k not in ("run_time_s",)} == {k: v for k, v in b.items() if k not in ("run_time_s",)}
            for a, b in zip(serial_rows, sorted(rows, key=lambda r: r["index"]))
        )
    return {
        "runs": len(task_list), "serial_s": serial, "parallel_s": wall, "speedup": serial / wall, "startup_s": startup,
        "own_s": own, "serial_own_s": sum(r["run_time_s"] for r in serial_rows), "overhead": (2 * wall - own) / own,
        "rows_identical": same, "mean_run_s": own / len(rows),
    }


def memory_child(runs: int) -> None:
    """One sweep of ``runs`` short runs in this process; prints its peak RSS (MiB) as JSON."""
    from hbvs_cli.stages.console import Console
    from hbvs_cli.stages.sweep import run_sweep

    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch) / "results"
        started = time.perf_counter()
        devnull = open(os.devnull, "w")
        stdout, sys.stdout = sys.stdout, devnull
        try:
            run_sweep(_options(folder, runs, short=True), Console(quiet=True))
        finally:
            sys.stdout = stdout
        elapsed = time.perf_counter() - started
        import pyarrow.parquet as pq

        rows = pq.read_metadata(folder / "runs.parquet").num_rows
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    workers = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    print(json.dumps({"runs": rows, "peak_mib": peak, "children_peak_mib": workers, "elapsed_s": elapsed}))


def memory(small: int, large: int) -> dict:
    """S3: peak memory of the driving process, ``large`` runs against ``small``."""
    result = {}
    for runs in (small, large):
        out = subprocess.run([sys.executable, "-m", "bench.sweep", "--memory-child", str(runs)], cwd=REPO,
                             capture_output=True, text=True, check=True)
        result[runs] = json.loads(out.stdout.strip().splitlines()[-1])
    result["ratio"] = result[large]["peak_mib"] / result[small]["peak_mib"]
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.sweep")
    parser.add_argument("--quick", action="store_true", help="fewer runs (a smoke test of the benchmark)")
    parser.add_argument("--only", choices=("throughput", "memory"))
    parser.add_argument("--memory-child", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.memory_child:
        memory_child(args.memory_child)
        return 0
    started = time.perf_counter()
    lines = []
    load = os.getloadavg()
    if args.only in (None, "throughput"):
        t = throughput(60 if args.quick else 200)
        lines.append(
            f"| S1. sweep throughput, 2 workers / serial loop (same {t['runs']} runs) | {t['speedup']:.2f}x | >= 1.7x | "
            f"{'yes' if t['speedup'] >= 1.7 else 'no'} | serial {t['serial_s']:.1f} s, sweep {t['parallel_s']:.1f} s "
            f"(+ {t['startup_s']:.1f} s once to start the cluster); mean run {1000 * t['mean_run_s']:.0f} ms; "
            f"rows of both identical: {t['rows_identical']} |"
        )
        lines.append(
            f"| S2. engine overhead per run (2 x wall - run time) / run time | {100 * t['overhead']:.1f} % | <= 10 % | "
            f"{'yes' if t['overhead'] <= 0.10 else 'no'} | runs' own time {t['own_s']:.1f} s on workers "
            f"({t['serial_own_s']:.1f} s serially), 2 x wall {2 * t['parallel_s']:.1f} s |"
        )
    if args.only in (None, "memory"):
        small, large = (500, 5000) if args.quick else (2000, 20000)
        m = memory(small, large)
        lines.append(
            f"| S3. peak memory of the driving process, {large} / {small} runs | {m['ratio']:.2f} | <= 1.2 | "
            f"{'yes' if m['ratio'] <= 1.2 else 'no'} | {m[small]['peak_mib']:.0f} MiB vs {m[large]['peak_mib']:.0f} MiB "
            f"(ru_maxrss); largest worker {m[small]['children_peak_mib']:.0f} vs {m[large]['children_peak_mib']:.0f} MiB; "
            f"{m[large]['elapsed_s']:.0f} s for {m[large]['runs']} runs |"
        )
    elapsed = time.perf_counter() - started
    import dask
    import pyarrow

    header = [
        "# hbvs sweep benchmark results",
        "",
        f"Produced by `python -m bench.sweep{' --quick' if args.quick else ''}` in {elapsed:.0f} s on {datetime.date.today()}, "
        f"load average {load[0]:.1f} at the start ({os.cpu_count()} cores; other work was running: times are inflated, ratios less so).",
        f"Python {platform.python_version()}, dask {dask.__version__}, pyarrow {pyarrow.__version__}.",
        "",
        "| figure | measured | target | met | detail |",
        "|---|---:|---|---|---|",
    ]
    text = "\n".join(header + lines) + "\n"
    print(text)
    if not args.quick:
        RESULTS.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
