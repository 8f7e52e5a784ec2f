"""The summary of a sweep's table: convergence rates with Wilson intervals, error quantiles,
per law crossed with each other swept parameter's values or ``BINS`` bins. Failed runs are
left out of the rate, unsettled ones out of the settling-time quantiles."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, TextIO

import numpy as np

#: Bins of a sampled (not gridded) parameter in the summary and the plots.
BINS = 8
#: Values of a gridded parameter beyond which it is binned like a sampled one.
MAX_GROUPS = 24
#: Coverage of the convergence-rate interval.
CONFIDENCE = 0.95


def wilson_interval(converged: int, runs: int) -> tuple[float | None, float | None]:
    """Wilson score interval of a proportion (scipy's ``binomtest``), None for no runs."""
    if runs == 0:
        return None, None
    from scipy.stats import binomtest

    interval = binomtest(converged, runs).proportion_ci(confidence_level=CONFIDENCE, method="wilson")
    return float(interval.low), float(interval.high)


def _quantiles(values: np.ndarray) -> dict[str, float | None]:
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return {"median": None, "p95": None}
    return {"median": float(np.median(finite)), "p95": float(np.percentile(finite, 95))}


class SweepData:
    """The columns the summary needs, as numpy arrays, with the sweep's description."""

    def __init__(self, folder: Path) -> None:
        from ..io.sweep_table import read_description, read_rows

        info = read_description(folder)
        spec = info["fingerprint"]["spec"]
        self.vary: dict[str, Any] = spec["vary"]
        self.fixed: dict[str, Any] = spec["fixed"]
        self.total_runs: int = int(info.get("runs", 0))
        # A fixed parameter is a column too (a fixed law groups the runs as a swept one does).
        table = read_rows(folder, ["status", "converged", "final_position_m", "final_heading_deg",
                                   "settling_time_position_s", "settling_time_heading_s", *self.vary, *self.fixed])
        self.rows = table.num_rows
        self.columns: dict[str, np.ndarray] = {}
        for name in table.column_names:
            column = table.column(name)
            if column.type == "string":
                self.columns[name] = np.array(column.to_pylist(), dtype=object)
            elif column.type == "bool":
                self.columns[name] = np.array([bool(v) for v in column.to_pylist()])
            else:
                self.columns[name] = column.to_numpy(zero_copy_only=False).astype(float)
        # NaN (never settled) when either error never settled.
        self.columns["settling_time_s"] = np.maximum(self.columns["settling_time_position_s"], self.columns["settling_time_heading_s"])
        self.law = self.columns.get("law")

    def laws(self) -> list[tuple[str, np.ndarray]]:
        """``(law, mask)`` per law run, in the table's order; one group "all runs" without a law."""
        if self.law is None:
            return [("all runs", np.ones(self.rows, dtype=bool))]
        return [(str(v), self.law == v) for v in dict.fromkeys(self.law.tolist())]

    def groups(self, name: str) -> list[tuple[str, Any, np.ndarray]]:
        """``(label, value, mask)`` per value or bin of a swept parameter."""
        values = self.columns[name]
        axis = self.vary[name]
        listed = axis.get("values")
        if values.dtype == object:  # a choice: always listed
            return [(str(v), v, values == v) for v in listed]
        if listed is not None and len(listed) <= MAX_GROUPS:
            return [(f"{v:g}", float(v), np.isclose(values, v, rtol=0, atol=1e-12)) for v in listed]
        low, high = (axis["range"] if listed is None else (min(listed), max(listed)))
        edges = np.linspace(low, high, BINS + 1)
        which = np.clip(np.searchsorted(edges, values, side="right") - 1, 0, BINS - 1)
        return [(f"[{edges[b]:.4g}, {edges[b + 1]:.4g}{']' if b == BINS - 1 else ')'}", float(0.5 * (edges[b] + edges[b + 1])), which == b)
                for b in range(BINS)]


def group_stats(data: SweepData, mask: np.ndarray) -> dict[str, Any]:
    """The statistics of one group of rows (see the module docstring)."""
    reported = data.columns["status"][mask] != "failed"
    converged = data.columns["converged"][mask] & reported
    runs, n_converged = int(reported.sum()), int(converged.sum())
    low, high = wilson_interval(n_converged, runs)
    settle = data.columns["settling_time_s"][mask][reported]
    return {
        "runs": int(mask.sum()), "failed": int((~reported).sum()), "converged": n_converged,
        "rate": n_converged / runs if runs else None, "rate_ci95": [low, high],
        "final_position_m": _quantiles(data.columns["final_position_m"][mask][reported]),
        "final_heading_deg": _quantiles(data.columns["final_heading_deg"][mask][reported]),
        "settling_time_s": _quantiles(settle) | {"unsettled": int(np.isnan(settle).sum())},
    }


def summarize(folder: Path, sweep_label: str | None = None) -> dict[str, Any]:
    """The summary of a results folder as one JSON-ready dictionary (``hbvs sweep --json``); ``sweep_label``: ``--label``'s."""
    data = SweepData(folder)
    laws = data.laws()
    return {
        "folder": str(folder),
        "runs": {"planned": data.total_runs, "done": data.rows,
                 "failed": int((data.columns["status"] == "failed").sum()),
                 "stopped": int((data.columns["status"] == "stopped").sum())},
        "swept": list(data.vary), "fixed": data.fixed,
        "overall": group_stats(data, np.ones(data.rows, dtype=bool)),
        "by_law": [{"law": label} | group_stats(data, mask) for label, mask in laws] if data.law is not None else [],
        "by_parameter": {
            name: [{"value": label, "center": value} | ({"law": law_label} if data.law is not None else {})
                   | group_stats(data, mask & law_mask)
                   for law_label, law_mask in laws for label, value, mask in data.groups(name)]
            for name in data.vary if name != "law"
        },
    } | ({} if sweep_label is None else {"label": sweep_label})


def _stat_cells(stats: Mapping[str, Any]) -> list[str]:
    from .table import format_value

    low, high = stats["rate_ci95"]
    rate = "n/a" if stats["rate"] is None else f"{100 * stats['rate']:.1f} %"
    interval = "n/a" if low is None else f"[{100 * low:.1f}, {100 * high:.1f}]"
    # The median and p95 of each, the position's in cm.
    quantiles = [None if stats[key][q] is None else scale * stats[key][q] for key, scale in
                 (("final_position_m", 100), ("final_heading_deg", 1), ("settling_time_s", 1)) for q in ("median", "p95")]
    return [str(stats["runs"]), str(stats["failed"]), rate, interval, *map(format_value, quantiles)]


STAT_HEADERS = ["runs", "failed", "converged", "95 % CI (Wilson)", "pos. median (cm)", "pos. p95 (cm)",
                "head. median (deg)", "head. p95 (deg)", "settle median (s)", "settle p95 (s)"]


def print_summary(summary: Mapping[str, Any], stream: TextIO, console: Any = None) -> None:
    """The summary as tables on ``stream`` (or ``console``): rich on a terminal, plain text otherwise."""
    from rich.text import Text

    from .table import new_table, print_table, print_title, report_console

    console = console or report_console(stream)
    plain = not console.is_terminal
    runs = summary["runs"]
    print_title(console, f"sweep {summary.get('label', summary['folder'])}: {runs['done']} of {runs['planned']} runs, "
                f"{runs['failed']} failed, {runs['stopped']} stopped (target lost); swept: {', '.join(summary['swept'])}")
    groups = summary["by_law"] or [{"law": "all"} | summary["overall"]]
    table = new_table(["law", *STAT_HEADERS], plain)
    for entry in groups:
        table.add_row(entry["law"], *_stat_cells(entry))
    print_table(console, table)
    for name, rows in summary["by_parameter"].items():
        console.print()
        print_title(console, f"by {name}")
        with_law = bool(rows) and "law" in rows[0]
        table = new_table([name, *(["law"] if with_law else []), *STAT_HEADERS], plain)
        for entry in rows:
            table.add_row(entry["value"], *([entry["law"]] if with_law else []), *_stat_cells(entry))
        print_table(console, table, keys=2 if with_law else 1)
    console.print()
    console.print(Text("converged: hbvs report's verdict (docs/report.md); failed runs have no report and are not in the rate"))
