"""Unicycle kinematics (21), integrated exactly: a command (v, w) held over dt moves the robot
on an arc, ``phi' = phi + w dt``, ``(x', y') = (x, y) + v dt sinc(w dt / 2) (cos, sin)(phi + w dt / 2)``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray


def advance_unicycle(pose: ArrayLike, v: ArrayLike, w: ArrayLike, dt: ArrayLike) -> NDArray[np.float64]:
    """Poses ``(x, y, phi)`` (..., 3) after holding ``v`` (m/s), ``w`` (rad/s) for ``dt`` (s), broadcast."""
    pose = np.asarray(pose, dtype=float)
    turn = np.asarray(w, dtype=float) * dt
    half = 0.5 * turn
    chord = np.asarray(v, dtype=float) * dt * np.sinc(half / np.pi)
    heading = pose[..., 2] + half
    return np.stack(
        [pose[..., 0] + chord * np.cos(heading), pose[..., 1] + chord * np.sin(heading), pose[..., 2] + turn],
        axis=-1,
    )


def integrate_unicycle(pose: ArrayLike, v: float, w: float, dt: float) -> tuple[float, float, float]:
    """:func:`advance_unicycle` for one pose in plain floats (the closed loop calls it every period)."""
    x, y, phi = pose
    half = 0.5 * w * dt
    chord = v * dt * (math.sin(half) / half if abs(half) > 1e-12 else 1.0 - half * half / 6.0)
    heading = phi + half
    return x + chord * math.cos(heading), y + chord * math.sin(heading), phi + w * dt


def integrate_commands(pose0: ArrayLike, v: ArrayLike, w: ArrayLike, dt: ArrayLike) -> NDArray[np.float64]:
    """Poses (K + 1, 3) from ``pose0`` after each of K held commands (``dt`` (K,) or scalar):
    each step depends only on its starting heading, a cumulative sum."""
    pose0 = np.asarray(pose0, dtype=float)
    v = np.asarray(v, dtype=float)
    w = np.asarray(w, dtype=float)
    dt = np.broadcast_to(np.asarray(dt, dtype=float), v.shape)
    phi_start = pose0[2] + np.concatenate([[0.0], np.cumsum(w * dt)[:-1]])
    origins = np.stack([np.zeros_like(phi_start), np.zeros_like(phi_start), phi_start], axis=-1)
    steps = advance_unicycle(origins, v, w, dt)
    poses = np.empty((v.size + 1, 3))
    poses[0] = pose0
    poses[1:, :2] = pose0[:2] + np.cumsum(steps[:, :2], axis=0)
    poses[1:, 2] = steps[:, 2]
    return poses


class DynamicBase:
    """A wheeled base that does not obey a command at once: its speeds follow the command through a
    first-order motor lag of time constant ``lag_s`` (s), within the speed limits ``max_v``, ``max_w``
    (m/s, rad/s) and acceleration limits ``max_accel``, ``max_alpha`` (m/s^2, rad/s^2), and move it
    as :func:`integrate_unicycle`. With every limit ``inf`` and no lag it is the paper's unicycle (21).
    """

    #: The longest step (s) the speeds are integrated over at once.
    STEP_S = 0.002

    def __init__(self, max_v: float = math.inf, max_w: float = math.inf, max_accel: float = math.inf,
                 max_alpha: float = math.inf, lag_s: float = 0.0) -> None:
        self.max_v, self.max_w, self.max_accel, self.max_alpha, self.lag_s = max_v, max_w, max_accel, max_alpha, lag_s
        #: The base's actual speeds (m/s, rad/s).
        self.v = self.w = 0.0

    @property
    def kinematic(self) -> bool:
        return all(math.isinf(x) for x in (self.max_v, self.max_w, self.max_accel, self.max_alpha)) and self.lag_s == 0.0

    def advance(self, pose: tuple[float, float, float], command: tuple[float, float], dt: float) -> tuple[float, float, float]:
        """The pose after ``dt`` (s) under ``command`` (v, w) (m/s, rad/s); :attr:`v` and :attr:`w` follow it."""
        target_v = min(max(command[0], -self.max_v), self.max_v)
        target_w = min(max(command[1], -self.max_w), self.max_w)
        if self.kinematic:
            self.v, self.w = target_v, target_w
            return integrate_unicycle(pose, target_v, target_w, dt)
        steps = max(1, math.ceil(dt / self.STEP_S))
        h = dt / steps
        for _ in range(steps):
            self.v = self._follow(self.v, target_v, self.max_accel, h)
            self.w = self._follow(self.w, target_w, self.max_alpha, h)
            pose = integrate_unicycle(pose, self.v, self.w, h)
        return pose

    def _follow(self, speed: float, target: float, max_rate: float, h: float) -> float:
        # The lag's exact step for the rate, then clipped to the acceleration limit.
        change = (target - speed) * (1.0 - math.exp(-h / self.lag_s)) if self.lag_s > 0 else target - speed
        return speed + min(max(change, -max_rate * h), max_rate * h)
