"""The adaptive tracking controller of Chen et al., (19)-(31) and (36), with the lateral gain
k_2 (k_2 = 1 is the paper's law; docs/method.md, "Control")::

    e1 = x_h1 - x_hd1,  e2 = x_h2 - x_hd2,  e3 = theta - theta_d,  ebar2 = e2 - x_hd1 e3   (19), (27)
    w_c = k_w e3 - theta_d_dot - k_2 x_hd1_dot ebar2                                       (30)
    v_c = k_v e1 - k_2 ebar2 w_c + dhat (x_h2 w_c - x_hd1_dot)                              (29)
    dhat_dot = gamma_1 e1 (x_h2 w_c - x_hd1_dot)                                           (31)
    V = 1/2 d* e1^2 + k_2/2 ebar2^2 + 1/2 e3^2 + 1/(2 gamma_1) (d* - dhat)^2               (36)

and ``V_dot = -k_v e1^2 - k_w e3^2`` (38). Functions take scalars or broadcastable arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .control_settings import ControllerGains
from .depth import check_depth, project_depth
from .frames import wrap_angle

@dataclass(frozen=True)
class Measurement:
    """The decomposed homography at one instant (12), (14): theta = phi* - phi (rad), x_h = x_f / d*."""

    theta: float | NDArray[np.float64]
    x_h1: float | NDArray[np.float64]
    x_h2: float | NDArray[np.float64]


@dataclass(frozen=True)
class DesiredState:
    """The desired trajectory at one instant (Remark 1): theta_d (rad, unwrapped), x_hd (-),
    theta_d_dot = -w_cd (5) (rad/s), x_hd_dot (1/s, (25))."""

    theta_d: float | NDArray[np.float64]
    x_hd1: float | NDArray[np.float64]
    x_hd2: float | NDArray[np.float64]
    theta_d_dot: float | NDArray[np.float64]
    x_hd1_dot: float | NDArray[np.float64]
    x_hd2_dot: float | NDArray[np.float64]


@dataclass(frozen=True)
class TrackingErrors:
    """The errors (19) and (27)."""

    e1: float | NDArray[np.float64]
    e2: float | NDArray[np.float64]
    e3: float | NDArray[np.float64]
    ebar2: float | NDArray[np.float64]


@dataclass(frozen=True)
class ControlOutput:
    """One evaluation of the law: commands, the adaptation rate and the errors."""

    v_c: float | NDArray[np.float64]
    w_c: float | NDArray[np.float64]
    dhat_dot: float | NDArray[np.float64]
    errors: TrackingErrors


def tracking_errors(measured: Measurement, desired: DesiredState) -> TrackingErrors:
    """Errors (19) and ebar2 (27); e3 wrapped to [-pi, pi) so that crossing +-pi stays continuous."""
    e1 = measured.x_h1 - desired.x_hd1
    e2 = measured.x_h2 - desired.x_hd2
    e3 = wrap_angle(measured.theta - desired.theta_d)
    ebar2 = e2 - desired.x_hd1 * e3
    return TrackingErrors(e1=e1, e2=e2, e3=e3, ebar2=ebar2)


def control_law(measured: Measurement, desired: DesiredState, dhat: ArrayLike, gains: ControllerGains) -> ControlOutput:
    """Commands (29)-(30) and the update law (31) at the depth estimate ``dhat`` (m): ``v_c``
    (m/s), ``w_c`` (rad/s), ``dhat_dot`` (m/s)."""
    err = tracking_errors(measured, desired)
    k2 = gains.k_2
    w_c = gains.k_w * err.e3 - desired.theta_d_dot - k2 * desired.x_hd1_dot * err.ebar2
    coupling = measured.x_h2 * w_c - desired.x_hd1_dot
    v_c = gains.k_v * err.e1 - k2 * err.ebar2 * w_c + dhat * coupling
    dhat_dot = gains.gamma * err.e1 * coupling
    return ControlOutput(v_c=v_c, w_c=w_c, dhat_dot=dhat_dot, errors=err)


def lyapunov(errors: TrackingErrors, dhat: ArrayLike, d_star: float, gains: ControllerGains) -> NDArray[np.float64] | float:
    """The Lyapunov function (36) for the true depth d* (m), known only in simulation; without
    adaptation (gamma = 0) the depth term is left out."""
    d_tilde = d_star - dhat
    value = 0.5 * d_star * errors.e1 * errors.e1 + 0.5 * gains.k_2 * errors.ebar2 * errors.ebar2 + 0.5 * errors.e3 * errors.e3
    if gains.gamma > 0.0:
        value = value + 0.5 / gains.gamma * d_tilde * d_tilde
    return float(value) if np.ndim(value) == 0 else value


class AdaptiveTrackingController:
    """The law with its one piece of state, the depth estimate dhat (m), from ``dhat0``."""

    def __init__(self, gains: ControllerGains, dhat0: float) -> None:
        self.gains = gains
        self.dhat = self.dhat0 = check_depth(dhat0, "the initial depth estimate dhat0")

    @property
    def lateral_gain(self) -> float:
        """k_2 (1 for the paper's law)."""
        return self.gains.k_2

    def step(self, measured: Measurement, desired: DesiredState, dt: float, adapt: bool = True) -> ControlOutput:
        """Commands for this instant; advances dhat by ``dt`` (s) unless ``adapt`` is False."""
        output = control_law(measured, desired, self.dhat, self.gains)
        if adapt:
            self.adapt(output, dt)
        return output

    def adapt(self, output: ControlOutput | None, dt: float,
              depth_reference: tuple[float, float] | None = None) -> None:
        """Integrate (31) over ``dt`` (s) by explicit Euler, projected (:func:`~.depth.project_depth`); ``depth_reference`` ``(d_f, kappa)``
        (m, 1/s) adds the pull ``kappa (d_f - dhat)`` (:func:`~.state_filter.scheduled_depth_pull`).
        With gamma_1 = 0 (the non-adaptive baseline) dhat stays. ``output`` None: the pull alone (while
        the state filter settles (31) is frozen, but the depth the motion measures already paces the
        taught commands (25))."""
        rate = 0.0 if output is None else float(output.dhat_dot)
        if depth_reference is not None and self.gains.gamma > 0.0:
            depth, pull = depth_reference
            rate += pull * (depth - self.dhat)
        self.dhat = project_depth(self.dhat + rate * dt, self.dhat0)

    def feedforward(self, desired: DesiredState) -> tuple[float, float]:
        """The taught commands (25) at the current dhat: ``w = -theta_d_dot``, ``v = dhat (x_hd2 w - x_hd1_dot)``."""
        w_c = -float(desired.theta_d_dot)
        return self.dhat * (float(desired.x_hd2) * w_c - float(desired.x_hd1_dot)), w_c
