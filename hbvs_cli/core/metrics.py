"""Statistics and convergence measures of a run (docs/report.md): step times ``t`` (s, (K,))
and per-step signals (K,) in, ``float`` or ``None`` (no valid sample) out. NaN samples are left
out: a lost target has no measured error. The statistics are evo's (``std`` with ddof = 0).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

#: Share of the run's duration, at its end, over which ``final`` averages |x|.
FINAL_WINDOW_FRACTION = 0.05
#: An increase of V smaller than this times V(0) is integration noise, not an increase.
V_INCREASE_RELATIVE = 1e-9

#: Names of the statistics :func:`error_summary` returns, in order.
STATISTICS = ("rmse", "mean", "median", "std", "min", "max", "initial", "final", "settling_time_s")
#: Names of what :func:`lyapunov_summary` returns, in order.
LYAPUNOV = ("initial", "final", "ratio", "increase_fraction")
#: Names of what :func:`command_smoothness` returns, in order.
SMOOTHNESS = ("v_tv_per_s", "w_tv_per_s", "dv_dt_rms_mps2", "dw_dt_rms_radps2", "at_limit_fraction")


def _optional(value: float | np.floating | None) -> float | None:
    """A JSON-ready number: ``None`` stays ``None``, NaN becomes ``None``."""
    if value is None:
        return None
    value = float(value)
    return value if np.isfinite(value) else None


def _finite(x: ArrayLike) -> NDArray[np.float64]:
    x = np.asarray(x, dtype=float)
    return x[np.isfinite(x)]


def valid_samples(t: ArrayLike, x: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The times (s) and values of the finite samples of ``x``."""
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    keep = np.isfinite(x)
    return t[keep], x[keep]


def signal_statistics(x: ArrayLike) -> dict[str, float | None]:
    """``rmse, mean, median, std, min, max`` of the finite samples (units of ``x``)."""
    x = _finite(x)
    if x.size == 0:
        return dict.fromkeys(STATISTICS[:6])
    values = (np.sqrt(np.mean(np.square(x))), np.mean(x), np.median(x), np.std(x), np.min(x), np.max(x))
    return dict(zip(STATISTICS[:6], map(_optional, values)))


def initial_value(x: ArrayLike) -> float | None:
    """The first finite sample of ``x`` (its units), or ``None``."""
    finite = _finite(x)
    return _optional(finite[0]) if finite.size else None


def final_value(t: ArrayLike, x: ArrayLike, fraction: float = FINAL_WINDOW_FRACTION) -> float | None:
    """Mean of ``|x|`` over the valid samples with ``t >= t[-1] - fraction (t[-1] - t[0])``
    (the whole run's duration, lost steps included); ``None`` if the target was lost there."""
    t = np.asarray(t, dtype=float)
    if t.size == 0:
        return None
    start = t[-1] - fraction * (t[-1] - t[0])
    tv, xv = valid_samples(t, x)
    window = np.abs(xv[tv >= start])
    return _optional(np.mean(window)) if window.size else None


def settling_time(t: ArrayLike, x: ArrayLike, tolerance: float) -> float | None:
    """Time (s, from the run's first step) of the first valid sample after the last one with
    ``|x| > tolerance``; ``None`` if the last valid sample is outside (it never settled)."""
    t = np.asarray(t, dtype=float)
    tv, xv = valid_samples(t, x)
    if xv.size == 0:
        return None
    outside = np.flatnonzero(np.abs(xv) > tolerance)
    settled = outside[-1] + 1 if outside.size else 0
    return _optional(tv[settled] - t[0]) if settled < xv.size else None


def error_summary(t: ArrayLike, x: ArrayLike, tolerance: float) -> dict[str, float | None]:
    """Every statistic of :data:`STATISTICS` for one error signal (settling band ``tolerance``)."""
    return signal_statistics(x) | {"initial": initial_value(x), "final": final_value(t, x),
                                   "settling_time_s": settling_time(t, x, tolerance)}


def lyapunov_summary(V: ArrayLike, relative: float = V_INCREASE_RELATIVE) -> dict[str, float | None]:
    """``initial`` and ``final`` valid V (36), their ``ratio`` and ``increase_fraction``: the
    share of adjacent valid pairs where V rose by more than ``relative * V(0)``."""
    V = np.asarray(V, dtype=float)
    finite = V[np.isfinite(V)]
    if finite.size == 0:
        return dict.fromkeys(LYAPUNOV)
    initial, final = float(finite[0]), float(finite[-1])
    # Pairs that straddle a lost stretch are skipped: across it the law did not run.
    both = np.isfinite(V[:-1]) & np.isfinite(V[1:])
    rises = np.diff(V)[both] > relative * initial
    return {
        "initial": _optional(initial),
        "final": _optional(final),
        "ratio": _optional(final / initial) if initial > 0 else None,
        "increase_fraction": _optional(np.mean(rises)) if rises.size else None,
    }


def step_durations(t: ArrayLike) -> NDArray[np.float64]:
    """How long each step lasts (s): to the next step, the last one as long as the median step."""
    t = np.asarray(t, dtype=float)
    if t.size < 2:
        return np.zeros(t.size)
    return np.diff(t, append=t[-1] + np.median(np.diff(t)))


def longest_true_run_s(t: ArrayLike, flags: ArrayLike) -> float:
    """Duration (s) of the longest stretch of consecutive ``True`` steps (:func:`step_durations`)."""
    return longest_stretch(step_durations(t), flags)


def longest_stretch(durations: ArrayLike, flags: ArrayLike) -> float:
    """The largest sum of ``durations`` (>= 0) over a stretch of consecutive ``True`` ``flags``."""
    flags = np.asarray(flags, dtype=bool)
    # Each stretch of True steps shares its count of False steps before it: one bin per stretch, summed in order.
    stretches = np.bincount(np.cumsum(~flags), weights=np.where(flags, durations, 0.0))
    return float(np.max(stretches, initial=0.0))


def rms(x: ArrayLike) -> float | None:
    """Root mean square of the finite samples (units of ``x``), or ``None``."""
    return signal_statistics(x)["rmse"]


def peak_abs(x: ArrayLike) -> float | None:
    """Largest ``|x|`` over the finite samples (units of ``x``), or ``None``."""
    return _optional(np.max(np.abs(_finite(x)), initial=-np.inf))


def min_abs(x: ArrayLike) -> float | None:
    """Smallest ``|x|`` over the finite samples (units of ``x``), or ``None``."""
    return _optional(np.min(np.abs(_finite(x)), initial=np.inf))


def sample_rate_hz(t: ArrayLike) -> float | None:
    """Step rate (Hz): the inverse of the median step; ``None`` with fewer than two steps."""
    t = np.asarray(t, dtype=float)
    if t.size < 2:
        return None
    step = float(np.median(np.diff(t)))
    return 1.0 / step if step > 0 else None


def round_significant(value: Any, digits: int) -> Any:
    """``value`` with every finite float, in dicts, lists and tuples too, rounded to ``digits`` significant digits."""
    if isinstance(value, dict):
        return {key: round_significant(item, digits) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(round_significant(item, digits) for item in value)
    if isinstance(value, float) and math.isfinite(value) and value != 0.0:
        return round(value, digits - 1 - math.floor(math.log10(abs(value))))
    return value


def command_smoothness(t: ArrayLike, v: ArrayLike, w: ArrayLike, max_v: float | None = None, max_w: float | None = None,
                       max_accel: float | None = None) -> dict[str, float | None]:
    """How smooth a command stream ``v``, ``w`` (m/s, rad/s) is under the actuator limits (None:
    unlimited): the :data:`SMOOTHNESS` values (docs/report.md, ``commands``), None with fewer than two samples."""
    t = np.asarray(t, dtype=float)
    v = np.asarray(v, dtype=float)
    w = np.asarray(w, dtype=float)
    keep = np.isfinite(t) & np.isfinite(v) & np.isfinite(w)
    t, v, w = t[keep], v[keep], w[keep]
    if t.size < 2 or not t[-1] > t[0]:
        return dict.fromkeys(SMOOTHNESS)
    dt = np.diff(t)
    dv, dw = np.diff(v), np.diff(w)
    duration = float(t[-1] - t[0])
    positive = dt > 0
    at_limit = np.zeros(t.size, dtype=bool)
    for signal, bound in ((v, max_v), (w, max_w)):
        if bound is not None:
            at_limit |= np.abs(signal) >= bound * (1.0 - 1e-3)
    if max_accel is not None:
        step = max_accel * np.where(positive, dt, np.inf)
        at_limit[1:] |= (np.abs(dv) >= step * (1.0 - 1e-3)) | (np.abs(dw) >= step * (1.0 - 1e-3))
    return {
        "v_tv_per_s": float(np.sum(np.abs(dv)) / duration),
        "w_tv_per_s": float(np.sum(np.abs(dw)) / duration),
        "dv_dt_rms_mps2": float(np.sqrt(np.mean(np.square(dv[positive] / dt[positive])))) if positive.any() else None,
        "dw_dt_rms_radps2": float(np.sqrt(np.mean(np.square(dw[positive] / dt[positive])))) if positive.any() else None,
        "at_limit_fraction": float(np.mean(at_limit)),
    }


def taught_commands(x_hd2: ArrayLike, x_hd1_dot: ArrayLike, theta_d_dot: ArrayLike, depth: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The commands of the desired trajectory (25): ``w_d = -theta_d_dot``,
    ``v_d = d* (x_hd2 w_d - x_hd1_dot)`` (m/s, rad/s), at depth ``depth`` (m)."""
    w_d = -np.asarray(theta_d_dot, dtype=float)
    return depth * (np.asarray(x_hd2, dtype=float) * w_d - np.asarray(x_hd1_dot, dtype=float)), w_d
