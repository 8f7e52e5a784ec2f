"""Initial depth estimates dhat(0) for (31) (docs/method.md, "Depth d*"): d* is unobservable
from images alone, and a poor dhat(0) slows convergence."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..errors import GeometryError, InvalidValueError


#: The adaptive estimate dhat is projected onto [dhat(0) / F, inf): d* is taken to be more than 1/F of
#: its initial estimate. Projection keeps (36) non-increasing whenever d* lies in the set (the
#: parameter error only shrinks at its edge), and keeps dhat positive as (29) needs, where (31)
#: alone can drive it through zero when the robot does not follow the commands (an open-loop replay,
#: a stalled base). No upper bound: a poor dhat(0) can make (31) overshoot d* several times over.
DEPTH_PROJECTION_FACTOR = 10.0


def project_depth(dhat: float, dhat0: float) -> float:
    """``dhat`` (m) projected onto ``[dhat0 / F, inf)``, F = :data:`DEPTH_PROJECTION_FACTOR`."""
    return max(dhat, dhat0 / DEPTH_PROJECTION_FACTOR)


def check_depth(value: float, name: str) -> float:
    """``value`` as a depth d* or dhat (m): finite and positive, else InvalidValueError."""
    if not (math.isfinite(value) and value > 0.0):
        raise InvalidValueError(f"{name} must be a positive depth in metres, got {value}")
    return float(value)


@dataclass(frozen=True)
class DepthEstimate:
    """An estimate ``dhat0`` of d* (m), its 1-sigma ``standard_error`` (m, NaN when not
    applicable), its ``source`` and the number of equations used (``samples``)."""

    dhat0: float
    standard_error: float
    source: str
    samples: int


def depth_from_taught_commands(v_cd: ArrayLike, w_cd: ArrayLike, x_hd2: ArrayLike, x_hd1_dot: ArrayLike) -> DepthEstimate:
    """Least-squares d* from (25): ``v_cd = d* (x_hd2 w_cd - x_hd1_dot)``, for the taught
    commands (m/s, rad/s) and the fitted x_hd2 (-), x_hd1_dot (1/s), all shape (K,);
    GeometryError when the taught path does not move."""
    v = np.asarray(v_cd, dtype=float)
    regressor = np.asarray(x_hd2, dtype=float) * np.asarray(w_cd, dtype=float) - np.asarray(x_hd1_dot, dtype=float)
    keep = np.isfinite(v) & np.isfinite(regressor)
    v, regressor = v[keep], regressor[keep]
    energy = float(regressor @ regressor)
    if v.size < 2 or energy <= 1e-12 * max(v.size, 1):
        raise GeometryError("the taught commands do not move the robot: d* cannot be estimated from them")
    d_star = float(regressor @ v) / energy
    residual = v - d_star * regressor
    sigma2 = float(residual @ residual) / max(v.size - 1, 1)
    if d_star <= 0.0:
        raise GeometryError(
            f"the taught commands give a negative depth ({d_star:.3g} m): do the recorded commands belong to these images?"
        )
    return DepthEstimate(dhat0=d_star, standard_error=float(np.sqrt(sigma2 / energy)), source="commands", samples=int(v.size))


def depth_from_target_size(m_ref: ArrayLike, normal: ArrayLike, pair: tuple[int, int], distance_m: float) -> DepthEstimate:
    """d* from the known distance (m) between the target points ``pair`` of m*_i ``m_ref``
    (N, 3): they lie on ``n*^T m_bar*_i = d*`` (7), so distances scale with d*."""
    m_ref = np.asarray(m_ref, dtype=float)
    if not np.isfinite(distance_m) or distance_m <= 0.0:
        raise GeometryError(f"the target size must be a positive length in metres, got {distance_m}")
    g = m_ref @ np.asarray(normal, dtype=float)
    if np.any(g <= 0.0):
        raise GeometryError("the plane normal puts a target point behind the reference camera")
    unit_depth_points = m_ref / g[:, None]  # m_bar*_i / d*
    i, j = pair
    separation = float(np.linalg.norm(unit_depth_points[i] - unit_depth_points[j]))
    if separation <= 1e-12:
        raise GeometryError("the two points that define the target size coincide in the reference image")
    return DepthEstimate(dhat0=distance_m / separation, standard_error=float("nan"), source="target-size", samples=1)


def farthest_pair(m_ref: ArrayLike, normal: ArrayLike) -> tuple[int, int]:
    """The two target points farthest apart on the plane (the pair the target size names)."""
    m_ref = np.asarray(m_ref, dtype=float)
    points = m_ref / (m_ref @ np.asarray(normal, dtype=float))[:, None]
    distance = np.linalg.norm(points[:, None, :] - points[None, :, :], axis=-1)
    i, j = np.unravel_index(int(np.argmax(distance)), distance.shape)
    return int(i), int(j)
