"""Unicycle kinematics of the wheeled mobile robot, integrated exactly.

Velocity v_c along x, turn rate w_c about z (Sec. II, (21)); commands held over dt (as a
driver holds them between updates) move the robot on a circular arc::

    phi'  = phi + w dt
    x'    = x + v dt cos(phi + w dt / 2) sinc(w dt / 2)
    y'    = y + v dt sin(phi + w dt / 2) sinc(w dt / 2)

with ``sinc(a) = sin(a) / a``, which is exact and stays accurate as w -> 0.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray


def advance_unicycle(pose: ArrayLike, v: ArrayLike, w: ArrayLike, dt: ArrayLike) -> NDArray[np.float64]:
    """Poses after holding ``(v, w)`` for ``dt`` seconds, exactly; broadcasts over batches.

    ``pose`` (..., 3) is ``(x, y, phi)``; ``v`` (m/s), ``w`` (rad/s), ``dt`` (s, >= 0) broadcast.
    """
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
    """Poses after each of a sequence of held commands, exactly and vectorised.

    Each step's displacement depends only on its starting heading, a cumulative sum: no loop.
    ``v``, ``w``, ``dt`` have shape (K,) (or scalar dt); returns (K + 1, 3) from ``pose0``.
    """
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
