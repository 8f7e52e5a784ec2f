"""``hbvs report fit.mcap``: what the fit did to the taught signals (Remark 1): raw against
smoothed theta_d, x_hd1, x_hd2, and the spline's x_hd1_dot (fed forward by (29)-(30))
against a finite difference of the raw samples."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..errors import RecordingError
from ..io.topics import MODEL_TOPIC, TOPICS
from ..io.topics import RAW_DESIRED_TOPIC as RAW_TOPIC
from ..io.topics import SMOOTH_DESIRED_TOPIC as SMOOTH_TOPIC
from .figure_style import TAUGHT_COLOR, FigureStyle, PALETTE, column_count, new_figure, paper_rc

#: Fields of each signal, per topic.
RAW_FIELDS = ("t", "theta_d", "x_hd1", "x_hd2")
SMOOTH_FIELDS = ("t", "theta_d", "x_hd1", "x_hd2", "theta_d_dot", "x_hd1_dot", "x_hd2_dot")
#: The splines' standard deviations (a fit without the joint estimate of n* has none).
SIGMA_FIELDS = ("theta_d_sigma", "x_hd1_sigma")
#: Panels of the fit figure, in order.
FIT_PANELS = ("theta_d", "theta_d_residual", "x_hd1", "x_hd1_residual", "x_hd2", "x_hd2_residual", "x_hd1_dot")
#: A gap between raw samples longer than this many median frame intervals is shaded.
GAP_FRAMES = 1.5
#: Legend labels of the fitted curves: theta_d and x_hd1 are smoothing splines, x_hd2 comes from (25).
SPLINE_LABEL = r"smoothing spline ($\theta_d$, $x_{hd1}$)"
INTEGRATED_LABEL = r"$x_{hd2}$ integrated by (25)"


@dataclass
class FitSignals:
    """The raw and smoothed desired signals of a fit file (arrays, one per field)."""

    name: str
    raw: dict[str, np.ndarray]
    smooth: dict[str, np.ndarray]
    fit_min_abs_xhd1_dot: float | None


def _column(messages: list[dict[str, Any]], key: str, name: str, topic: str) -> np.ndarray:
    values = []
    for message in messages:
        value = message.get(key)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise RecordingError(f"{name}: malformed {topic} message ({key} = {str(value)[:40]!r})")
        values.append(float(value))
    return np.array(values)


def read_fit_signals(source: Any, name: str = "") -> FitSignals:
    """The raw and smoothed desired signals of a fit file (path, ``-`` or binary stream)."""
    from ..io.mcap import McapStream, read_metadata

    stream = McapStream(source, topics={RAW_TOPIC, SMOOTH_TOPIC, MODEL_TOPIC}, schemas=TOPICS["fit"], name=name)
    messages: dict[str, list[dict[str, Any]]] = {RAW_TOPIC: [], SMOOTH_TOPIC: []}
    model: dict[str, Any] = {}
    for message in stream:
        if message.topic == MODEL_TOPIC:
            model = message.json(stream.name)
        else:
            messages[message.topic].append(message.json(stream.name))
    info = read_metadata(stream, "hbvs")
    if info.get("file_kind") not in (None, "fit"):
        raise RecordingError(f"{stream.name}: a {info.get('file_kind')!r} file, not a fit file")
    if not messages[RAW_TOPIC] or not messages[SMOOTH_TOPIC]:
        raise RecordingError(f"{stream.name}: no desired signals in it (is it the output of hbvs fit, and complete?)")
    raw = {key: _column(messages[RAW_TOPIC], key, stream.name, RAW_TOPIC) for key in RAW_FIELDS}
    smooth = {key: _column(messages[SMOOTH_TOPIC], key, stream.name, SMOOTH_TOPIC) for key in SMOOTH_FIELDS}
    for key in SIGMA_FIELDS:
        if all(message.get(key) is not None for message in messages[SMOOTH_TOPIC]):
            smooth[key] = _column(messages[SMOOTH_TOPIC], key, stream.name, SMOOTH_TOPIC)
    for signals, topic in ((raw, RAW_TOPIC), (smooth, SMOOTH_TOPIC)):
        if not all(np.all(np.isfinite(v)) for v in signals.values()) or np.any(np.diff(signals["t"]) <= 0):
            raise RecordingError(f"{stream.name}: {topic} holds values that are not finite or times that do not increase")
    condition = model.get("condition35") if isinstance(model.get("condition35"), Mapping) else {}
    fitted = condition.get("min_abs_xhd1_dot")
    return FitSignals(
        name=stream.name, raw=raw, smooth=smooth,
        fit_min_abs_xhd1_dot=float(fitted) if isinstance(fitted, (int, float)) and not isinstance(fitted, bool) and math.isfinite(fitted) else None,
    )


def raw_derivative(t: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Finite difference of raw samples: (midpoint times, slopes)."""
    return 0.5 * (t[1:] + t[:-1]), np.diff(x) / np.diff(t)


def _raw_minus_smooth(signals: FitSignals, key: str, scale: float) -> np.ndarray:
    raw, smooth = signals.raw, signals.smooth
    return scale * (raw[key] - np.interp(raw["t"], smooth["t"], smooth[key]))


def fit_summary(signals: FitSignals) -> dict[str, Any]:
    """The numbers of a fit report (JSON-ready): raw minus smooth at the raw frames (theta_d
    in deg), the spline's x_hd1_dot extremes (1/s) and the finite difference's RMS about it."""
    from ..core.metrics import round_significant

    raw, smooth = signals.raw, signals.smooth
    differences: dict[str, Any] = {}
    for key, scale, label in (("theta_d", 180.0 / math.pi, "theta_d_deg"), ("x_hd1", 1.0, "x_hd1"), ("x_hd2", 1.0, "x_hd2")):
        difference = _raw_minus_smooth(signals, key, scale)
        differences[label] = {"rms": float(np.sqrt(np.mean(difference**2))), "max_abs": float(np.max(np.abs(difference)))}
    t_mid, slope = raw_derivative(raw["t"], raw["x_hd1"])
    about = slope - np.interp(t_mid, smooth["t"], smooth["x_hd1_dot"])
    feed_forward = np.abs(smooth["x_hd1_dot"])
    summary = {
        "file": signals.name, "frames_raw": int(raw["t"].size), "frames_smooth": int(smooth["t"].size),
        "raw_minus_smooth": differences,
        "x_hd1_dot": {"min_abs": float(feed_forward.min()), "max_abs": float(feed_forward.max()),
                      "raw_difference_rms": float(np.sqrt(np.mean(about**2))) if about.size else None},
    }
    return round_significant(summary, 7)


def _gaps(t: np.ndarray) -> list[tuple[float, float]]:
    """Stretches between raw samples longer than :data:`GAP_FRAMES` frame intervals."""
    if t.size < 3:
        return []
    steps = np.diff(t)
    long = np.flatnonzero(steps > GAP_FRAMES * np.median(steps))
    return [(float(t[k]), float(t[k + 1])) for k in long]


def plot_fit(signals: FitSignals, style: FigureStyle | None = None) -> Any:
    """The unsaved fit figure, each axes labelled with its :data:`FIT_PANELS` name."""
    import matplotlib

    style = style or FigureStyle()
    panels = list(style.panels or FIT_PANELS)
    width, columns = column_count(style, len(panels))
    rows = math.ceil(len(panels) / columns)
    size = style.size_in or (width, 1.55 * rows + 0.45)
    raw, smooth = signals.raw, signals.smooth
    degrees = 180.0 / math.pi
    signal_panels = {
        "theta_d": (r"Desired rotation $\theta_d$ (Remark 1)", r"$\theta_d$ (deg)", "theta_d", degrees, SPLINE_LABEL),
        "x_hd1": (r"Desired translation $x_{hd1}$", r"$x_{hd1}$ (units of $d^*$)", "x_hd1", 1.0, SPLINE_LABEL),
        "x_hd2": (r"Desired translation $x_{hd2}$", r"$x_{hd2}$ (units of $d^*$)", "x_hd2", 1.0, INTEGRATED_LABEL),
    }
    with matplotlib.rc_context(paper_rc()):
        figure = new_figure(size, style.dpi)
        grid = figure.add_gridspec(rows, columns)
        for index, name in enumerate(panels):
            last_alone = index == len(panels) - 1 and columns == 2 and len(panels) % 2 == 1
            ax = figure.add_subplot(grid[index // columns, :] if last_alone else grid[index // columns, index % columns])
            ax.set_label(name)
            if name == "x_hd1_dot":
                _paint_feed_forward(ax, raw, smooth)
            elif name.endswith("_residual"):
                title, _, key, scale, how = signal_panels[name.removesuffix("_residual")]
                ax.plot(raw["t"], _raw_minus_smooth(signals, key, scale), ls="none", marker="o", ms=1.6, mew=0, color="0.45")
                ax.axhline(0.0, color=PALETTE[0], lw=1.0)
                unit = "deg" if key == "theta_d" else "units of $d^*$"
                ax.set(title=f"{title.split(' (')[0]}: raw minus {'integrated' if how == INTEGRATED_LABEL else 'smoothing'}",
                       ylabel=f"difference ({unit})")
            else:
                title, ylabel, key, scale, how = signal_panels[name]
                ax.plot(raw["t"], scale * raw[key], ls="none", marker="o", ms=1.6, mew=0, color="0.55", label="raw: one homography per frame")
                ax.plot(smooth["t"], scale * smooth[key], color=PALETTE[0], lw=1.2, label=how)
                if f"{key}_sigma" in smooth:
                    band = 1.96 * scale * smooth[f"{key}_sigma"]
                    ax.fill_between(smooth["t"], scale * smooth[key] - band, scale * smooth[key] + band, color=PALETTE[0],
                                    alpha=0.2, lw=0, label="95 % interval (n*, reference points, noise)")
                ax.set(title=title, ylabel=ylabel)
            for start, end in _gaps(raw["t"]):
                ax.axvspan(start, end, color="0.5", alpha=0.2, lw=0, zorder=0)
            ax.set_xlabel("time t (s)")
        figure.suptitle(f"Desired trajectory fitted by hbvs fit ({Path(signals.name).name}); shaded: target not found")
        _figure_legend(figure)
    return figure


def _figure_legend(figure: Any) -> None:
    """One legend under the panels for every labelled line (in a panel's corner it covered
    the curves it named)."""
    handles: dict[str, Any] = {}
    for ax in figure.axes:
        for handle, label in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(label, handle)
    if handles:
        figure.legend(handles.values(), handles.keys(), loc="outside lower center", ncols=min(3, len(handles)),
                      fontsize=6.5, handlelength=1.8, markerscale=2.5)


def _paint_feed_forward(ax: Any, raw: Mapping[str, np.ndarray], smooth: Mapping[str, np.ndarray]) -> None:
    """x_hd1_dot of the spline (what (29)-(30) feed forward) against a raw finite difference."""
    t_mid, slope = raw_derivative(raw["t"], raw["x_hd1"])
    ax.plot(t_mid, slope, color="0.6", lw=0.5, label=r"finite difference of raw $x_{hd1}$")
    ax.plot(smooth["t"], smooth["x_hd1_dot"], color=PALETTE[0], lw=1.4, label=r"spline derivative $\dot{x}_{hd1}$ (fed forward)")
    ax.axhline(0.0, color=TAUGHT_COLOR, lw=0.6)
    values = smooth["x_hd1_dot"]
    # Zero in view (condition (35)) and the spline's range; raw spikes may leave the frame.
    low, high = min(float(values.min()), 0.0), max(float(values.max()), 0.0)
    pad = 0.25 * (high - low) + 1e-9
    ax.set_ylim(low - pad, high + pad)
    ax.set(title=r"Feed-forward $\dot{x}_{hd1}$ of (29)-(30); condition (35) needs it away from 0", ylabel=r"$\dot{x}_{hd1}$ (1/s)")

