"""``--plot``: one figure of a run (or several, overlaid) fit for a paper; its panels
(:data:`PANELS`) and conventions: docs/report.md, "Figure"."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ..errors import UsageError
from ..io.run_file import RunData
from .figure_style import TAUGHT_COLOR, FigureStyle, column_count, law_colors, new_figure, paper_rc, save_figure
from .build import (DEFAULT_TOLERANCES, image_error_signal, pose_error_signals, run_limits, taught_commands_along, true_depth,
                    true_depth_along)
from .result import RunReport
from .table import run_labels

#: Most points one run draws in one panel; longer runs are shown as bin means.
MAX_POINTS_PER_RUN = 600
#: Shortest loss (s) that is shaded.
MIN_SHADED_LOSS_S = 0.1
#: Seconds between two heading arrows in the top view.
HEADING_EVERY_S = 2.0
#: Height (in) of a row of time panels, of the top view, and of the legend.
ROW_HEIGHT_IN = 1.45
TOP_VIEW_HEIGHT_IN = 2.3
LEGEND_HEIGHT_IN = 0.55
#: The least share of their natural height ``--size`` may leave the panels (else labels overlap).
MIN_SCALE = 0.7
#: Colour of tolerance lines and actuator limits.
GUIDE_COLOR = "0.35"
#: Line style of a tolerance (dotted) and of the taught command in the v_c and omega_c
#: panels (dash-dot): two styles, so the legend names each once.
TOLERANCE_STYLE = ":"
TAUGHT_COMMAND_STYLE = "-."


@dataclass
class PanelContext:
    """What every panel painter gets: the runs, their colours, the tolerances."""

    runs: Sequence[RunData]
    colors: Sequence[str]
    tolerances: Mapping[str, float]
    line_styles: Mapping[str, Mapping[str, float]] = field(default_factory=dict)


def display_series(t: np.ndarray, x: np.ndarray, lost: np.ndarray | None, max_points: int = MAX_POINTS_PER_RUN) -> tuple[np.ndarray, np.ndarray]:
    """The samples of a signal as drawn: broken (NaN) where ``lost`` (K,) is true (None: never),
    joined across dropped frames, and beyond ``max_points`` the means over equal time bins."""
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float).copy()
    breaks = np.zeros(t.size, dtype=bool) if lost is None else np.asarray(lost, dtype=bool)
    x[breaks] = np.nan
    # A NaN that is not a loss (a dropped frame) is skipped: the line joins across it.
    keep = np.isfinite(x) | breaks
    t, x, breaks = t[keep], x[keep], breaks[keep]
    if t.size <= max_points or t.size < 2:
        return t, x
    edges = np.linspace(t[0], t[-1], max_points + 1)
    index = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, max_points - 1)
    seen = ~breaks
    sums = np.bincount(index, weights=np.where(seen, x, 0.0), minlength=max_points)
    valid = np.bincount(index, weights=seen.astype(float), minlength=max_points)
    centres = 0.5 * (edges[:-1] + edges[1:])
    with np.errstate(invalid="ignore", divide="ignore"):
        means = sums / valid
    # A bin without a measurement breaks the line; one with some keeps their mean.
    means[valid == 0] = np.nan
    filled = np.bincount(index, minlength=max_points) > 0
    return centres[filled], means[filled]


def lost_intervals(t: np.ndarray, lost: np.ndarray) -> list[tuple[float, float]]:
    """(start, end) times (s) of each stretch of lost steps; a step lasts until the next."""
    from ..core.metrics import step_durations

    t = np.asarray(t, dtype=float)
    lost = np.asarray(lost, dtype=bool)
    if not lost.any():
        return []
    ends = t + step_durations(t)
    edges = np.diff(np.concatenate([[0], lost.astype(int), [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    return [(float(t[a]), float(ends[b])) for a, b in zip(starts, stops)]


def _shade_losses(ax: Any, context: PanelContext) -> None:
    """Shade each loss of at least :data:`MIN_SHADED_LOSS_S` in its run's colour (shorter ones only
    break the line); a route's switches from one segment to the next as dotted lines."""
    for run, color in zip(context.runs, context.colors):
        for switch in (run.info.get("route") or {}).get("switch_times", []):
            ax.axvline(switch, color=color, ls=":", lw=0.8, zorder=0)
        for start, end in lost_intervals(run.state["t"], run.lost):
            if end - start >= MIN_SHADED_LOSS_S:
                ax.axvspan(start, end, color=color, alpha=0.15, lw=0, zorder=0)


def _runs_with(ax: Any, context: PanelContext, has: Callable[[RunData], bool], title: str,
               absent: str) -> list[tuple[RunData, str]]:
    """The runs for which ``has`` holds, with their colours; with none, the panel says ``absent``."""
    with_data = [(run, color) for run, color in zip(context.runs, context.colors) if has(run)]
    if not with_data:
        ax.set_title(title)
        ax.text(0.5, 0.5, absent, transform=ax.transAxes, ha="center", va="center", color="0.35", wrap=True)
        ax.set(xticks=[], yticks=[])
        ax.grid(False)
    return with_data


def _time_axes(ax: Any, title: str, ylabel: str) -> None:
    ax.set(title=title, xlabel="time t (s)", ylabel=ylabel)


def _band(ax: Any, tolerance: float, signed: bool, ls: Any = TOLERANCE_STYLE, lw: float = 0.9) -> None:
    for level in ((-tolerance, tolerance) if signed else (tolerance,)):
        ax.axhline(level, color=GUIDE_COLOR, ls=ls, lw=lw, zorder=1)


def _line(ax: Any, context: PanelContext, t: np.ndarray, x: np.ndarray, color: str, lost: np.ndarray | None) -> None:
    ax.plot(*display_series(t, x, lost), color=color, alpha=0.9, **context.line_styles.get(color, {}))


def _line_styles(runs: Sequence[RunData], colors: Sequence[str]) -> dict[str, dict[str, float]]:
    """Each run's line width and stacking: denser runs lower and thinner (200 Hz under 30 Hz)."""
    density = [run.steps / max(float(run.state["t"][-1] - run.state["t"][0]), 1e-9) for run in runs]
    slowest = min(density)
    order = np.argsort(np.argsort([-d for d in density], kind="stable"), kind="stable")
    return {
        color: {"zorder": 2.0 + 0.1 * float(rank), "lw": 1.0 if d <= 2.0 * slowest else 0.7}
        for color, rank, d in zip(colors, order, density)
    }


NO_POSES = "no ground-truth poses\n(a replay or a real run)"


def _pose_panel(key: str, title: str, ylabel: str, scale: float) -> Callable[[Any, PanelContext], None]:
    def paint(ax: Any, context: PanelContext) -> None:
        with_poses = _runs_with(ax, context, RunData.has_poses, title, NO_POSES)
        if not with_poses:
            return
        for run, color in with_poses:
            magnitude = np.abs(scale * pose_error_signals(run)[key])
            # A log axis cannot show an exact zero: the first step of a run started on the path.
            magnitude[magnitude <= 0] = np.nan
            _line(ax, context, run.state["t"], magnitude, color, None)
        _band(ax, scale * context.tolerances[key], signed=False)
        ax.set_yscale("log")
        _time_axes(ax, title, ylabel)

    return paint


def _image_error_panel(name: str, title: str, ylabel: str) -> Callable[[Any, PanelContext], None]:
    def paint(ax: Any, context: PanelContext) -> None:
        for run, color in zip(context.runs, context.colors):
            _line(ax, context, run.state["t"], image_error_signal(run, name), color, run.lost)
        _band(ax, context.tolerances[name], signed=True)
        _time_axes(ax, title, ylabel)

    return paint


def _command_panel(key: str, limit_key: str, title: str, ylabel: str) -> Callable[[Any, PanelContext], None]:
    def paint(ax: Any, context: PanelContext) -> None:
        for run, color in zip(context.runs, context.colors):
            _line(ax, context, run.state["t"], run.state[key], color, None)
            taught = taught_commands_along(run)[0 if key == "v_c" else 1]
            ax.plot(*display_series(run.state["t"], taught, None), color=color, lw=0.7, ls=TAUGHT_COMMAND_STYLE, zorder=1.5)
        limits = {getattr(run_limits(run), limit_key) for run in context.runs}
        for limit in sorted(value for value in limits if value is not None and math.isfinite(value)):
            _band(ax, limit, signed=True, ls="--", lw=0.8)
        _time_axes(ax, title, ylabel)

    return paint


def _distinct(values: Sequence[np.ndarray]) -> list[np.ndarray]:
    """The values unlike every earlier one (runs of one fit share a taught path and d*)."""
    kept: list[np.ndarray] = []
    for value in values:
        if not any(value.shape == k.shape and np.allclose(value, k) for k in kept):
            kept.append(value)
    return kept


def _depth_panel(ax: Any, context: PanelContext) -> None:
    for run, color in zip(context.runs, context.colors):
        _line(ax, context, run.state["t"], run.state["dhat"], color, None)
    def on_a_route(run: RunData) -> bool:
        return isinstance(run.info.get("route"), dict)

    for d_true in _distinct([np.array(d) for run in context.runs if not on_a_route(run) and (d := true_depth(run)) is not None]):
        ax.axhline(float(d_true), color=TAUGHT_COLOR, ls="--", lw=1.0, zorder=3)
    for run in filter(on_a_route, context.runs):  # each segment's d*_i while it is in force
        depths = true_depth_along(run)
        if depths is not None:
            ax.plot(run.state["t"], depths, color=TAUGHT_COLOR, ls="--", lw=1.0, zorder=3, drawstyle="steps-post")
    _time_axes(ax, r"Depth estimate $\hat{d}$ (31), true $d^*$ dashed", "depth (m)")


def _normalised_V(run: RunData) -> np.ndarray:
    """V / V(0) (dimensionless), NaN where V is unknown or not positive."""
    V = run.state["V"]
    finite = V[np.isfinite(V)]
    if finite.size == 0 or finite[0] <= 0:
        return np.full(V.size, np.nan)
    ratio = V / finite[0]
    ratio[~(ratio > 0)] = np.nan
    return ratio


def _has_V(run: RunData) -> bool:
    return bool(np.isfinite(_normalised_V(run)).any())


def _lyapunov_panel(ax: Any, context: PanelContext) -> None:
    title = "Lyapunov function V (36), relative to V(0)"
    with_V = _runs_with(ax, context, _has_V, title, "V unknown: it needs the true depth d*\n(only hbvs repeat --sim records it)")
    if not with_V:
        return
    for run, color in with_V:
        _line(ax, context, run.state["t"], _normalised_V(run), color, run.lost)
    ax.set_yscale("log")
    _time_axes(ax, title, "V / V(0) (-)")


def _top_view_geometry(run: RunData) -> dict[str, Any] | None:
    """The wall and target of a run's metadata (``top_view``), checked; None if absent."""
    data = run.info.get("top_view")
    if not isinstance(data, Mapping):
        return None
    try:
        wall_x = float(data["wall_x"])
        poster_y = np.asarray(data["poster_y"], dtype=float).reshape(2)
        target = np.asarray(data["target_xy"], dtype=float).reshape(-1, 2)
    except (KeyError, TypeError, ValueError):
        return None
    if not (np.isfinite(wall_x) and np.all(np.isfinite(poster_y)) and np.all(np.isfinite(target)) and 0 < target.shape[0] <= 64):
        return None
    return {"wall_x": wall_x, "poster_y": poster_y, "target_xy": target}


def _heading_arrows(ax: Any, pose: np.ndarray, t: np.ndarray, color: str, length: float) -> None:
    """The robot's heading as arrows, one every :data:`HEADING_EVERY_S` seconds."""
    marks = np.searchsorted(t, np.arange(t[0], t[-1] + 1e-9, HEADING_EVERY_S))
    marks = marks[marks < t.size]
    ax.quiver(
        pose[marks, 0], pose[marks, 1], length * np.cos(pose[marks, 2]), length * np.sin(pose[marks, 2]),
        color=color, angles="xy", scale_units="xy", scale=1.0, width=0.004, headwidth=4, headlength=5, zorder=4,
    )


def _draw_paths(ax: Any, with_poses: Sequence[tuple[RunData, str]]) -> None:
    for run, color in with_poses:
        ax.plot(run.true_pose[:, 0], run.true_pose[:, 1], color=color, lw=1.2, zorder=2)
        ax.plot(*run.true_pose[0, :2], marker="o", color=color, ms=3.5, zorder=4)
    # The taught path on top of the repeated ones: a converged run hides under it otherwise.
    for taught in _distinct([run.desired_pose for run, _ in with_poses]):
        ax.plot(taught[:, 0], taught[:, 1], color=TAUGHT_COLOR, ls=(0, (4, 3)), lw=1.0, zorder=5)


def _top_view_panel(ax: Any, context: PanelContext) -> None:
    """The scene to scale, and the paths with y stretched (centimetres vanish at the wall's scale)."""
    with_poses = _runs_with(ax, context, RunData.has_poses, "Top view", NO_POSES)
    if not with_poses:
        return
    ax.set_axis_off()
    one_column = ax.get_subplotspec().get_gridspec().ncols == 1
    boxes = ax.get_subplotspec().subgridspec(2, 1) if one_column else ax.get_subplotspec().subgridspec(1, 2, width_ratios=[1.0, 1.25])
    scene = ax.figure.add_subplot(boxes[0], label="top_scene")
    zoom = ax.figure.add_subplot(boxes[1], label="top_paths")
    _scene_view(scene, with_poses)
    _draw_paths(zoom, with_poses)
    zoom.set(title="Paths, y stretched: taught (dashed), repeated", xlabel="x (m)", ylabel="y (m)")


def _scene_view(ax: Any, with_poses: Sequence[tuple[RunData, str]]) -> None:
    ax.set_title(f"Top view to scale; arrows: heading every {HEADING_EVERY_S:g} s")
    _draw_paths(ax, with_poses)
    paths = np.concatenate([np.concatenate([run.true_pose[:, :2], run.desired_pose[:, :2]]) for run, _ in with_poses])
    low, high = paths.min(axis=0), paths.max(axis=0)
    geometry = next((g for g in (_top_view_geometry(run) for run, _ in with_poses) if g is not None), None)
    if geometry is not None:
        y_low, y_high = sorted(geometry["poster_y"])
        ax.plot([geometry["wall_x"]] * 2, [y_low - 0.4, y_high + 0.4], color="0.6", lw=2.0, solid_capstyle="butt", zorder=1)
        ax.plot([geometry["wall_x"]] * 2, [y_low, y_high], color=TAUGHT_COLOR, lw=3.0, solid_capstyle="butt", zorder=2)
        ax.plot(geometry["target_xy"][:, 0], geometry["target_xy"][:, 1], ls="none", marker="o", ms=3.5,
                mfc="white", mec=TAUGHT_COLOR, zorder=6)
        ax.annotate("wall, target", (geometry["wall_x"], y_high + 0.4), xytext=(-4, 0),
                    textcoords="offset points", ha="right", va="top", fontsize=6.5, color="0.3")
        low = np.minimum(low, [geometry["wall_x"], y_low - 0.4])
        high = np.maximum(high, [geometry["wall_x"], y_high + 0.4])
    span = float(np.max(high - low)) or 1.0
    for run, color in with_poses:
        _heading_arrows(ax, run.true_pose, run.state["t"], color, 0.08 * span)
    ax.margins(0.06)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set(xlabel="x (m)", ylabel="y (m)")


#: Every panel of the run figure, in the default order.
PANELS: dict[str, Callable[[Any, PanelContext], None]] = {
    "position": _pose_panel("position_m", "Position error against the taught pose", "position error (cm)", 100.0),
    "heading": _pose_panel("heading_deg", "Heading error against the taught pose", "|heading error| (deg)", 1.0),
    "e1": _image_error_panel("e1", r"Longitudinal image error $e_1$ (19)", r"$e_1$ (units of $d^*$)"),
    "ebar2": _image_error_panel("ebar2", r"Lateral image error $\bar{e}_2$ (27)", r"$\bar{e}_2$ (units of $d^*$)"),
    "e2": _image_error_panel("e2", r"Lateral image error $e_2$ (19)", r"$e_2$ (units of $d^*$)"),
    "e3": _image_error_panel("e3", r"Rotation error $e_3$ (19)", r"$e_3$ (deg)"),
    "v": _command_panel("v_c", "max_v", r"Linear velocity command $v_c$ (29)", r"$v_c$ (m/s)"),
    "w": _command_panel("w_c", "max_w", r"Angular velocity command $\omega_c$ (30)", r"$\omega_c$ (rad/s)"),
    "dhat": _depth_panel,
    "V": _lyapunov_panel,
    "top": _top_view_panel,
}
PANEL_NAMES = tuple(PANELS)


def _row_heights(panels: Sequence[str], columns: int) -> list[float]:
    """Height (in) of each row at its natural size: the time panels', then the top view's."""
    rows = math.ceil(len([name for name in panels if name != "top"]) / columns)
    top_height = TOP_VIEW_HEIGHT_IN * (2 if columns == 1 else 1)   # one column: scene above paths
    return [ROW_HEIGHT_IN] * rows + ([top_height] if "top" in panels else [])


def _layout(panels: Sequence[str], style: FigureStyle) -> tuple[tuple[float, float], int]:
    """Figure size (in) and number of columns; UsageError when ``--size`` leaves the panels less than :data:`MIN_SCALE` of their height."""
    width, columns = column_count(style, len(panels))
    content = sum(_row_heights(panels, columns))
    if style.size_in is None:
        return (width, content + LEGEND_HEIGHT_IN), columns
    least = MIN_SCALE * content + LEGEND_HEIGHT_IN
    if style.size_in[1] < least:
        need = math.ceil(least * 2.0) / 2.0
        raise UsageError(
            f"--size {width:g}x{style.size_in[1]:g} is too short for {len(panels)} panels in "
            f"{'one column' if columns == 1 else 'two columns'}: give at least {width:g}x{need:g}, or fewer --panels"
            + (" (e.g. --size 3.5x8 --panels position,heading,v,w,top)" if columns == 1 else "")
        )
    return style.size_in, columns


#: Panels only a run with ground truth has data for, each with the test whether a run has it (poses, d*).
GROUND_TRUTH_PANELS: dict[str, Callable[[RunData], bool]] = {
    "position": RunData.has_poses, "heading": RunData.has_poses, "V": _has_V, "top": RunData.has_poses,
}


def figure_panels(runs: Sequence[RunData], style: FigureStyle) -> list[str]:
    """The panels drawn: ``--panels``, by default every panel for which a run has data."""
    if style.panels is not None:
        return list(style.panels)
    absent = {name for name, has in GROUND_TRUTH_PANELS.items() if not any(has(run) for run in runs)}
    return [name for name in PANEL_NAMES if name not in absent]


def check_figure_size(runs: Sequence[RunData], style: FigureStyle) -> None:
    """Refuse a ``--size`` the panels of these runs do not fit in (see :func:`_layout`)."""
    _layout(figure_panels(runs, style), style)


def _run_legend_label(label: str, report: RunReport, run: RunData, panels: Sequence[str]) -> str:
    """A run's legend entry: its label and status; a run left out of the ground-truth panels
    that are drawn says so here rather than in every panel's title."""
    absent = not any(has(run) for has in GROUND_TRUTH_PANELS.values()) and any(name in panels for name in GROUND_TRUTH_PANELS)
    status = "converged" if report.verdict.converged else "not converged"
    status = "open-loop replay" if report.run.source.mode == "replay" else status
    return f"{label} ({status}{'; no ground truth' if absent else ''})"


def _legend_handles(runs: Sequence[RunData], reports: Sequence[RunReport], colors: Sequence[str], panels: Sequence[str]) -> list[Any]:
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles: list[Any] = [
        Line2D([], [], color=color, lw=2.0, label=_run_legend_label(label, report, run, panels))
        for color, label, report, run in zip(colors, run_labels(reports), reports, runs)
    ]
    if "top" in panels or "dhat" in panels:
        handles.append(Line2D([], [], color=TAUGHT_COLOR, ls=(0, (4, 3)), lw=1.1, label="taught / true"))
    handles.append(Line2D([], [], color=GUIDE_COLOR, ls=TOLERANCE_STYLE, lw=0.9, label="tolerance"))
    if "v" in panels or "w" in panels:
        handles.append(Line2D([], [], color=GUIDE_COLOR, ls=TAUGHT_COMMAND_STYLE, lw=0.9, label="taught command (25)"))
        handles.append(Line2D([], [], color=GUIDE_COLOR, ls="--", lw=0.8, label="actuator limit"))
    handles.append(Patch(color="0.5", alpha=0.3, lw=0, label="target lost"))
    return handles


def plot_runs(
    runs: Sequence[RunData], reports: Sequence[RunReport], style: FigureStyle | None = None,
    tolerances: Mapping[str, float] | None = None,
) -> Any:
    """The unsaved figure of one or several runs, overlaid; ``reports`` give the legend, each axes is labelled with its panel name."""
    import matplotlib

    style = style or FigureStyle()
    panels = figure_panels(runs, style)
    colors = law_colors([report.run.law for report in reports])
    context = PanelContext(runs, colors, {**DEFAULT_TOLERANCES, **(tolerances or {})}, _line_styles(runs, colors))
    size, columns = _layout(panels, style)
    with matplotlib.rc_context(paper_rc()):
        figure = new_figure(size, style.dpi)
        time_panels = [name for name in panels if name != "top"]
        ratios = _row_heights(panels, columns)
        grid = figure.add_gridspec(len(ratios), columns, height_ratios=ratios)
        slots = {name: grid[index // columns, index % columns] for index, name in enumerate(time_panels)}
        slots["top"] = grid[-1, :]  # the top view's row, the last, when it is drawn
        start = min(float(run.state["t"][0]) for run in runs)
        end = max(float(run.state["t"][-1]) for run in runs)
        for name in panels:
            ax = figure.add_subplot(slots[name])
            ax.set_label(name)
            PANELS[name](ax, context)
            if name != "top" and ax.get_lines():  # a time panel with data
                _shade_losses(ax, context)
                if end > start:
                    ax.set_xlim(start, end)
            if columns == 1 and name != "top" and name != time_panels[-1] and ax.get_lines():
                # Stacked in one column: the shared time axis is labelled once, under the last.
                ax.tick_params(labelbottom=False)
                ax.set_xlabel("")
        handles = _legend_handles(runs, reports, context.colors, panels)
        figure.legend(handles=handles, loc="outside upper center", ncols=min(len(handles), 4 if columns > 1 else 2))
    return figure


def save_plot(
    runs: Sequence[RunData], reports: Sequence[RunReport], path: Path, style: FigureStyle | None = None,
    tolerances: Mapping[str, float] | None = None,
) -> Any:
    """Draw :func:`plot_runs` and write it to ``path`` (:func:`save_figure`); returns the figure."""
    style = style or FigureStyle()
    figure = plot_runs(runs, reports, style, tolerances)
    save_figure(figure, path, style.dpi)
    return figure
