"""``hbvs demo``: teach, fit, repeat under both laws with images in the loop, and report, into
one folder; exit 0 only when the default law converged, so it also tests the installation."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from ..errors import InputError
from ..io.mcap import json_ready
from ..io.output_target import write_output_bytes
from ..io.run_file import read_run
from ..report.plots import save_plot
from ..report.build import build_report
from ..report.table import print_report_tables
from .console import Console
from .fit import FitOptions, run_fit
from .repeat import RepeatOptions, run_repeat
from .teach import TeachOptions, run_teach

#: The laws the demo compares; the first is the default whose convergence decides the exit code.
DEMO_LAWS = ("lateral-gain", "paper")


def run_demo(folder: Path, console: Console) -> int:
    """Run the demo into ``folder``; 0 when the default law converged, else 1."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise InputError(f"{folder}: exists and is not a folder")
    folder.mkdir(parents=True, exist_ok=True)
    quiet = Console(quiet=True)
    teach, fit = folder / "teach.mcap", folder / "fit.mcap"
    console.info(f"demo 1/4: teach the default scenario in simulation -> {teach}")
    run_teach(TeachOptions(output=str(teach)), quiet)
    console.info(f"demo 2/4: fit the desired trajectory -> {fit}")
    run_fit(FitOptions(input=str(teach), output=str(fit)), quiet)
    runs = []
    for law in DEMO_LAWS:
        path = folder / f"run-{law}.mcap"
        console.info(f"demo 3/4: repeat in closed loop, images in the loop, {law} law -> {path}")
        run_repeat(RepeatOptions(input=str(fit), output=str(path), sim=True, law=law), quiet)
        runs.append(read_run(path))
    reports = [build_report(run) for run in runs]
    report_json, plot = folder / "report.json", folder / "report.png"
    document = {"runs": [report.to_dict() for report in reports]}
    write_output_bytes(report_json, (json.dumps(json_ready(document), indent=2) + "\n").encode("utf-8"), "report")
    save_plot(runs, reports, plot)
    console.info(f"demo 4/4: report -> {report_json}, {plot}")
    print_report_tables(reports, sys.stdout)
    default = reports[0].verdict
    if default.converged:
        console.info(f"demo: the {DEMO_LAWS[0]} law converged; every file is in {folder}/")
        return 0
    console.warn(f"the {DEMO_LAWS[0]} law did not converge: " + "; ".join(r for r in default.reasons if r.startswith("fail")))
    return 1
