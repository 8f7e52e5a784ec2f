"""Frames, rotations and planar poses in the paper's conventions (docs/method.md, "Frames").

Robot/camera frame F: x forward (optical axis), y left, z up; a planar pose is ``(x, y, phi)``
(m, m, rad) in a world frame W with z up, F* is at ``(x*, y*, phi*)``, and (3)-(5) give
``R = Rz(theta)``, ``theta = phi* - phi``, ``x_f = Rz(phi)^T (p* - p)``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

#: Paper axes (x fwd, y left, z up) -> OpenCV camera axes (x right, y down, z fwd).
PAPER_TO_OPENCV: NDArray[np.float64] = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
PAPER_TO_OPENCV.setflags(write=False)


def rotation_z(theta: ArrayLike) -> NDArray[np.float64]:
    """Right-handed rotation (..., 3, 3) about z by ``theta`` (rad), the paper's R of (4)."""
    theta = np.asarray(theta, dtype=float)
    c, s = np.cos(theta), np.sin(theta)
    zero, one = np.zeros_like(c), np.ones_like(c)
    return np.stack([c, -s, zero, s, c, zero, zero, zero, one], axis=-1).reshape(theta.shape + (3, 3))


def wrap_angle(angle: ArrayLike) -> NDArray[np.float64] | float:
    """Wrap angles (rad) to [-pi, pi)."""
    if isinstance(angle, float):  # the closed loop's scalar case, without numpy's overhead
        return (angle + math.pi) % (2.0 * math.pi) - math.pi
    wrapped = (np.asarray(angle, dtype=float) + np.pi) % (2.0 * np.pi) - np.pi
    return float(wrapped) if wrapped.ndim == 0 else wrapped


def world_to_robot(points_world: ArrayLike, pose: ArrayLike, camera_height: float) -> NDArray[np.float64]:
    """World points (N, 3) in F: ``Rz(phi)^T (P - p)``, ``p = (x, y, camera_height)`` (m)."""
    points_world = np.asarray(points_world, dtype=float)
    x, y, phi = (float(v) for v in np.asarray(pose, dtype=float))
    c, s = np.cos(phi), np.sin(phi)
    d = points_world - np.array([x, y, camera_height])
    return np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2]], axis=-1)


def compose_planar_pose(base: ArrayLike, offset: ArrayLike) -> NDArray[np.float64]:
    """World pose of ``offset``, given in the frame of ``base`` (both ``(x, y, phi)``)."""
    bx, by, bphi = (float(v) for v in np.asarray(base, dtype=float))
    ox, oy, ophi = (float(v) for v in np.asarray(offset, dtype=float))
    c, s = np.cos(bphi), np.sin(bphi)
    return np.array([bx + c * ox - s * oy, by + s * ox + c * oy, bphi + ophi])


def yaw_to_quaternion(phi: ArrayLike) -> NDArray[np.float64]:
    """Quaternion ``(x, y, z, w)`` (..., 4) of a rotation by ``phi`` (rad) about z."""
    half = 0.5 * np.asarray(phi, dtype=float)
    zeros = np.zeros_like(half)
    return np.stack([zeros, zeros, np.sin(half), np.cos(half)], axis=-1)


def quaternion_to_yaw(q: ArrayLike) -> NDArray[np.float64] | float:
    """Yaw (rad) of a quaternion ``(x, y, z, w)``, the rotation about z."""
    q = np.asarray(q, dtype=float)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return float(yaw) if np.ndim(yaw) == 0 else yaw
