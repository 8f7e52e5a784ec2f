"""Gains of (29)-(31) from the data: the taught path's x_hd1_dot and the detector's noise.

Near the desired path the lateral pair (ebar2, e3) behaves like
``s^2 + k_w s + k_2 x_hd1_dot^2`` and the depth error decays at ``gamma x_hd1_dot^2 / k_v``
(docs/method.md, "Choosing the gains"). The rules:

* ``k_w = 1`` 1/s and ``k_v = 4`` m/s (time constants of 1 s for e3 and d*/k_v for e1);
* ``k_2 = k_w^2 / (4 x_hd1_dot^2)``: the lateral mode is critically damped, at ``k_w / 2``;
* ``gamma = 0.4 k_v / x_hd1_dot^2 / (1 + (sigma_e1 / SIGMA_E1_REFERENCE)^2)``: without noise
  the depth is learnt at 0.4 1/s; the adaptation (31) integrates the noise of e1, so the
  variance it adds to dhat grows as ``gamma sigma_e1^2``, and gamma falls as ``1/sigma_e1^2``
  once the per-frame noise of x_h1 passes the reference.

sigma_e1 is the per-frame standard deviation of x_h1 that the detector's noise gives at F*
(``sigma^2 (J^T J)^-1`` of :func:`~.state_filter.measurement_information`), so the rule
sees the target's size and distance as well as the pixels.

The fit's own uncertainty enters as a tolerance, not as a gain: an error of n* is a bias
common to the whole taught trajectory, which no gain removes (the robot tracks the biased
trajectory as well as the true one). A repeat can therefore be held to its taught heading
only within the taught theta_d's 95 % interval; the suggestion carries that as
``heading_tolerance_deg``, ``max(default, INTERVAL_SIGMAS x the largest sigma of theta_d)``,
for ``hbvs report --tolerance heading_deg=...``. The noise is never taken below
:data:`DESIGN_NOISE_FLOOR_PX`: the taught images' residual is a lower bound of the live
camera's (rendered or still images give a few hundredths of a pixel; a real detector on a
moving robot 0.2-0.5 px).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .controller import ControllerGains
from .state_filter import measurement_information

#: Per-coordinate pixel noise the gains are designed for at least (px).
DESIGN_NOISE_FLOOR_PX = 0.5
#: Per-frame std of x_h1 at which gamma is halved: 0.39 px in the default scene (the 2 m
#: dot poster 4 m ahead, f = 500 px). With the state filter at 0.5 px, gamma 2330 lost one
#: run of ten (1.7 m off); 971 converged all ten: the campaign is in docs/method.md.
SIGMA_E1_REFERENCE = 0.002
#: Depth learning rate without noise, gamma x_hd1_dot^2 / k_v (1/s).
DEPTH_RATE = 0.4
DEFAULT_K_V = 4.0
DEFAULT_K_W = 1.0
#: The range of dhat(0) / d* the suggested gains are good for, with the state filter that
#: measures the depth from the motion (docs/method.md, "The depth in the filter"): the
#: campaign of tests/test_control_depth.py converges from every start in it at 0.5 px.
DHAT0_RANGE = (0.25, 4.0)
#: The half-width of the taught trajectory's 95 % interval, in its sigmas.
INTERVAL_SIGMAS = 1.96


def dhat0_range_text() -> str:
    """The range :data:`DHAT0_RANGE` in words, as ``fit`` prints it next to the gains."""
    low, high = DHAT0_RANGE
    return f"dhat(0) from d*/{1.0 / low:g} to {high:g} d*"


@dataclass(frozen=True)
class GainSuggestion:
    """Gains suggested for a fit, and the numbers they came from.

    Attributes
    ----------
    gains : ControllerGains
    x_hd1_dot : float
        The median |x_hd1_dot| of the taught path (1/s).
    noise_px : float
        The detector's per-coordinate noise measured on the taught images (px).
    design_noise_px : float
        The noise the gains are designed for: ``max(noise_px, DESIGN_NOISE_FLOOR_PX)``.
    sigma_e1 : float
        Per-frame std of x_h1 at F* under the design noise (dimensionless).
    heading_tolerance_deg : float
        The final heading error a repeat can be held to (deg): the default tolerance, or
        the taught theta_d's 95 % half-interval where that is larger; NaN when the fit
        has no uncertainty.
    """

    gains: ControllerGains
    x_hd1_dot: float
    noise_px: float
    design_noise_px: float
    sigma_e1: float
    heading_tolerance_deg: float = float("nan")

    def as_dict(self) -> dict[str, float]:
        extra = {"heading_tolerance_deg": self.heading_tolerance_deg} if math.isfinite(self.heading_tolerance_deg) else {}
        return self.gains.as_dict() | {
            "x_hd1_dot": self.x_hd1_dot, "noise_px": self.noise_px,
            "design_noise_px": self.design_noise_px, "sigma_e1": self.sigma_e1,
        } | extra


def heading_tolerance(default_deg: float, theta_d_sigma_deg: float) -> float:
    """The heading tolerance (deg) of the module docstring: ``max(default_deg,
    INTERVAL_SIGMAS * theta_d_sigma_deg)``; NaN when the sigma is unknown."""
    if not math.isfinite(theta_d_sigma_deg):
        return float("nan")
    return max(float(default_deg), INTERVAL_SIGMAS * float(theta_d_sigma_deg))


def noise_from_residual(residual_rms: float, points: int) -> float:
    """Per-coordinate noise from the RMS residual of the known-normal solve over 2N
    coordinates with 3 unknowns: ``E[r^2] = sigma^2 (2N - 3) / (2N)`` (any unit)."""
    return residual_rms * math.sqrt(2.0 * points / max(2.0 * points - 3.0, 1.0))


def suggest_gains(x_hd1_dot: float, noise_px: float, m_ref: ArrayLike, normal: ArrayLike, focal_px: float,
                  heading_tolerance_deg: float = float("nan")) -> GainSuggestion:
    """The rules of the module docstring.

    Parameters
    ----------
    x_hd1_dot : float
        Typical |x_hd1_dot| of the taught path (1/s), e.g. its median; > 0.
    noise_px : float
        Per-coordinate detector noise on the taught images (px); NaN if unknown.
    m_ref : array_like, shape (N, 3)
        Reference normalised points.
    normal : array_like, shape (3,)
        Plane normal n*.
    focal_px : float
        Focal length (px).
    heading_tolerance_deg : float, optional
        :func:`heading_tolerance` of the fit, carried in the suggestion.
    """
    speed = abs(float(x_hd1_dot))
    if not (math.isfinite(speed) and speed > 1e-6):
        # A path that does not move: no lateral convergence to design for (condition (35)).
        return GainSuggestion(ControllerGains(), float(x_hd1_dot), float(noise_px), float("nan"), float("nan"), heading_tolerance_deg)
    design = max(noise_px, DESIGN_NOISE_FLOOR_PX) if math.isfinite(noise_px) else DESIGN_NOISE_FLOOR_PX
    information = measurement_information(np.asarray(m_ref, dtype=float), np.asarray(normal, dtype=float), (0.0, 0.0, 0.0))
    sigma_e1 = design / focal_px * math.sqrt(float(np.linalg.inv(information)[1, 1]))
    k_w, k_v = DEFAULT_K_W, DEFAULT_K_V
    k_2 = max(1.0, k_w * k_w / (4.0 * speed * speed))
    gamma = DEPTH_RATE * k_v / (speed * speed) / (1.0 + (sigma_e1 / SIGMA_E1_REFERENCE) ** 2)
    return GainSuggestion(ControllerGains(k_v=k_v, k_w=k_w, gamma=gamma, k_2=k_2), speed, float(noise_px), design, sigma_e1,
                          heading_tolerance_deg)
