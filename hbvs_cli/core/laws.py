"""Every control law ``hbvs repeat --law`` knows (docs/method.md, "Baselines"): the adaptive
law (29)-(31) as ``lateral-gain`` (default) or ``paper`` (k_2 = 1); ``non-adaptive``, gamma_1 = 0;
and ``kanayama`` (Kanayama, Kimura, Miyazaki, Noguchi, IEEE ICRA 1990) on the planar pose
reconstructed from the homography at a fixed dhat. Each has the methods of
:class:`~.controller.AdaptiveTrackingController`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from ..errors import InvalidValueError
from .control_settings import ALL_LAWS, LAW_KANAYAMA, LAW_LATERAL_GAIN, LAW_NON_ADAPTIVE, LAW_PAPER, ControllerGains
from .controller import AdaptiveTrackingController, ControlOutput, DesiredState, Measurement, tracking_errors
from .depth import check_depth

__all__ = ["ALL_LAWS", "LAW_KANAYAMA", "LAW_NON_ADAPTIVE"]  # spelled in control_settings (no numpy: --help lists them)


@dataclass(frozen=True)
class KanayamaGains:
    """Gains of Kanayama et al. (1990), their example: K_x (1/s), K_y (1/m^2), K_theta (1/m)
    = 2 sqrt(K_y), the linearised lateral error critically damped."""

    k_x: float = 10.0
    k_y: float = 64.0
    k_theta: float = 16.0


def gains_for_law(gains: ControllerGains, law: str) -> ControllerGains:
    """The gains a law runs with (recorded in the run file): ``paper`` forces k_2 = 1,
    ``non-adaptive`` and ``kanayama`` have gamma_1 = 0."""
    if law in (LAW_PAPER, LAW_LATERAL_GAIN):
        return gains.with_law(law)
    if law in (LAW_NON_ADAPTIVE, LAW_KANAYAMA):
        return replace(gains, gamma=0.0)
    raise InvalidValueError(f"--law must be one of {', '.join(ALL_LAWS)}, got {law!r}")


def make_controller(law: str, gains: ControllerGains, dhat0: float):
    """The controller of ``law`` with the gains of :func:`gains_for_law` and dhat(0) (m)."""
    gains = gains_for_law(gains, law)
    if law == LAW_KANAYAMA:
        return KanayamaController(dhat0)
    # gamma_1 = 0 makes (31) zero: the non-adaptive law is the adaptive one, frozen.
    return AdaptiveTrackingController(gains, dhat0)


def reconstructed_tracking_error(measured: Measurement, desired: DesiredState, dhat: float) -> tuple[float, float, float]:
    """Kanayama's error posture: the desired pose seen from the robot, ``e_xy = dhat (x_h -
    Rz(e3) x_hd)`` (m) with ``x_f = dhat x_h`` (3), (14), and ``e_theta = e3`` (rad)."""
    e3 = float(tracking_errors(measured, desired).e3)
    c, s = math.cos(e3), math.sin(e3)
    x_hd1, x_hd2 = float(desired.x_hd1), float(desired.x_hd2)
    e_x = dhat * (float(measured.x_h1) - (c * x_hd1 - s * x_hd2))
    e_y = dhat * (float(measured.x_h2) - (s * x_hd1 + c * x_hd2))
    return e_x, e_y, e3


class KanayamaController:
    """Kanayama et al. (1990) at the fixed depth ``dhat`` (m): ``v = v_r cos e_theta + K_x e_x``,
    ``w = w_r + v_r (K_y e_y + K_theta sin e_theta)``, (v_r, w_r) from :meth:`feedforward`."""

    def __init__(self, dhat: float) -> None:
        self.dhat = check_depth(dhat, "the depth estimate dhat0")
        self.gains = KanayamaGains()

    def step(self, measured: Measurement, desired: DesiredState, dt: float, adapt: bool = True) -> ControlOutput:
        """Commands for this instant (nothing adapts)."""
        e_x, e_y, e_theta = reconstructed_tracking_error(measured, desired, self.dhat)
        v_r, w_r = self.feedforward(desired)
        g = self.gains
        v = v_r * math.cos(e_theta) + g.k_x * e_x
        w = w_r + v_r * (g.k_y * e_y + g.k_theta * math.sin(e_theta))
        return ControlOutput(v_c=v, w_c=w, dhat_dot=0.0, errors=tracking_errors(measured, desired))

    def adapt(self, output: ControlOutput, dt: float, depth_reference: tuple[float, float] | None = None) -> None:
        """Nothing to learn: the depth estimate stays fixed."""

    def follow_depth(self, depth_reference: tuple[float, float], dt: float) -> None:
        """Nothing to learn: the depth estimate stays fixed."""

    def feedforward(self, desired: DesiredState) -> tuple[float, float]:
        """The reference commands (25), as :meth:`~.controller.AdaptiveTrackingController.feedforward`."""
        w_r = -float(desired.theta_d_dot)
        return self.dhat * (float(desired.x_hd2) * w_r - float(desired.x_hd1_dot)), w_r

    def hold(self) -> tuple[float, float]:
        """Commands while the target is lost: stop."""
        return 0.0, 0.0
