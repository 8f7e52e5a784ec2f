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
