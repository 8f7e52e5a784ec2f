"""Every control law ``hbvs repeat --law`` knows (docs/method.md, "Baselines"): the adaptive
law (29)-(31) as ``lateral-gain`` (default) or ``paper`` (k_2 = 1); ``non-adaptive``, gamma_1 = 0;
and ``kanayama`` (Kanayama, Kimura, Miyazaki, Noguchi, IEEE ICRA 1990) on the planar pose
reconstructed from the homography at a fixed dhat. Each is a :class:`ControlLaw` in
:data:`LAW_REGISTRY`; another is added with :func:`register_law` (docs/layout.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Callable, Protocol

from ..errors import InvalidValueError
from .control_settings import LAW_KANAYAMA, LAW_LATERAL_GAIN, LAW_NON_ADAPTIVE, LAW_PAPER, ControllerGains
from .controller import AdaptiveTrackingController, ControlOutput, DesiredState, Measurement, tracking_errors
from .depth import check_depth

class ControlLaw(Protocol):
    """What the loop asks of a law (:class:`~.simulator.ServoStep`): its depth estimate ``dhat`` and dhat(0) (m),
    commands for a measurement, the update (31) and its pull toward the filter's depth (the pull alone
    without the law's output), the taught commands (25) and ``lateral_gain`` (k_2, 1 without one). A
    lost target stops the robot whatever the law (:class:`~.simulator.ServoStep`). ``gains`` are the ones
    it was made with (:func:`gains_for_law`); a route swaps them at each segment (sim/route_loop.py)."""

    dhat: float
    dhat0: float
    gains: ControllerGains

    @property
    def lateral_gain(self) -> float: ...

    def step(self, measured: Measurement, desired: DesiredState, dt: float, adapt: bool = True) -> ControlOutput: ...

    def adapt(self, output: ControlOutput | None, dt: float,
              depth_reference: tuple[float, float] | None = None) -> None: ...

    def feedforward(self, desired: DesiredState) -> tuple[float, float]: ...


@dataclass(frozen=True)
class LawSpec:
    """A law by name: ``gains`` the gains it runs with (recorded in the run file) from the ones set,
    ``factory(gains, dhat0)`` the law itself."""

    name: str
    gains: Callable[[ControllerGains], ControllerGains]
    factory: Callable[[ControllerGains, float], ControlLaw]


#: Every law ``--law`` and ``hbvs sweep`` accept, by name, the default first (:func:`register_law` adds one).
LAW_REGISTRY: dict[str, LawSpec] = {}


def register_law(spec: LawSpec) -> None:
    """Make ``spec`` a law ``--law`` accepts (a name already taken is replaced)."""
    LAW_REGISTRY[spec.name] = spec


def _law(name: str) -> LawSpec:
    if name not in LAW_REGISTRY:
        raise InvalidValueError(f"--law must be one of {', '.join(LAW_REGISTRY)}, got {name!r}")
    return LAW_REGISTRY[name]


def gains_for_law(gains: ControllerGains, law: str) -> ControllerGains:
    """The gains ``law`` runs with: ``paper`` forces k_2 = 1, ``non-adaptive`` and ``kanayama`` have gamma_1 = 0."""
    return _law(law).gains(gains)


def make_controller(law: str, gains: ControllerGains, dhat0: float) -> ControlLaw:
    """The controller of ``law`` with the gains of :func:`gains_for_law` and dhat(0) (m)."""
    spec = _law(law)
    return spec.factory(spec.gains(gains), dhat0)


@dataclass(frozen=True)
class KanayamaGains:
    """Gains of Kanayama et al. (1990), their example: K_x (1/s), K_y (1/m^2), K_theta (1/m)
    = 2 sqrt(K_y), the linearised lateral error critically damped."""

    k_x: float = 10.0
    k_y: float = 64.0
    k_theta: float = 16.0


def _without_adaptation(gains: ControllerGains) -> ControllerGains:
    # gamma_1 = 0 makes (31) zero: the non-adaptive law is the adaptive one, frozen.
    return replace(gains, gamma=0.0)


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
    ``w = w_r + v_r (K_y e_y + K_theta sin e_theta)``, (v_r, w_r) from :meth:`feedforward`. It steers
    with its own :class:`KanayamaGains` whatever ``gains`` (recorded, and swapped by a route) say."""

    #: Kanayama's law has no k_2: the depth pull (scheduled_depth_pull) sees the paper's 1.
    lateral_gain = 1.0

    def __init__(self, gains: ControllerGains, dhat: float) -> None:
        self.dhat = self.dhat0 = check_depth(dhat, "the depth estimate dhat0")
        self.gains, self.kanayama = gains, KanayamaGains()

    def step(self, measured: Measurement, desired: DesiredState, dt: float, adapt: bool = True) -> ControlOutput:
        """Commands for this instant (nothing adapts)."""
        e_x, e_y, e_theta = reconstructed_tracking_error(measured, desired, self.dhat)
        v_r, w_r = self.feedforward(desired)
        g = self.kanayama
        v = v_r * math.cos(e_theta) + g.k_x * e_x
        w = w_r + v_r * (g.k_y * e_y + g.k_theta * math.sin(e_theta))
        return ControlOutput(v_c=v, w_c=w, dhat_dot=0.0, errors=tracking_errors(measured, desired))

    def adapt(self, output: ControlOutput | None, dt: float,
              depth_reference: tuple[float, float] | None = None) -> None:
        """Nothing to learn: the depth estimate stays fixed."""

    #: The reference commands (25) at its fixed dhat: the adaptive law's own.
    feedforward = AdaptiveTrackingController.feedforward


register_law(LawSpec(LAW_LATERAL_GAIN, lambda gains: gains, AdaptiveTrackingController))
register_law(LawSpec(LAW_PAPER, lambda gains: replace(gains, k_2=1.0), AdaptiveTrackingController))  # (29): no lateral gain
register_law(LawSpec(LAW_NON_ADAPTIVE, _without_adaptation, AdaptiveTrackingController))
register_law(LawSpec(LAW_KANAYAMA, _without_adaptation, KanayamaController))
