"""Gains of (29)-(31) from the taught path's x_hd1_dot and the detector's noise
(docs/method.md, "Choosing the gains").

Near the path (ebar2, e3) behaves like ``s^2 + k_w s + k_2 x_hd1_dot^2``, so
``k_2 = k_w^2 / (4 x_hd1_dot^2)`` (critically damped), and the depth error decays at
``gamma x_hd1_dot^2 / k_v``, so ``gamma = DEPTH_RATE k_v / x_hd1_dot^2 / (1 + (sigma_e1 /
SIGMA_E1_REFERENCE)^2)``: (31) integrates e1's noise, sigma_e1 the per-frame std of x_h1 at F*.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .controller import ControllerGains
from .state_filter import measurement_information, residual_to_variance

#: Per-coordinate pixel noise the gains are designed for at least (px): the taught images'
#: residual is a lower bound of a live camera's.
DESIGN_NOISE_FLOOR_PX = 0.5
#: Per-frame std of x_h1 at which gamma is halved.
SIGMA_E1_REFERENCE = 0.002
#: Depth learning rate without noise, gamma x_hd1_dot^2 / k_v (1/s).
DEPTH_RATE = 0.4
#: The range of dhat(0) / d* the suggested gains are good for with the state filter.
DHAT0_RANGE = (0.25, 4.0)
#: The half-width of the taught trajectory's 95 % interval, in its sigmas.
INTERVAL_SIGMAS = 1.96


def dhat0_range_text() -> str:
    """The range :data:`DHAT0_RANGE` in words, as ``fit`` prints it next to the gains."""
    low, high = DHAT0_RANGE
    return f"dhat(0) from d*/{1.0 / low:g} to {high:g} d*"


@dataclass(frozen=True)
class GainSuggestion:
    """Gains suggested for a fit and what they came from: the taught path's median
    |``x_hd1_dot``| (1/s), the detector's noise ``noise_px`` and the ``design_noise_px`` (px),
    ``sigma_e1`` under it (-) and the :func:`heading_tolerance` (deg)."""

    gains: ControllerGains
    x_hd1_dot: float
    noise_px: float
    design_noise_px: float
    sigma_e1: float
    heading_tolerance_deg: float = float("nan")


def heading_tolerance(default_deg: float, theta_d_sigma_deg: float) -> float:
    """The final heading error (deg) a repeat can be held to: an error of the fitted n* biases
    the whole taught path, so at least theta_d's 95 % half-interval; NaN when it is unknown."""
    if not math.isfinite(theta_d_sigma_deg):
        return float("nan")
    return max(float(default_deg), INTERVAL_SIGMAS * float(theta_d_sigma_deg))


def noise_from_residual(residual_rms: float, points: int) -> float:
    """Per-coordinate noise (any unit) from the RMS residual of the known-normal solve
    (:func:`~.state_filter.residual_to_variance`)."""
    return residual_rms * math.sqrt(residual_to_variance(points))


def suggest_gains(x_hd1_dot: float, noise_px: float, m_ref: ArrayLike, normal: ArrayLike, focal_px: float) -> GainSuggestion:
    """The rules of the module docstring for a typical |x_hd1_dot| (1/s), the noise (px, NaN
    if unknown), m*_i ``m_ref`` (N, 3), n* ``normal`` (3,) and the focal length (px)."""
    speed = abs(float(x_hd1_dot))
    if not (math.isfinite(speed) and speed > 1e-6):
        # A path that does not move: no lateral convergence to design for (condition (35)).
        return GainSuggestion(ControllerGains(), float(x_hd1_dot), float(noise_px), float("nan"), float("nan"))
    design = max(noise_px, DESIGN_NOISE_FLOOR_PX) if math.isfinite(noise_px) else DESIGN_NOISE_FLOOR_PX
    information = measurement_information(np.asarray(m_ref, dtype=float), np.asarray(normal, dtype=float), (0.0, 0.0, 0.0))
    sigma_e1 = design / focal_px * math.sqrt(float(np.linalg.inv(information)[1, 1]))
    k_w, k_v = ControllerGains().k_w, ControllerGains().k_v
    k_2 = max(1.0, k_w * k_w / (4.0 * speed * speed))
    gamma = DEPTH_RATE * k_v / (speed * speed) / (1.0 + (sigma_e1 / SIGMA_E1_REFERENCE) ** 2)
    return GainSuggestion(ControllerGains(k_v=k_v, k_w=k_w, gamma=gamma, k_2=k_2), speed, float(noise_px), design, sigma_e1)
