"""The desired trajectory theta_d(t), x_hd(t) and its derivatives (Remark 1).

Cubic smoothing splines of theta_d (unwrapped) and x_hd1 give bounded feed-forward terms.
x_hd2 is ``x_hd2_dot = x_hd1 theta_d_dot`` (25) integrated exactly plus one fitted constant:
(38) needs that relation, and k_2 amplifies any mismatch. Outside ``[t_start, t_end]``
trajectories hold their end values with zero derivatives.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import InsufficientDataError, InvalidValueError, MalformedDataError
from .controller import DesiredState
from .metrics import longest_stretch

#: Names of the fitted spline channels; x_hd2 follows from them by (25).
CHANNELS = ("theta_d", "x_hd1")


class DesiredTrajectory(Protocol):
    """Anything that gives the desired state at a time."""

    t_start: float
    t_end: float

    def evaluate(self, t: ArrayLike) -> DesiredState:  # pragma: no cover - protocol
        ...


#: Largest spline coefficient a file may hold (theta_d in rad, x_hd1 in units of d*): a real
#: fit stays far below, and a huge one makes every command infinite.
MAX_SPLINE_COEFFICIENT = 1e6


@dataclass(frozen=True)
class SplineChannel:
    """One cubic B-spline channel and the smoothing it was fitted with.

    ``knots`` (K,), ``coefficients`` (K - 4,), ``smoothing``: penalty weight lambda (s^3),
    ``residual_rms``: RMS of spline minus samples.
    """

    knots: NDArray[np.float64]
    coefficients: NDArray[np.float64]
    smoothing: float
    residual_rms: float


class SplineTrajectory:
    """Desired signals as smooth functions of time (Remark 1), consistent with (25).

    ``channels``: :class:`SplineChannel` of ``theta_d`` and ``x_hd1``; ``x_hd2_offset``:
    x_hd2 at ``t_start`` (s), from where (25) carries it; ``x_hd2_residual_rms``: RMS of the
    derived x_hd2 minus its samples.
    """

    def __init__(self, channels: dict[str, SplineChannel], x_hd2_offset: float, t_start: float, t_end: float,
                 x_hd2_residual_rms: float = float("nan")) -> None:
        if not (np.isfinite(t_start) and np.isfinite(t_end) and t_end > t_start):
            raise MalformedDataError("the trajectory model's time span is empty or not finite")
        if not np.isfinite(x_hd2_offset):
            raise MalformedDataError("the trajectory model's x_hd2 offset is not finite")
        self.channels = channels
        self.t_start = float(t_start)
        self.t_end = float(t_end)
        self.x_hd2_offset = float(x_hd2_offset)
        self.x_hd2_residual_rms = float(x_hd2_residual_rms)
        from scipy.interpolate import BSpline

        self._splines = {name: BSpline(channels[name].knots, channels[name].coefficients, 3, extrapolate=False)
                         for name in CHANNELS}
        self._derivatives = {name: spline.derivative() for name, spline in self._splines.items()}
        self._x_hd2_integral = _product_antiderivative(self._splines["x_hd1"], self._splines["theta_d"])
        self._x_hd2_origin = float(self._x_hd2_integral(self.t_start))

    def evaluate(self, t: ArrayLike) -> DesiredState:
        """Desired state at times ``t`` (s); held, with zero derivatives, outside the span."""
        t = np.asarray(t, dtype=float)
        inside = (t >= self.t_start) & (t <= self.t_end)
        clamped = np.clip(t, self.t_start, self.t_end)
        theta_d = self._splines["theta_d"](clamped)
        x_hd1 = self._splines["x_hd1"](clamped)
        theta_d_dot = np.where(inside, self._derivatives["theta_d"](clamped), 0.0)
        x_hd1_dot = np.where(inside, self._derivatives["x_hd1"](clamped), 0.0)
        x_hd2 = self.x_hd2_offset + self._x_hd2_integral(clamped) - self._x_hd2_origin
        return _desired_state(theta_d, x_hd1, x_hd2, theta_d_dot, x_hd1_dot, x_hd1 * theta_d_dot)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description: knots and coefficients of every channel."""
        channels = {name: {"knots": ch.knots.tolist(), "coefficients": ch.coefficients.tolist(), "smoothing": ch.smoothing,
                           "residual_rms": ch.residual_rms} for name, ch in self.channels.items()}
        x_hd2 = {"derived_from": "(25): x_hd2_dot = x_hd1 theta_d_dot", "value_at_t_start": self.x_hd2_offset,
                 "residual_rms": self.x_hd2_residual_rms}
        return {"t_start": self.t_start, "t_end": self.t_end, "degree": 3, "channels": channels, "x_hd2": x_hd2}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "SplineTrajectory":
        """Inverse of :meth:`to_dict`; raises :class:`MalformedDataError` when malformed."""
        try:
            if int(data.get("degree", 3)) != 3:
                raise ValueError("only cubic splines are supported")
            channels = {}
            for name in CHANNELS:
                raw = data["channels"][name]
                knots = np.asarray(raw["knots"], dtype=float)
                coefficients = np.asarray(raw["coefficients"], dtype=float)
                if knots.ndim != 1 or coefficients.ndim != 1 or knots.size != coefficients.size + 4 or knots.size < 8:
                    raise ValueError(f"channel {name}: {knots.size} knots do not fit {coefficients.size} coefficients")
                if not (np.all(np.isfinite(knots)) and np.all(np.isfinite(coefficients))) or np.any(np.diff(knots) < 0):
                    raise ValueError(f"channel {name}: knots must be finite and non-decreasing")
                if np.any(np.abs(coefficients) > MAX_SPLINE_COEFFICIENT):
                    raise ValueError(f"channel {name}: coefficients beyond +-{MAX_SPLINE_COEFFICIENT:g} (radians, or units of d*)")
                channels[name] = SplineChannel(knots, coefficients, float(raw.get("smoothing", float("nan"))),
                                               float(raw.get("residual_rms", float("nan"))))
            first, second = (channels[name].knots for name in CHANNELS)
            if first.shape != second.shape or not np.allclose(first, second):
                raise ValueError("theta_d and x_hd1 must share their knots")
            x_hd2 = data["x_hd2"]
            return cls(channels, float(x_hd2["value_at_t_start"]), float(data["t_start"]), float(data["t_end"]),
                       float(x_hd2.get("residual_rms", float("nan"))))
        except (KeyError, TypeError, ValueError) as exc:
            raise MalformedDataError(f"malformed trajectory model: {exc}") from None


def _product_antiderivative(spline: Any, other: Any) -> Any:
    """Exact antiderivative (PPoly) of ``spline * other'`` on shared knots (both callers of
    :class:`SplineTrajectory` make them so): x_hd2 of (25)."""
    from scipy.interpolate import PPoly

    first = PPoly.from_spline(spline)
    second = PPoly.from_spline(other).derivative()
    product = np.zeros((first.c.shape[0] + second.c.shape[0] - 1, first.c.shape[1]))
    for i in range(first.c.shape[0]):  # the coefficients' convolution, interval by interval
        product[i:i + second.c.shape[0]] += first.c[i] * second.c
    return PPoly(product, first.x).antiderivative()


class TimeScaledTrajectory:
    """``base`` played from its start at ``speed`` times its taught pace (derivatives times ``speed``)."""

    def __init__(self, base: DesiredTrajectory, speed: float = 1.0) -> None:
        if not np.isfinite(speed) or speed <= 0.0:
            raise InvalidValueError(f"--speed must be a positive number, got {speed}")
        self.base = base
        self.speed = float(speed)
        self.start = float(base.t_start)
        self.t_start = 0.0
        self.t_end = (base.t_end - self.start) / self.speed

    def evaluate(self, t: ArrayLike) -> DesiredState:
        state = self.base.evaluate(self.start + self.speed * np.asarray(t, dtype=float))
        return replace(state, theta_d_dot=np.multiply(state.theta_d_dot, self.speed),
                       x_hd1_dot=np.multiply(state.x_hd1_dot, self.speed), x_hd2_dot=np.multiply(state.x_hd2_dot, self.speed))


def _desired_state(*values: ArrayLike) -> DesiredState:
    """A DesiredState of (theta_d, x_hd1, x_hd2, theta_d_dot, x_hd1_dot, x_hd2_dot), a float for a scalar time."""
    arrays = [np.asarray(value, dtype=float) for value in values]
    return DesiredState(*(float(array) if array.ndim == 0 else array for array in arrays))


#: Fewest samples a spline can be fitted to (scipy's smoothing spline needs 5).
MIN_SAMPLES = 5


def fit_spline_trajectory(t: ArrayLike, theta_d: ArrayLike, x_hd1: ArrayLike, x_hd2: ArrayLike,
                          smoothing: float | None = None) -> SplineTrajectory:
    """Fit the desired trajectory of Remark 1 to decomposed samples at times ``t`` (K,) (s,
    strictly increasing; gaps are bridged): ``theta_d`` (K,) rad (unwrapped here), ``x_hd1`` and
    ``x_hd2`` (K,), which only sets the constant of (25). ``smoothing``: both splines' lambda
    (s^3), as ``fit --smoothing`` checked it; None: per channel by generalised cross-validation (:mod:`.gcv`).
    """
    from scipy.interpolate import make_smoothing_spline

    from .gcv import gcv_smoothing

    t = np.asarray(t, dtype=float)
    samples = {"theta_d": np.unwrap(np.asarray(theta_d, dtype=float)), "x_hd1": np.asarray(x_hd1, dtype=float)}
    x_hd2 = np.asarray(x_hd2, dtype=float)
    if t.ndim != 1 or t.size < MIN_SAMPLES:
        raise InsufficientDataError(f"need at least {MIN_SAMPLES} frames to fit the desired trajectory, got {t.size}")
    if np.any(np.diff(t) <= 0.0):
        raise MalformedDataError("frame times must increase strictly")
    channels = {}
    for name, y in samples.items():
        if y.shape != t.shape or not np.all(np.isfinite(y)):
            raise MalformedDataError(f"the {name} samples must be finite and as many as the times")
        lam = float(smoothing) if smoothing is not None else gcv_smoothing(t, y)
        spline = make_smoothing_spline(t, y, lam=lam)
        residual = float(np.sqrt(np.mean((spline(t) - y) ** 2)))
        channels[name] = SplineChannel(np.asarray(spline.t, dtype=float), np.asarray(spline.c, dtype=float), lam, residual)
    if x_hd2.shape != t.shape or not np.all(np.isfinite(x_hd2)):
        raise MalformedDataError("the x_hd2 samples must be finite and as many as the times")
    # x_hd2 by (25) from the two splines; its one free constant by least squares.
    shape_only = SplineTrajectory(channels, 0.0, float(t[0]), float(t[-1]))
    integrated = np.atleast_1d(shape_only.evaluate(t).x_hd2)
    offset = float(np.mean(x_hd2 - integrated))
    residual = float(np.sqrt(np.mean((x_hd2 - integrated - offset) ** 2)))
    return SplineTrajectory(channels, offset, float(t[0]), float(t[-1]), residual)


@dataclass(frozen=True)
class FeedforwardCondition:
    """Condition (35), x_hd1_dot away from zero, on a taught path: the minimum and percentiles
    (p5 ... p95) of |x_hd1_dot| (1/s), and the fraction and longest stretch (s) of the path
    where it is below ``threshold`` (1/s): stopped."""

    min_abs_xhd1_dot: float
    percentiles: dict[str, float]
    stopped_fraction: float
    longest_stop_s: float
    threshold: float

    @property
    def path_stops(self) -> bool:
        """True when the path stops somewhere: e2 cannot converge there."""
        return self.stopped_fraction > 0.0


#: Below this |x_hd1_dot| (1/s) the path counts as stopped: 1 cm/s at d* = 5 m.
STOP_THRESHOLD = 0.002


def feedforward_condition(trajectory: DesiredTrajectory, t: ArrayLike, threshold: float = STOP_THRESHOLD) -> FeedforwardCondition:
    """Measure condition (35)/(44) of a trajectory on the sample times ``t``."""
    t = np.asarray(t, dtype=float)
    rate = np.abs(np.atleast_1d(trajectory.evaluate(t).x_hd1_dot))
    stopped = rate < threshold
    longest = longest_stretch(np.diff(t, append=t[-1] + (t[-1] - t[-2] if t.size > 1 else 0.0)), stopped)
    percentiles = {f"p{q}": float(np.percentile(rate, q)) for q in (5, 25, 50, 75, 95)}
    return FeedforwardCondition(float(rate.min()), percentiles, float(np.mean(stopped)), float(longest), threshold)
