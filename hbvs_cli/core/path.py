"""Teach-pendant command profiles: each (v, w) is held until the next, so every segment is an
arc and the taught pose is exact. The :data:`PRESETS` keep the default target in view and
x_hd1_dot away from zero, condition (35)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import InvalidValueError, MalformedDataError
from .unicycle import advance_unicycle, integrate_commands


@dataclass(frozen=True)
class CommandProfile:
    """Piecewise-constant commands ``v`` (m/s), ``w`` (rad/s), shape (K,), starting at ``t``
    (s, strictly increasing from 0) until ``t_end`` (s)."""

    t: NDArray[np.float64]
    v: NDArray[np.float64]
    w: NDArray[np.float64]
    t_end: float

    def __post_init__(self) -> None:
        t, v, w = (np.asarray(a, dtype=float) for a in (self.t, self.v, self.w))
        if t.ndim != 1 or t.size == 0 or v.shape != t.shape or w.shape != t.shape:
            raise MalformedDataError("a command profile needs equally long, non-empty t, v and w columns")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(v)) and np.all(np.isfinite(w))):
            raise MalformedDataError("the command profile contains NaN or infinity")
        if np.any(np.diff(t) <= 0.0):
            bad = int(np.flatnonzero(np.diff(t) <= 0.0)[0]) + 1
            raise MalformedDataError(f"command times must increase strictly (row {bad + 1}: t={t[bad]:g} s)")
        if not np.isfinite(self.t_end) or self.t_end <= t[-1]:
            raise MalformedDataError("the command profile must end after its last command starts")
        for name, value in (("t", t - t[0]), ("v", v), ("w", w), ("t_end", float(self.t_end - t[0]))):
            object.__setattr__(self, name, value)

    @property
    def duration(self) -> float:
        """Length of the profile (s)."""
        return self.t_end

    def segment_index(self, t: ArrayLike) -> NDArray[np.intp]:
        """Index of the command in force at each time (clamped to the profile)."""
        return np.clip(np.searchsorted(self.t, np.asarray(t, dtype=float), side="right") - 1, 0, self.t.size - 1)

    def commands_at(self, t: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(v, w) in force at times ``t``; zero after ``t_end``."""
        t = np.asarray(t, dtype=float)
        index = self.segment_index(t)
        running = (t >= 0.0) & (t < self.t_end)
        return np.where(running, self.v[index], 0.0), np.where(running, self.w[index], 0.0)

    def segment_start_poses(self, start_pose: ArrayLike) -> NDArray[np.float64]:
        """Exact pose at the start of every segment, shape (K + 1, 3) (the last at t_end)."""
        dt = np.diff(np.append(self.t, self.t_end))
        return integrate_commands(start_pose, self.v, self.w, dt)

    def poses_at(self, t: ArrayLike, start_pose: ArrayLike, segment_starts: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
        """Exact poses (..., 3) at times ``t`` (s), held after ``t_end``; ``segment_starts``
        (:meth:`segment_start_poses`) saves re-integrating when asked one at a time."""
        t = np.clip(np.asarray(t, dtype=float), 0.0, self.t_end)
        starts = self.segment_start_poses(start_pose) if segment_starts is None else segment_starts
        index = self.segment_index(t)
        return advance_unicycle(starts[index], self.v[index], self.w[index], t - self.t[index])


def sampled_profile(function: Callable[[NDArray[np.float64]], tuple[ArrayLike, ArrayLike]], duration: float, rate: float) -> CommandProfile:
    """``function(t) -> (v, w)`` sampled at ``rate`` Hz for ``duration`` s, as a pendant does."""
    if duration <= 0 or rate <= 0:
        raise InvalidValueError("the duration and the rate of a command profile must be positive")
    steps = max(1, int(round(duration * rate)))
    t = np.arange(steps) / rate
    v, w = function(t)
    v, w = (np.broadcast_to(np.asarray(values, dtype=float), t.shape).copy() for values in (v, w))
    return CommandProfile(t=t, v=v, w=w, t_end=steps / rate)


@dataclass(frozen=True)
class PathPreset:
    """A built-in taught path: commands, a start pose and a one-line description."""

    name: str
    description: str
    commands: Callable[[NDArray[np.float64]], tuple[ArrayLike, ArrayLike]]
    duration: float
    start_pose: tuple[float, float, float]


PRESETS: dict[str, PathPreset] = {
    preset.name: preset
    for preset in (
        PathPreset("straight", "straight approach toward the target at 0.1 m/s for 20 s (4 m -> 2 m from it)",
                   lambda t: (np.full_like(t, 0.1), np.zeros_like(t)), 20.0, (0.0, 0.0, 0.0)),
        PathPreset("s-curve", "S-curve toward the target: 0.1 m/s, w = 0.045 cos(2 pi t / 20 s) rad/s (heading +-8 deg), 20 s",
                   lambda t: (np.full_like(t, 0.1), 0.045 * np.cos(2.0 * np.pi * t / 20.0)), 20.0,
                   (0.0, -0.05, 0.0)),
        PathPreset("arc", "arc toward the target: 0.1 m/s, w = -0.012 rad/s, 20 s, starting 0.35 m left, heading 8 deg left",
                   lambda t: (np.full_like(t, 0.1), np.full_like(t, -0.012)), 20.0, (0.0, 0.35, np.radians(8.0))),
    )
}


def preset_profile(name: str, rate: float, duration: float | None = None) -> tuple[CommandProfile, tuple[float, float, float]]:
    """The command profile (``rate`` Hz, ``duration`` s or the preset's) and start pose of a
    built-in path; InvalidValueError for an unknown name."""
    try:
        preset = PRESETS[name]
    except KeyError:
        raise InvalidValueError(f"unknown path preset {name!r}: choose one of {', '.join(PRESETS)} or give a CSV file") from None
    profile = sampled_profile(preset.commands, duration if duration is not None else preset.duration, rate)
    return profile, preset.start_pose
