"""Figures of a sweep: convergence map (rate over pairs of the first three numeric parameters,
one column per law), CDFs of the final errors per law, final error against each parameter."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .figure_style import law_colors
from .sweep_summary import SweepData, group_stats

FILES = ("convergence_map.png", "final_error_cdf.png", "final_error_vs_parameters.png")
#: The convergence map shows every pair of the first this many numeric swept parameters.
MAP_PARAMETERS = 3
#: The axis of a convergence rate: a fraction from 0 to 1, not a percentage.
RATE_LABEL = "convergence rate (fraction of runs)"
#: A log axis spanning at most this many decades is labelled at 1, 2 and 5 times each power of ten.
FEW_DECADES = 2.0


def parameter_label(name: str, units: Mapping[str, str]) -> str:
    """A swept parameter's axis label with its unit: ``offset_y (m)``; ``(-)`` when it has none, the name alone without units."""
    return f"{name} ({units[name] or '-'})" if name in units else name


def label_log_axis(axis: Any, which: str) -> None:
    """Make the ``which`` ("x" or "y") axis a log axis, with plain numbers at a few ticks: every power of ten,
    and 2 and 5 times it when the axis spans few decades, with no minor labels (matplotlib's own labelled
    minor ticks overlapped each other on an axis of less than a decade)."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    getattr(axis, f"set_{which}scale")("log")
    target = axis.xaxis if which == "x" else axis.yaxis
    low, high = axis.get_xlim() if which == "x" else axis.get_ylim()
    decades = np.log10(max(high, 1e-300) / max(low, 1e-300))
    target.set_major_locator(LogLocator(base=10.0, subs=(1.0, 2.0, 5.0) if decades <= FEW_DECADES else (1.0,)))
    target.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
    target.set_minor_formatter(NullFormatter())


def _convergence_curve(plt, data: SweepData, name: str, laws, units: Mapping[str, str]) -> Any:
    """The map of a single numeric parameter: rate per value or bin, one line per law, Wilson 95 %."""
    from matplotlib.ticker import MaxNLocator

    figure, axis = plt.subplots(figsize=(5.2, 3.6), constrained_layout=True)
    for colour, (law, law_mask) in zip(law_colors([law for law, _ in laws]), laws):
        stats = [(centre, group_stats(data, law_mask & group)) for _, centre, group in data.groups(name)]
        # (centre, rate, Wilson low, high) of each value or bin with reported runs
        points = [(centre, s["rate"], *s["rate_ci95"]) for centre, s in stats if s["rate"] is not None]
        centres, rates, low, high = zip(*points) if points else ([], [], [], [])
        axis.plot(centres, rates, marker="o", ms=3, color=colour, label=law)
        axis.fill_between(centres, low, high, color=colour, alpha=0.12, lw=0)
    axis.set_ylim(-0.02, 1.02)
    axis.xaxis.set_major_locator(MaxNLocator(nbins=6))
    axis.set(xlabel=parameter_label(name, units), ylabel=RATE_LABEL, title="shaded: Wilson 95 % interval")
    axis.grid(True, alpha=0.3)
    figure.legend(loc="outside right upper", fontsize=8)
    return figure


def save_sweep_plots(folder: Path, units: Mapping[str, str] | None = None) -> list[Path]:
    """Write :func:`sweep_figures` into ``folder``; returns the paths written."""
    import matplotlib.pyplot as plt

    written = []
    for name, (figure, dpi) in sweep_figures(folder, units).items():
        figure.savefig(Path(folder) / name, dpi=dpi)
        plt.close(figure)
        written.append(Path(folder) / name)
    return written


def sweep_figures(folder: Path, units: Mapping[str, str] | None = None) -> dict[str, tuple[Any, int]]:
    """The figures of a results folder (docs/sweeps.md) by file name (of :data:`FILES`), each with its dpi;
    ``units``: each swept parameter's unit for its axis label ("" dimensionless). The caller closes them (pyplot's)."""
    units = units or {}
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data = SweepData(folder)
    figures: dict[str, tuple[Any, int]] = {}
    reported = data.columns["status"] != "failed"
    laws = data.laws()
    colours = law_colors([law for law, _ in laws])
    numeric = [name for name in data.vary if name != "law" and data.columns[name].dtype != object]
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
                axis.set(xlabel=parameter_label(x_name, units), ylabel=parameter_label(y_name, units), title=law)
        figure.colorbar(image, ax=axes.ravel().tolist(), label=RATE_LABEL)
        figures[FILES[0]] = (figure, 110)
    elif numeric:
        figures[FILES[0]] = (_convergence_curve(plt, data, numeric[0], laws, units), 110)
    figure, axes = plt.subplots(1, 2, figsize=(10, 3.8), constrained_layout=True)
    for axis, column, scale, label in ((axes[0], "final_position_m", 100.0, "final position error (cm)"),
                                       (axes[1], "final_heading_deg", 1.0, "final heading error (deg)")):
        for colour, (law, law_mask) in zip(colours, laws):
            values = np.sort(data.columns[column][law_mask & reported])
            values = values[np.isfinite(values)] * scale
            if values.size:
                axis.step(values, np.arange(1, values.size + 1) / values.size, where="post", label=law, color=colour)
        label_log_axis(axis, "x")
        axis.set(xlabel=label, ylabel="fraction of runs at or below (0-1)")
        axis.grid(True, alpha=0.3)
    figure.legend(*axes[0].get_legend_handles_labels(), loc="outside right upper", fontsize=8)
    figures[FILES[1]] = (figure, 120)
    if numeric:
        figure, axes = plt.subplots(1, len(numeric), figsize=(4.2 * len(numeric), 3.6), squeeze=False, constrained_layout=True)
        for axis, name in zip(axes[0], numeric):
            for colour, (law, law_mask) in zip(colours, laws):
                mask = law_mask & reported
                axis.scatter(data.columns[name][mask], 100 * data.columns["final_position_m"][mask], s=4, alpha=0.35, color=colour, label=law)
                # The median of each value or bin with a finite final error.
                medians = {centre: group_stats(data, law_mask & group)["final_position_m"]["median"]
                           for _, centre, group in data.groups(name)}
                centres = [centre for centre, median in medians.items() if median is not None]
                axis.plot(centres, [100 * medians[centre] for centre in centres], color=colour, linewidth=1.5)
            label_log_axis(axis, "y")
            axis.set(xlabel=parameter_label(name, units), ylabel="final position error (cm)")
            axis.grid(True, alpha=0.3)
        # Outside the panels: inside, it hid the runs at the axis' ends.
        figure.legend(*axes[0][0].get_legend_handles_labels(), loc="outside lower center", fontsize=8, markerscale=3,
                      ncols=min(len(laws), 2 * len(numeric)))
        figures[FILES[2]] = (figure, 120)
    return figures
