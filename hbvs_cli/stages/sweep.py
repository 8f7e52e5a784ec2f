"""``hbvs sweep``: Monte Carlo studies and controller comparisons, on Dask. Rows are written as
runs finish (:mod:`.sweep_run`), so the same command resumes an interrupted sweep."""

from __future__ import annotations

import hashlib
import time
from pathlib import Path
from typing import Any

from ..errors import HbvsError, InputError, UsageError
from ..io.fit_file import FitFile, read_fit_file
from ..settings.commands import SweepOptions
from ..io.sweep_table import ResultsTable, failed_row, row_schema
from ..sim.scene import simulation_world
from ..sweep.engine import check_scheduler_address, dashboard_address, dask_client, default_workers, require_engine, run_tasks
from ..sweep.spec import PARAMETERS, SweepPlan, SweepSpec, build_spec, file_digest, load_spec_file, repeat_arguments, repeat_command
from ..report.sweep_plots import save_sweep_plots
from ..report.sweep_summary import print_summary, summarize
from .console import Console, print_document
from .sweep_run import RunTask, check_arguments, execute_run


class SweepTasks:
    """The runs still to do, made lazily from their indices (flat memory)."""

    def __init__(self, plan: SweepPlan, fit_path: str, d_true: float | None, folder: Path, keep: str, done: set[int]) -> None:
        self.plan, self.fit_path, self.d_true, self.folder, self.keep, self.done = plan, fit_path, d_true, folder, keep, done

    def task(self, index: int) -> RunTask:
        run = self.plan.run(index)
        arguments = repeat_arguments(run.values, run.seed, self.d_true)
        keep_path = None if self.keep == "none" else str(self.folder / "runs" / f"run-{index:06d}.mcap")
        return RunTask(**vars(run), fit_path=self.fit_path, arguments=arguments, keep_path=keep_path, keep=self.keep,
                       command=repeat_command(self.fit_path, arguments, f"run-{index:06d}.mcap"))

    def __iter__(self):
        return (self.task(i) for i in range(self.plan.runs) if i not in self.done)


def prepare(options: SweepOptions) -> tuple[SweepPlan, SweepSpec, ResultsTable, SweepTasks]:
    """Check the options, plan the runs, open the results table (nothing runs yet)."""
    require_engine()
    check_scheduler_address(options.scheduler)
    dashboard_address(options.dashboard)
    if options.dashboard is not None and (options.scheduler is not None or options.cluster is not None):
        raise UsageError("--dashboard is for the local cluster; a running scheduler or --cluster has its own")
    if options.fit == "-":
        raise UsageError("hbvs sweep needs the fit as a file (every worker reads it), not - (stdin)")
    fit_path = Path(options.fit)
    if not fit_path.is_file():
        raise InputError(f"{fit_path}: no such fit file")
    spec = build_spec(
        load_spec_file(options.spec) if options.spec is not None else None,
        options.vary, options.fixed, options.repeats, options.seed, options.sampling, options.samples,
    )
    plan = SweepPlan(spec)
    fit_text = str(fit_path.resolve())
    fit = read_fit_file(fit_text)
    try:
        d_true: float | None = float(simulation_world(fit.model, None, None).d_true)
    except UsageError:  # a fit of real footage: no simulated world, no d*
        d_true = None
    _check_values(spec, fit, fit_text, d_true)
    schema = row_schema({name: p.kind for name, p in PARAMETERS.items() if name in plan.swept or name in spec.fixed})
    fingerprint = {"spec": spec.as_dict(), "fit": fit_text, "fit_sha256": file_digest(fit_path)}
    description = {"runs": plan.runs, "points": plan.points, "d_true": d_true}
    table = ResultsTable(Path(options.output), schema, fingerprint, description)
    # Absolute: the workers (on other machines with --scheduler) keep run files there.
    tasks = SweepTasks(plan, fit_text, d_true, Path(options.output).absolute(), options.keep_runs, table.done)
    return plan, spec, table, tasks


def _check_values(spec: SweepSpec, fit: FitFile, fit_path: str, d_true: float | None) -> None:
    """Refuse before running what ``hbvs repeat`` would refuse for some run (each axis's extremes), with its message."""
    base = dict(spec.fixed)
    candidates = [("", base)]
    for axis in spec.axes:
        if axis.is_range:
            values: tuple[Any, ...] = (axis.low, axis.high)
        elif PARAMETERS[axis.name].kind == "choice":
            values = axis.values
        else:
            values = (min(axis.values), max(axis.values))
        candidates += [(f"{axis.name}={value!r}: ", base | {axis.name: value}) for value in values]
    for where, values in candidates:
        try:
            check_arguments(fit, fit_path, repeat_arguments(values, 0, d_true))
        except HbvsError as exc:
            exc.args = (f"{where}{exc}",)
            raise


def run_sweep(options: SweepOptions, console: Console) -> int:
    """Run (or resume) a sweep, then print its summary."""
    plan, spec, table, tasks = prepare(options)
    try:
        remaining = plan.runs - len(table.done)
        console.info(
            f"sweep: {plan.runs} runs ({plan.points} points x {spec.repeats} repeats, {spec.sampling}) of "
            f"{', '.join(plan.swept)}; {plan.runs - remaining} already done -> {options.output}/"
        )
        if remaining:
            key = hashlib.sha256(tasks.fit_path.encode() + repr(spec.as_dict()).encode()).hexdigest()[:12]
            failures = 0
            started = time.monotonic()
            dashboard = dashboard_address(options.dashboard)
            with dask_client(options.scheduler, options.cluster, options.workers, dashboard=dashboard) as client, \
                    console.progress("sweep", remaining, "runs, {task.fields[failed]} failed", failed=0) as progress:
                if dashboard is not None:
                    console.info(f"sweep: Dask dashboard at {client.dashboard_link} "
                                 "(no authentication: anyone who reaches it sees the workers)")
                workers = len(client.scheduler_info().get("workers", {})) or options.workers or default_workers()
                in_flight = max(4 * workers, 8)

                def on_row(row: dict[str, Any]) -> None:
                    nonlocal failures
                    table.append(row)
                    failures += row["status"] == "failed"
                    progress.advance(failed=failures)

                try:
                    done = run_tasks(client, tasks, execute_run, on_row, failed_row, in_flight, f"hbvs-sweep-{key}",
                                     total=remaining)
                except BaseException:
                    # Keep every finished row: the same command resumes.
                    table.close()
                    raise
            elapsed = time.monotonic() - started
            console.info(f"sweep: {done} runs in {elapsed:.1f} s ({done / max(elapsed, 1e-9):.2f} runs/s on {workers} workers), "
                         f"{failures} failed")
        finish(options, table, console)
        return 0
    finally:
        table.release()


def finish(options: SweepOptions, table: ResultsTable, console: Console) -> None:
    """Merge the table, print the summary (stdout), draw the figures."""
    rows = table.finish()
    summary = summarize(Path(options.output))
    print_document(summary, options.json_output, print_summary)
    if options.plots and rows:
        units = {name: parameter.unit for name, parameter in PARAMETERS.items()}
        for path in save_sweep_plots(Path(options.output), units):
            console.info(f"sweep: figure {path}")
    failed = summary["runs"]["failed"]
    if failed:
        console.warn(f"{failed} runs failed; their error is in the error column of {options.output}/runs.csv")
