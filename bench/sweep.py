"""``python -m bench.sweep [--quick]``: the sweep engine's throughput, overhead and memory.

Figures (targets from issue 15):

* **S1 throughput**: the same runs (``hbvs repeat --sim --perception points`` on the
  sample fit, 20 s at 10 Hz, 0.2 px noise, four laws x lateral offsets) through
  ``hbvs sweep``'s engine on a LocalCluster of 2 single-threaded worker processes, against
  a serial loop of :func:`hbvs_cli.stages.sweep_run.execute_run` in this process; target
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
import re
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


def _cpu_seconds(process) -> float:
    times = process.cpu_times()
    return times.user + times.system


def _run_all(tasks: list) -> float:
    """In a plain process: the runs one after the other; returns their CPU time (s)."""
    from hbvs_cli.stages.sweep_run import execute_run

    cpu = time.process_time()
    for task in tasks:
        execute_run(task)
    return time.process_time() - cpu


def _warm(task, seconds: float) -> None:
    from hbvs_cli.stages.sweep_run import execute_run

    execute_run(task)
    time.sleep(seconds)  # so that the pool's other process takes the other warm-up


def throughput(runs: int, rounds: int) -> dict:
    """S1 and S2: the engine on 2 workers against a serial loop, the same runs.

    ``rounds`` times in turn: the serial loop, then the sweep (one cluster for all rounds),
    so that both sides of a round meet the same load from other work on the machine. Wall
    times and CPU times (``psutil``: this process, which holds the scheduler, the nannies
    and the results table; and each worker process) are kept per round. Each round also
    runs the two halves of the runs in two plain processes side by side (no engine): the
    most any engine could give on this machine, where two busy cores slow each other.
    """
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    import psutil

    from hbvs_cli.stages.sweep import prepare
    from hbvs_cli.sweep.engine import dask_client, run_tasks
    from hbvs_cli.stages.sweep_run import execute_run
    from hbvs_cli.io.sweep_table import failed_row

    def comparable(row: dict) -> dict:
        return {k: v for k, v in row.items() if k != "run_time_s"}

    result: dict = {"rounds": []}
    with tempfile.TemporaryDirectory() as scratch:
        plan, spec, table, tasks = prepare(_options(Path(scratch) / "parallel", runs, short=False))
        task_list = list(tasks)
        execute_run(task_list[0])  # warm: imports, the fit read once
        me = psutil.Process()
        halves = [task_list[0::2], task_list[1::2]]
        pool = ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn"))
        list(pool.map(_warm, task_list[:2], [1.0, 1.0]))
        cluster_started = time.perf_counter()
        with pool, dask_client(None, None, 2) as client:
            client.wait_for_workers(2)
            result["startup_s"] = time.perf_counter() - cluster_started
            client.run(lambda: execute_run(task_list[0]) and None)  # warm, as the serial side
            plain = set(pool._processes)  # the pool's two plain processes
            workers = [p for p in me.children(recursive=True) if "--multiprocessing-fork" in " ".join(p.cmdline()) and p.pid not in plain]
            assert len(workers) == 2, workers
            for number in range(rounds):
                load = os.getloadavg()[0]
                cpu = time.process_time()
                started = time.perf_counter()
                serial_rows = [execute_run(task) for task in task_list]
                serial, serial_cpu = time.perf_counter() - started, time.process_time() - cpu
                started = time.perf_counter()
                pair_cpu = sum(pool.map(_run_all, halves))
                pair = time.perf_counter() - started
                rows: list[dict] = []

                def on_row(row: dict) -> None:
                    table.append(row)
                    rows.append(row)

                before = [_cpu_seconds(p) for p in [me, *workers]]
                started = time.perf_counter()
                run_tasks(client, iter(task_list), execute_run, on_row, failed_row, 8, f"bench-{number}", total=len(task_list))
                table.flush()
                wall = time.perf_counter() - started
                after = [_cpu_seconds(p) for p in [me, *workers]]
                driver_cpu, *worker_cpu = [b - a for a, b in zip(before, after)]
                own = sum(r["run_time_s"] for r in rows)
                assert len(rows) == len(task_list) and all(r["status"] != "failed" for r in rows)
                same = [comparable(r) for r in serial_rows] == [comparable(r) for r in sorted(rows, key=lambda r: r["index"])]
                result["rounds"].append({
                    "load": load, "load_after": os.getloadavg()[0], "serial_s": serial, "parallel_s": wall,
                    "speedup": serial / wall, "pair_s": pair, "pair_speedup": serial / pair, "pair_cpu_s": pair_cpu,
                    "pair_cpu_speedup": 2 * serial_cpu / pair_cpu, "serial_cpu_s": serial_cpu, "driver_cpu_s": driver_cpu,
                    "worker_cpu_s": sum(worker_cpu), "cpu_speedup": serial_cpu / ((driver_cpu + sum(worker_cpu)) / 2),
                    "own_s": own, "serial_own_s": sum(r["run_time_s"] for r in serial_rows),
                    "overhead": (2 * wall - own) / own, "rows_identical": same,
                })
                print(json.dumps(result["rounds"][-1]), file=sys.stderr, flush=True)
    result["runs"] = len(task_list)
    return result


def _median(values) -> float:
    ordered = sorted(values)
    middle = len(ordered) // 2
    return ordered[middle] if len(ordered) % 2 else (ordered[middle - 1] + ordered[middle]) / 2


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


def _figure(line: str) -> str | None:
    """``S1`` of a results row ``| S1. ...`` (None for any other line)."""
    found = re.match(r"\| (S\d+)", line)
    return found.group(1) if found else None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.sweep")
    parser.add_argument("--quick", action="store_true", help="fewer runs (a smoke test of the benchmark)")
    parser.add_argument("--only", choices=("throughput", "memory"))
    parser.add_argument("--rounds", type=int, default=3, help="serial loop + sweep pairs for S1 and S2 (default 3)")
    parser.add_argument("--memory-child", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.memory_child:
        memory_child(args.memory_child)
        return 0
    started = time.perf_counter()
    lines = []
    if args.only in (None, "throughput"):
        t = throughput(60 if args.quick else 200, args.rounds)
        rounds = t["rounds"]
        speedup, cpu_speedup = _median(r["speedup"] for r in rounds), _median(r["cpu_speedup"] for r in rounds)
        overhead = _median(r["overhead"] for r in rounds)
        per_run = {key: 1000 * _median(r[key] for r in rounds) / t["runs"]
                   for key in ("serial_s", "serial_cpu_s", "own_s", "worker_cpu_s", "driver_cpu_s", "pair_cpu_s")}
        pair_speedup, pair_cpu_speedup = _median(r["pair_speedup"] for r in rounds), _median(r["pair_cpu_speedup"] for r in rounds)
        pair_rounds = "; ".join(f"{r['pair_speedup']:.2f}x ({r['pair_cpu_speedup']:.2f}x in CPU time)" for r in rounds)
        cpu_rounds = ", ".join(f"{r['cpu_speedup']:.2f}x" for r in rounds)
        overhead_rounds = ", ".join(f"{100 * r['overhead']:.1f} %" for r in rounds)
        each = "; ".join(f"{r['speedup']:.2f}x (serial {r['serial_s']:.1f} s, sweep {r['parallel_s']:.1f} s, load {r['load']:.1f}-{r['load_after']:.1f})"
                         for r in rounds)
        lines.append(
            f"| S1. sweep throughput, 2 workers / serial loop (same {t['runs']} runs), median of {len(rounds)} rounds | "
            f"{speedup:.2f}x | >= 1.7x | {'yes' if speedup >= 1.7 else 'no'} | {each}; "
            f"+ {t['startup_s']:.1f} s once to start the cluster; rows of both identical: {all(r['rows_identical'] for r in rounds)} |"
        )
        lines.append(
            f"| S1 in CPU time: serial CPU / (sweep CPU of all processes / 2 cores) | {cpu_speedup:.2f}x | (>= 1.7x) | "
            f"{'yes' if cpu_speedup >= 1.7 else 'no'} | per run: serial {per_run['serial_cpu_s']:.1f} ms CPU; sweep "
            f"{per_run['worker_cpu_s']:.1f} ms in the workers + {per_run['driver_cpu_s']:.1f} ms in the driving process "
            f"(scheduler, nannies, table); rounds {cpu_rounds} |"
        )
        lines.append(
            f"| S1 ceiling: the same runs in two plain processes side by side, no engine | {pair_speedup:.2f}x | - | - | "
            f"{pair_cpu_speedup:.2f}x in CPU time (a run takes {per_run['pair_cpu_s']:.1f} ms of CPU when both cores are busy, "
            f"{per_run['serial_cpu_s']:.1f} ms alone); rounds {pair_rounds}; the engine reaches {speedup / pair_speedup:.0%} "
            f"of it in wall time, {cpu_speedup / pair_cpu_speedup:.0%} in CPU time |"
        )
        lines.append(
            f"| S2. engine overhead per run (2 x wall - run time) / run time, median | {100 * overhead:.1f} % | <= 10 % | "
            f"{'yes' if overhead <= 0.10 else 'no'} | mean run {per_run['own_s']:.0f} ms on a worker, "
            f"{per_run['serial_s']:.0f} ms serially; rounds {overhead_rounds} |"
        )
    if args.only in (None, "memory"):
        small, large = (500, 5000) if args.quick else (2000, 20000)
        load = os.getloadavg()[0]
        m = memory(small, large)
        lines.append(
            f"| S3. peak memory of the driving process, {large} / {small} runs | {m['ratio']:.2f} | <= 1.2 | "
            f"{'yes' if m['ratio'] <= 1.2 else 'no'} | {m[small]['peak_mib']:.0f} MiB vs {m[large]['peak_mib']:.0f} MiB "
            f"(ru_maxrss); largest worker {m[small]['children_peak_mib']:.0f} vs {m[large]['children_peak_mib']:.0f} MiB; "
            f"{m[large]['elapsed_s']:.0f} s for {m[large]['runs']} runs (load {load:.1f} at its start) |"
        )
    elapsed = time.perf_counter() - started
    import dask
    import pyarrow

    # Rows of figures not measured this time, and the hand-written sections (## ...) after
    # the table, are kept from the previous file.
    measured = {_figure(line) for line in lines}
    kept, notes = [], []
    if RESULTS.is_file():
        previous = RESULTS.read_text().splitlines()
        first_note = next((i for i, line in enumerate(previous) if line.startswith("## ")), len(previous))
        kept = [line for line in previous[:first_note] if _figure(line) and _figure(line) not in measured]
        notes = previous[first_note:]
    header = [
        "# hbvs sweep benchmark results",
        "",
        f"Produced by `python -m bench.sweep{' --quick' if args.quick else ''}{f' --only {args.only}' if args.only else ''}` "
        f"in {elapsed:.0f} s on {datetime.date.today()} ({os.cpu_count()} cores, shared: the load average is given "
        f"with each figure){'; rows not re-measured are from an earlier run' if kept else ''}.",
        f"Python {platform.python_version()}, dask {dask.__version__}, pyarrow {pyarrow.__version__}.",
        "",
        "| figure | measured | target | met | detail |",
        "|---|---:|---|---|---|",
    ]
    table_rows = sorted(lines + kept, key=_figure)
    text = "\n".join(header + table_rows + ([""] + notes if notes else [])) + "\n"
    print(text)
    if not args.quick:
        RESULTS.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
