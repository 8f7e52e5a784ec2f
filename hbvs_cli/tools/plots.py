"""``--plot``: one figure of a run (or several, overlaid) fit for a paper.

Eight panels on a 4 x 2 grid, 12 x 10 in at 100 dpi (1200 x 1000 px):

* e1 and ebar2 (units of d*), e3 (deg) against time: (19), (27);
* the commands v_c (m/s) and w_c (rad/s) sent to the robot;
* the depth estimate dhat (m), with the true d* dashed when known;
* the Lyapunov function V (36) on a log scale (simulation only);
* the top view of the taught (dashed) and repeated (solid) paths (m, equal aspect);
* the position error against the taught path at the same time (cm).

Each run has one colour throughout; the figure legend names the runs by law and file.
A panel whose data no run has (a replay has no poses and no V) says so in its middle.
matplotlib is imported here only, with the Agg backend: no display is ever needed.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ..errors import InputError, UsageError
from ..io.run_file import RunData
from .report_data import image_error_signal, pose_error_signals
from .report_table import run_label

#: Figure size (in) and resolution (dpi): 1200 x 1000 px.
FIGURE_SIZE_IN = (12.0, 10.0)
FIGURE_DPI = 100


def _figure() -> tuple[Any, Any]:
    """A figure on the Agg canvas (no pyplot: no global state, no display) and its 4 x 2 axes."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=FIGURE_SIZE_IN, dpi=FIGURE_DPI, layout="constrained")
    FigureCanvasAgg(figure)
    axes = figure.subplots(4, 2)
    return figure, axes


def supported_formats() -> set[str]:
    """File suffixes (without the dot) the Agg canvas can write: png, pdf, svg..."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    return set(FigureCanvasAgg.get_supported_filetypes())


def check_plot_path(path: Path) -> None:
    """Fail early, before any work, on a figure path that cannot be written.

    Raises
    ------
    UsageError
        A suffix matplotlib cannot write.
    InputError
        The folder does not exist.
    """
    suffix = path.suffix.lower().lstrip(".")
    formats = supported_formats()
    if suffix not in formats:
        raise UsageError(f"--plot {path}: unknown figure format {path.suffix!r}; use .png (or {', '.join(sorted(formats - {'png'}))})")
    if not path.parent.exists():
        raise InputError(f"--plot {path}: the folder {path.parent} does not exist")


def _say_absent(ax: Any, message: str) -> None:
    """Mark a panel with no data: a message in its middle, no ticks."""
    ax.text(0.5, 0.5, message, transform=ax.transAxes, ha="center", va="center", fontsize=11, color="0.35", wrap=True)
    ax.set_xticks([])
    ax.set_yticks([])


def _time_panel(ax: Any, title: str, ylabel: str) -> None:
    ax.set_title(title, fontsize=11)
    ax.set_xlabel("time t (s)")
    ax.set_ylabel(ylabel)
    ax.grid(True, alpha=0.3)


def _plot_errors(ax_e: Any, ax_e3: Any, runs: Sequence[RunData], colors: Sequence[Any]) -> None:
    for run, color in zip(runs, colors):
        t = run.state["t"]
        ax_e.plot(t, image_error_signal(run, "e1"), color=color, lw=1.4)
        ax_e.plot(t, image_error_signal(run, "ebar2"), color=color, lw=1.4, ls="--")
        ax_e3.plot(t, image_error_signal(run, "e3"), color=color, lw=1.4)
    _time_panel(ax_e, "translation errors e1 (19), ebar2 (27)", "error (units of d*)")
    _time_panel(ax_e3, "rotation error e3 (19)", "e3 (deg)")
    _style_legend(ax_e, {"e1": "-", "ebar2": "--"})


def _style_legend(ax: Any, styles: Mapping[str, str]) -> None:
    """A legend of line styles (the colours name runs, in the figure legend)."""
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], color="0.2", ls=style, lw=1.4, label=label) for label, style in styles.items()]
    ax.legend(handles=handles, loc="best", fontsize=9, framealpha=0.8)


def _plot_commands(ax_v: Any, ax_w: Any, runs: Sequence[RunData], colors: Sequence[Any]) -> None:
    from ..core.metrics import taught_commands

    drawn: set[tuple[str, float]] = set()
    for run, color in zip(runs, colors):
        t = run.state["t"]
        ax_v.plot(t, run.state["v_c"], color=color, lw=1.4)
        ax_w.plot(t, run.state["w_c"], color=color, lw=1.4)
        d_true = run.info.get("d_true")
        dhat = run.state["dhat"][np.isfinite(run.state["dhat"])]
        depth = float(d_true) if isinstance(d_true, (int, float)) and d_true > 0 else (float(dhat[-1]) if dhat.size else float("nan"))
        v_d, w_d = taught_commands(run.state["x_hd2"], run.state["x_hd1_dot"], run.state["theta_d_dot"], depth)
        ax_v.plot(t, v_d, color=color, lw=1.0, ls=":")
        ax_w.plot(t, w_d, color=color, lw=1.0, ls=":")
        limits = ((run.info.get("settings") or {}).get("limits")) or {}
        for ax, name in ((ax_v, "max_v"), (ax_w, "max_w")):
            bound = limits.get(name)
            if isinstance(bound, (int, float)) and bound > 0 and (name, float(bound)) not in drawn:
                drawn.add((name, float(bound)))
                for sign in (-1.0, 1.0):
                    ax.axhline(sign * bound, color="0.4", lw=1.0, ls="--")
    _style_legend(ax_v, {"sent": "-", "taught (25)": ":", "limit": "--"})
    _time_panel(ax_v, "linear velocity command v_c (29)", "v_c (m/s)")
    _time_panel(ax_w, "angular velocity command w_c (30)", "w_c (rad/s)")


def _distinct(values: Sequence[np.ndarray]) -> list[np.ndarray]:
    """The values that differ from every earlier one: runs of one fit share a taught path and d*."""
    kept: list[np.ndarray] = []
    for value in values:
        if not any(value.shape == k.shape and np.allclose(value, k) for k in kept):
            kept.append(value)
    return kept


def _note_missing(ax: Any, runs: Sequence[RunData], has_data: Callable[[RunData], bool]) -> None:
    """When only some runs have the panel's data, name the others in the title (not over the data)."""
    missing = [Path(run.name).name for run in runs if not has_data(run)]
    if missing:
        ax.set_title(f"{ax.get_title()}\n(no data: {', '.join(missing)})", fontsize=11)


def _has_d_true(run: RunData) -> bool:
    return isinstance(run.info.get("d_true"), (int, float))


def _plot_depth(ax: Any, runs: Sequence[RunData], colors: Sequence[Any]) -> None:
    for run, color in zip(runs, colors):
        ax.plot(run.state["t"], run.state["dhat"], color=color, lw=1.4)
    truths = _distinct([np.array(float(run.info["d_true"])) for run in runs if _has_d_true(run)])
    for d_true in truths:
        ax.axhline(float(d_true), color="k", ls="--", lw=1.2)
    _time_panel(ax, "depth estimate dhat (31)", "depth (m)")
    _style_legend(ax, {"dhat": "-", "true d*": "--"} if truths else {"dhat": "-"})


def _positive_V(run: RunData) -> np.ndarray:
    """Steps with a V a log axis can show (known and > 0)."""
    V = run.state["V"]
    return np.isfinite(V) & (V > 0)


def _has_V(run: RunData) -> bool:
    return bool(_positive_V(run).any())


def _plot_lyapunov(ax: Any, runs: Sequence[RunData], colors: Sequence[Any]) -> None:
    with_V = [(run, color) for run, color in zip(runs, colors) if _has_V(run)]
    if not with_V:
        _say_absent(ax, "V unknown: it needs the true depth d*\n(only hbvs repeat --sim records it)")
        ax.set_title("Lyapunov function V (36)", fontsize=11)
        return
    for run, color in with_V:
        keep = _positive_V(run)
        ax.plot(run.state["t"][keep], run.state["V"][keep], color=color, lw=1.4)
    ax.set_yscale("log")
    _time_panel(ax, "Lyapunov function V (36)", "V (units of (36), log scale)")
    _note_missing(ax, runs, _has_V)


def _has_poses(run: RunData) -> bool:
    return run.true_pose is not None and run.desired_pose is not None


def _plot_top_view(ax: Any, runs: Sequence[RunData], colors: Sequence[Any]) -> None:
    ax.set_title("top view: taught (black, dashed) and repeated paths", fontsize=11)
    with_poses = [(run, color) for run, color in zip(runs, colors) if _has_poses(run)]
    if not with_poses:
        _say_absent(ax, "no ground-truth poses\n(a replay or a real run)")
        return
    for taught in _distinct([run.desired_pose for run, _ in with_poses]):
        ax.plot(taught[:, 0], taught[:, 1], color="k", ls="--", lw=1.2)
    for run, color in with_poses:
        ax.plot(run.true_pose[:, 0], run.true_pose[:, 1], color=color, lw=1.6)
        ax.plot(*run.true_pose[0, :2], marker="o", color=color, ms=5)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    _style_legend(ax, {"taught": "--", "repeated (o: start)": "-"})
    _note_missing(ax, runs, _has_poses)


def _plot_position_error(ax: Any, runs: Sequence[RunData], colors: Sequence[Any]) -> None:
    with_poses = [(run, color) for run, color in zip(runs, colors) if _has_poses(run)]
    if not with_poses:
        _say_absent(ax, "no ground-truth poses:\nno position error")
        ax.set_title("position error", fontsize=11)
        return
    for run, color in with_poses:
        ax.plot(run.state["t"], 100.0 * pose_error_signals(run)["position_m"], color=color, lw=1.4)
    _time_panel(ax, "position error against the taught path", "position error (cm)")
    ax.set_ylim(bottom=0.0)
    _note_missing(ax, runs, _has_poses)


#: Panel painters in grid order: each takes its axes, the runs and their colours.
_PANELS: tuple[tuple[tuple[int, ...], Callable[..., None]], ...] = (
    ((0, 1), _plot_errors),
    ((2, 3), _plot_commands),
    ((4,), _plot_depth),
    ((5,), _plot_lyapunov),
    ((6,), _plot_top_view),
    ((7,), _plot_position_error),
)


def _status(report: Mapping[str, Any]) -> str:
    if report["run"]["source"].get("mode") == "replay":
        return "open-loop replay"
    return "converged" if report["verdict"]["converged"] else "not converged"


def plot_runs(runs: Sequence[RunData], reports: Sequence[Mapping[str, Any]]) -> Any:
    """The figure of one or several runs (overlaid, one colour per run).

    Parameters
    ----------
    runs : list of RunData
    reports : list of dict
        Their reports (for the runs' names and verdicts in the legend).

    Returns
    -------
    matplotlib.figure.Figure
        12 x 10 in at 100 dpi, not yet saved.
    """
    figure, axes = _figure()
    flat = axes.ravel()
    colors = [f"C{index % 10}" for index in range(len(runs))]
    for indices, paint in _PANELS:
        paint(*(flat[i] for i in indices), runs, colors)
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], color=color, lw=2.0, label=f"{run_label(report)} ({_status(report)})") for color, report in zip(colors, reports)]
    figure.legend(handles=handles, loc="outside upper center", ncols=min(len(handles), 3), fontsize=10, frameon=False)
    return figure


def save_plot(runs: Sequence[RunData], reports: Sequence[Mapping[str, Any]], path: Path) -> Any:
    """Draw :func:`plot_runs` and write it to ``path`` (format from the suffix); returns the figure.

    Raises
    ------
    InputError
        The file cannot be written.
    """
    figure = plot_runs(runs, reports)
    try:
        figure.savefig(path, dpi=FIGURE_DPI)
    except OSError as exc:
        raise InputError(f"{path}: cannot write the figure ({exc.strerror or exc})") from None
    return figure
