"""The look shared by every hbvs figure: sized in inches for a two-column paper with 7-9 pt
fonts, the colour-blind safe Okabe-Ito palette, the taught path black and dashed."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

from ..core.control_settings import ALL_LAWS
from ..errors import OutputError, UsageError
from ..settings.commands import DEFAULT_DPI

#: Okabe-Ito colours, in the order runs get them (black is kept for the taught path).
PALETTE = ("#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#F0E442")
#: The taught path / desired signal, and the truth: black.
TAUGHT_COLOR = "black"
#: Width (in) unless ``--size`` says otherwise: a two-column figure of a paper.
DEFAULT_WIDTH_IN = 7.0
#: Below this width (in) panels are stacked in one column.
ONE_COLUMN_BELOW_IN = 4.5
#: The figure may be neither smaller nor larger than this (in), either way.
SIZE_RANGE_IN = (1.5, 40.0)


@dataclass(frozen=True)
class FigureStyle:
    """How to draw a figure: ``size_in`` (width, height) in inches, ``panels`` in drawing order (None: default)."""

    dpi: float = DEFAULT_DPI
    size_in: tuple[float, float] | None = None
    panels: tuple[str, ...] | None = None


def column_count(style: FigureStyle, panels: int) -> tuple[float, int]:
    """The figure's width (in) and its columns of panels (one below :data:`ONE_COLUMN_BELOW_IN`)."""
    width = style.size_in[0] if style.size_in else DEFAULT_WIDTH_IN
    return width, 1 if width < ONE_COLUMN_BELOW_IN or panels == 1 else 2


def parse_size(text: str) -> tuple[float, float]:
    """``"7x5"`` (inches, width x height) -> ``(7.0, 5.0)``, each in :data:`SIZE_RANGE_IN`."""
    match = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*[xX*,]\s*([0-9]*\.?[0-9]+)\s*", text or "")
    if not match:
        raise UsageError(f"--size {text!r}: give WIDTHxHEIGHT in inches, e.g. 3.5x8 (one column) or 7x9")
    width, height = float(match.group(1)), float(match.group(2))
    low, high = SIZE_RANGE_IN
    if not (low <= width <= high and low <= height <= high):
        raise UsageError(f"--size {text!r}: each side must be between {low:g} and {high:g} inches")
    return width, height


def parse_panels(text: str, known: Sequence[str]) -> tuple[str, ...]:
    """``"position,heading,top"`` -> the panel names, each in ``known`` and given once."""
    names = [name.strip() for name in (text or "").split(",") if name.strip()]
    if not names:
        raise UsageError(f"--panels: name at least one panel ({', '.join(known)})")
    unknown = [name for name in names if name not in known]
    if unknown:
        raise UsageError(f"--panels: unknown panel {unknown[0]!r}; use some of {', '.join(known)}")
    if len(set(names)) != len(names):
        raise UsageError("--panels: a panel is named twice")
    return tuple(names)


def figure_style(dpi: float | None, size: str | None, panels: str | None, known_panels: Sequence[str]) -> FigureStyle:
    """The :class:`FigureStyle` of ``--dpi`` (checked with the options), ``--size`` and ``--panels``; UsageError for a bad value."""
    return FigureStyle(
        dpi=float(dpi) if dpi is not None else DEFAULT_DPI,
        size_in=parse_size(size) if size is not None else None,
        panels=parse_panels(panels, known_panels) if panels is not None else None,
    )


def paper_rc() -> dict[str, Any]:
    """matplotlib rcParams of the paper style (fonts in points, thin lines, the palette)."""
    from cycler import cycler

    return {
        "font.size": 8.0, "axes.titlesize": 8.5, "axes.labelsize": 8.0, "xtick.labelsize": 7.0, "ytick.labelsize": 7.0,
        "legend.fontsize": 7.5, "figure.titlesize": 9.5,
        "lines.linewidth": 1.0, "axes.linewidth": 0.6, "xtick.major.width": 0.6, "ytick.major.width": 0.6,
        "grid.linewidth": 0.4, "grid.alpha": 0.35, "axes.grid": True,
        "axes.prop_cycle": cycler(color=list(PALETTE)), "axes.titlelocation": "left", "legend.frameon": False,
        # Text stays text in vector output.
        "pdf.fonttype": 42, "ps.fonttype": 42, "svg.fonttype": "none", "mathtext.default": "regular",
    }


#: One colour per control law in every figure, report and sweep alike (``--law``'s order).
LAW_COLORS = dict(zip(ALL_LAWS, PALETTE))


def law_colors(laws: Sequence[str | None]) -> list[str]:
    """A colour per run (or group of runs) of the given laws: its law's :data:`LAW_COLORS`
    the first time the law comes; a law seen before (two runs of one law) or unknown takes
    the next palette colour no law has, then those of the laws absent here (cycling)."""
    taken = {LAW_COLORS[law] for law in laws if law in LAW_COLORS}
    spare = [color for color in PALETTE if color not in LAW_COLORS.values()] + [
        color for color in LAW_COLORS.values() if color not in taken]
    colors: list[str] = []
    for law in laws:  # a law's own colour is never spare, so it is in colors once the law has come
        first = law in LAW_COLORS and LAW_COLORS[law] not in colors
        colors.append(LAW_COLORS[law] if first else spare[sum(color in spare for color in colors) % len(spare)])
    return colors


def new_figure(size_in: tuple[float, float], dpi: float) -> Any:
    """A figure on the Agg canvas (no pyplot: no global state, no display needed)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=size_in, dpi=dpi, layout="constrained")
    FigureCanvasAgg(figure)
    return figure


def check_plot_path(path: Path) -> None:
    """Before any work: UsageError for a suffix matplotlib cannot write, OutputError for a missing folder."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    suffix = path.suffix.lower().lstrip(".")
    formats = set(FigureCanvasAgg.get_supported_filetypes())
    if suffix not in formats:
        others = ", ".join(sorted(formats - {"pdf", "svg", "png"}))
        raise UsageError(f"--plot {path}: unknown figure format {path.suffix!r}; use .pdf or .svg (vector) or .png (or {others})")
    if not path.parent.exists():
        raise OutputError(f"--plot {path}: the folder {path.parent} does not exist")


def save_figure(figure: Any, path: Path, dpi: float) -> None:
    """Write ``figure`` to ``path`` (format from the suffix) under the paper style, atomically."""
    import io

    import matplotlib

    from ..io.output_target import write_output_bytes

    image = io.BytesIO()
    with matplotlib.rc_context(paper_rc()):
        figure.savefig(image, dpi=dpi, format=Path(path).suffix.lower().lstrip(".") or "png")
    write_output_bytes(path, image.getvalue(), "figure")
