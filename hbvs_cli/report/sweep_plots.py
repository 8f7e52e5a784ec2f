"""Figures of a sweep: convergence map (rate over pairs of the first three numeric parameters,
one column per law), CDFs of the final errors per law, final error against each parameter."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .sweep_summary import SweepData, wilson_interval

FILES = ("convergence_map.png", "final_error_cdf.png", "final_error_vs_parameters.png")
#: The convergence map shows every pair of the first this many numeric swept parameters.
MAP_PARAMETERS = 3


def _save(plt, figure, path: Path, dpi: int) -> Path:
    figure.savefig(path, dpi=dpi)
    plt.close(figure)
    return path


def _convergence_curve(plt, data: SweepData, name: str, laws, reported: np.ndarray, path: Path) -> Path:
    """The map of a single numeric parameter: rate per value or bin, one line per law, Wilson 95 %."""
    figure, axis = plt.subplots(figsize=(5.2, 3.6), constrained_layout=True)
    for index, (law, law_mask) in enumerate(laws):
        centres, rates, low, high = [], [], [], []
        for _, centre, group in data.groups(name):
            cell = law_mask & group & reported
            if cell.any():
                converged = int(data.columns["converged"][cell].sum())
                lower, upper = wilson_interval(converged, int(cell.sum()))
                centres.append(centre)
                rates.append(converged / cell.sum())
                low.append(lower)
                high.append(upper)
        axis.plot(centres, rates, marker="o", ms=3, color=f"C{index}", label=law)
        axis.fill_between(centres, low, high, color=f"C{index}", alpha=0.12, lw=0)
    axis.set_ylim(-0.02, 1.02)
    axis.set(xlabel=name, ylabel="convergence rate (Wilson 95 %)")
    axis.grid(True, alpha=0.3)
    axis.legend(fontsize=8)
    return _save(plt, figure, path, 110)


def save_sweep_plots(folder: Path) -> list[Path]:
    """Write the figures into ``folder`` (the map and the scatter need a numeric swept parameter); returns the paths written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data = SweepData(folder)
    written = []
    reported = data.columns["status"] != "failed"
    laws = data.laws("all runs")
    numeric = [name for name in data.swept if name != "law" and data.columns[name].dtype != object]
    pairs = [(a, b) for i, a in enumerate(numeric[:MAP_PARAMETERS]) for b in numeric[i + 1:MAP_PARAMETERS]]
    if pairs:
        figure, axes = plt.subplots(len(pairs), len(laws), figsize=(4.2 * len(laws) + 1, 3.6 * len(pairs)), squeeze=False,
                                    constrained_layout=True)
        image = None
        for row, (x_name, y_name) in enumerate(pairs):
            x_groups, y_groups = data.groups(x_name), data.groups(y_name)
            for axis, (law, law_mask) in zip(axes[row], laws):
                rate = np.full((len(y_groups), len(x_groups)), np.nan)
                for i, (_, _, y_mask) in enumerate(y_groups):
                    for j, (_, _, x_mask) in enumerate(x_groups):
                        cell = law_mask & x_mask & y_mask & reported
                        if cell.any():
                            rate[i, j] = data.columns["converged"][cell].mean()
                image = axis.imshow(rate, origin="lower", aspect="auto", vmin=0, vmax=1, cmap="viridis")
                axis.set_xticks(range(len(x_groups)), [g[0] for g in x_groups], rotation=60, fontsize=7)
                axis.set_yticks(range(len(y_groups)), [g[0] for g in y_groups], fontsize=7)
                axis.set(xlabel=x_name, ylabel=y_name, title=law)
        figure.colorbar(image, ax=axes.ravel().tolist(), label="convergence rate")
        written.append(_save(plt, figure, Path(folder) / FILES[0], 110))
    elif numeric:
        written.append(_convergence_curve(plt, data, numeric[0], laws, reported, Path(folder) / FILES[0]))
    figure, axes = plt.subplots(1, 2, figsize=(10, 3.8), constrained_layout=True)
    for law, law_mask in laws:
        for axis, column, scale in ((axes[0], "final_position_m", 100.0), (axes[1], "final_heading_deg", 1.0)):
            values = np.sort(data.columns[column][law_mask & reported])
            values = values[np.isfinite(values)] * scale
            if values.size:
                axis.step(values, np.arange(1, values.size + 1) / values.size, where="post", label=law)
    for axis, label in ((axes[0], "final position error (cm)"), (axes[1], "final heading error (deg)")):
        axis.set_xscale("log")
        axis.set(xlabel=label, ylabel="fraction of runs")
        axis.grid(True, alpha=0.3)
        axis.legend(fontsize=8)
    written.append(_save(plt, figure, Path(folder) / FILES[1], 120))
    if numeric:
        figure, axes = plt.subplots(1, len(numeric), figsize=(4.2 * len(numeric), 3.6), squeeze=False, constrained_layout=True)
        for axis, name in zip(axes[0], numeric):
            for index, (law, law_mask) in enumerate(laws):
                mask = law_mask & reported
                colour = f"C{index}"
                axis.scatter(data.columns[name][mask], 100 * data.columns["final_position_m"][mask], s=4, alpha=0.35, color=colour, label=law)
                centres, medians = [], []
                for _, centre, group in data.groups(name):
                    values = data.columns["final_position_m"][group & mask]
                    values = values[np.isfinite(values)]
                    if values.size:
                        centres.append(centre)
                        medians.append(100 * np.median(values))
                axis.plot(centres, medians, color=colour, linewidth=1.5)
            axis.set_yscale("log")
            axis.set(xlabel=name, ylabel="final position error (cm)")
            axis.grid(True, alpha=0.3)
        axes[0][0].legend(fontsize=8, markerscale=3)
        written.append(_save(plt, figure, Path(folder) / FILES[2], 120))
    return written
