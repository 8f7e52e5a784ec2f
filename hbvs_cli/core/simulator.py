"""One control period of the closed loop, as the loop (:func:`hbvs_cli.sim.closed_loop.run_closed_loop`)
and a live robot share it: the actuator limits the commands pass through, the record of a
step, and how many rejected frames the last command is held through.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..errors import InvalidValueError
from .controller import ControlOutput, DesiredState, Measurement
from .estimation import Observation, ObservationStatus
from .state_filter import FilterEstimate


@dataclass(frozen=True)
class ActuatorLimits:
    """Limits of the robot's drive; ``None`` means unlimited.

    Attributes
    ----------
    max_v : float or None
        |v| bound (m/s).
    max_w : float or None
        |w| bound (rad/s).
    max_accel : float or None
        Bound on the change of v per second (m/s^2); w's change is bounded by
        ``max_accel`` rad/s^2 as well, a common simplification for differential drives.
    """

    max_v: float | None = None
    max_w: float | None = None
    max_accel: float | None = None

    def __post_init__(self) -> None:
        for name in ("max_v", "max_w", "max_accel"):
            value = getattr(self, name)
            if value is not None and (not np.isfinite(value) or value <= 0.0):
                raise InvalidValueError(f"--{name.replace('_', '-')} must be a positive number, got {value}")

    def apply(self, v: float, w: float, previous: tuple[float, float], dt: float) -> tuple[float, float, bool]:
        """Clip a command; returns ``(v, w, saturated)``."""
        v_out, w_out = float(v), float(w)
        if self.max_accel is not None:
            step = self.max_accel * dt
            v_out = float(np.clip(v_out, previous[0] - step, previous[0] + step))
            w_out = float(np.clip(w_out, previous[1] - step, previous[1] + step))
        if self.max_v is not None:
            v_out = float(np.clip(v_out, -self.max_v, self.max_v))
        if self.max_w is not None:
            w_out = float(np.clip(w_out, -self.max_w, self.max_w))
        saturated = abs(v_out - v) > 1e-12 or abs(w_out - w) > 1e-12
        return v_out, w_out, saturated


@dataclass(frozen=True)
class StepRecord:
    """What happened in one control period.

    Attributes
    ----------
    t : float
        Time of the measurement (s).
    pose : ndarray, shape (3,)
        True robot pose at ``t`` (m, m, rad).
    observation : Observation
        What the controller acted on (after any latency).
    desired : DesiredState
    output : ControlOutput or None
        The law's evaluation (None when lost or dropped).
    v_c, w_c : float
        The command actually sent after limits (m/s, rad/s).
    saturated : bool
    dhat : float
        Depth estimate used at this step (m), before its update.
    target_lost : bool or None
        Whether the target counts as lost at this step: the last frame that arrived did
        not show it (a dropped frame keeps the state before it). ``None``: the
        observation's own ``lost``.
    estimate : FilterEstimate or None
        The state filter's estimate the law acted on (None without a filter, or before
        its first measurement).
    """

    t: float
    pose: NDArray[np.float64]
    observation: Observation
    desired: DesiredState
    output: ControlOutput | None
    v_c: float
    w_c: float
    saturated: bool
    dhat: float
    target_lost: bool | None = None
    estimate: FilterEstimate | None = None

    @property
    def measurement(self) -> Measurement | None:
        return self.observation.measurement

    @property
    def lost(self) -> bool:
        return self.observation.lost if self.target_lost is None else self.target_lost

    @property
    def dropped(self) -> bool:
        """The camera frame of this step was dropped (not: still on its way, with latency)."""
        return self.observation.status == ObservationStatus.DROPPED and self.observation is not NOT_YET


#: Consecutive outlier frames through which the last command is held before stopping.
MAX_HELD_OUTLIERS = 3

#: What the controller sees before the first (latency-delayed) frame arrives.
NOT_YET = Observation(None, status=ObservationStatus.DROPPED)
