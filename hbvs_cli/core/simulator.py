"""One control period of the closed loop, shared by the simulated loop and a live robot.

A lost target stops the robot and freezes the adaptation until it is back; a dropped frame,
or a few outliers in a row, hold the last command (stopping for one bad frame would make the
robot lag). With the state filter the law acts on its estimate, through frames without a
measurement on its prediction while that stays precise.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .controller import ControlOutput, DesiredState, Measurement
from .estimation import Observation, ObservationStatus, dropped
from .laws import ControlLaw
from .state_filter import FilterEstimate, FilterOutcome, ServoStateFilter, scheduled_depth_pull


@dataclass(frozen=True)
class ActuatorLimits:
    """Limits of the robot's drive, None for unlimited: |v| (m/s), |w| (rad/s), and the
    change of v per second (m/s^2), which bounds w's (rad/s^2) as well; ``lag_s`` the drive's
    time constant (s): its speeds follow a command as a first-order lag (0: at once). Checked
    where they are read (``repeat``'s options and ``--config``), not again here."""

    max_v: float | None = None
    max_w: float | None = None
    max_accel: float | None = None
    lag_s: float = 0.0

    def executed(self, speeds: tuple[float, float], command: tuple[float, float], dt: float) -> tuple[tuple[float, float], tuple[float, float]]:
        """What the drive does with ``command`` (v, w) held for ``dt`` (s) from ``speeds``: its mean speeds over
        ``dt`` (what moves the robot) and its speeds at the end, through the lag ``tau``:
        ``s(t) = c + (s0 - c) exp(-t / tau)``. Without a lag both are the command."""
        if self.lag_s == 0.0:
            return command, command
        decay = math.exp(-dt / self.lag_s)
        kept = self.lag_s / dt * (1.0 - decay) if dt > 0 else 1.0
        (v0, w0), (v, w) = speeds, command
        return (v + (v0 - v) * kept, w + (w0 - w) * kept), (v + (v0 - v) * decay, w + (w0 - w) * decay)

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
    """One control period: the measurement's time ``t`` (s), the true ``pose`` (3,) (m, m, rad),
    the ``observation`` acted on, the law's ``output`` (None when lost or dropped), the command
    sent ``v_c, w_c`` (m/s, rad/s), ``dhat`` (m) before its update, whether the target is
    ``lost`` and the filter's ``estimate``."""

    t: float
    pose: NDArray[np.float64]
    observation: Observation
    desired: DesiredState
    output: ControlOutput | None
    v_c: float
    w_c: float
    saturated: bool
    dhat: float
    lost: bool
    estimate: FilterEstimate | None = None

    @property
    def measurement(self) -> Measurement | None:
        return self.observation.measurement

    @property
    def dropped(self) -> bool:
        """The camera frame of this step was dropped (not: still on its way, with latency)."""
        return self.observation.status == ObservationStatus.DROPPED and self.observation is not NOT_YET


#: Consecutive outlier frames through which the last command is held before stopping.
MAX_HELD_OUTLIERS = 3

#: What the controller sees before the first (latency-delayed) frame arrives.
NOT_YET = dropped()


class ServoStep:
    """One camera frame's decision, filter, law, limits and adaptation: :meth:`decide` for each
    frame, then :meth:`sent` once the command is out. ``latency_steps``: frames between taking
    a frame and acting on it."""

    def __init__(self, controller: ControlLaw, limits: ActuatorLimits, latency_steps: int = 0,
                 state_filter: ServoStateFilter | None = None, stop_when_lost: bool = False) -> None:
        self.controller = controller
        #: A robot stops at once when the target is lost (the simulator may coast on the filter's prediction).
        self.stop_when_lost = stop_when_lost
        self.limits = limits
        self.latency_steps = latency_steps
        self.state_filter = state_filter
        #: The last command sent (m/s, rad/s).
        self.previous = (0.0, 0.0)
        #: The drive's speeds as the limits' lag makes them (m/s, rad/s).
        self.speeds = (0.0, 0.0)
        self.rejected_in_a_row = 0
        self.target_lost = False
        # Commands sent since the frame being fused was taken (latency_steps of them).
        self.unseen_commands: deque[tuple[float, float]] = deque()
        #: Whether dhat has met the filter's depth (scheduled_depth_pull).
        self.depth_met = False
        if state_filter is not None:
            # The filter starts its depth from dhat(0), and the motion measures it from there.
            state_filter.expect_depth(controller.dhat)

    def decide(self, t: float, pose: NDArray[np.float64], observation: Observation, desired: DesiredState, dt: float) -> StepRecord:
        """The command for ``observation`` (taken at ``t``, s), held for the period ``dt`` (s);
        ``pose`` is only recorded (the true pose in simulation, NaN on a robot)."""
        controller, state_filter, previous = self.controller, self.state_filter, self.previous
        dhat = controller.dhat
        output = None
        # The lost state and the run of rejected frames describe the frames that arrived.
        if observation.status != ObservationStatus.DROPPED:
            self.rejected_in_a_row = self.rejected_in_a_row + 1 if observation.status == ObservationStatus.OUTLIER else 0
            self.target_lost = observation.lost
        coasting = 0 < self.rejected_in_a_row <= MAX_HELD_OUTLIERS or (observation.status == ObservationStatus.DROPPED and not self.target_lost)
        estimate = None
        fresh = predicted = False
        if state_filter is not None:
            if observation.status == ObservationStatus.OK:
                fresh = state_filter.correct(observation.measurement, observation.residual, dt) != FilterOutcome.GATED
            estimate = state_filter.estimate(self.unseen_commands, dt)
            # Without a usable frame the law acts on a trusted prediction, adaptation frozen.
            predicted = not fresh and state_filter.trusted(estimate)
        if estimate is not None and not state_filter.settled:
            # Soft start: the feedback of (29)-(30) fades in from the taught commands (25).
            output = controller.step(estimate.measurement, desired, dt, adapt=False)
            v_ff, w_ff = controller.feedforward(desired)
            share = state_filter.settling_fraction
            v_cmd = v_ff + share * (float(output.v_c) - v_ff)
            w_cmd = w_ff + share * (float(output.w_c) - w_ff)
            if fresh:
                controller.adapt(None, dt, (estimate.depth, estimate.depth_pull))
        elif fresh or predicted or (state_filter is None and observation.status == ObservationStatus.OK):
            # Without a filter the law adapts dhat (31) itself; with one, below.
            measured = observation.measurement if state_filter is None else estimate.measurement
            output = controller.step(measured, desired, dt, adapt=state_filter is None)
            v_cmd, w_cmd = float(output.v_c), float(output.w_c)
        elif coasting:
            v_cmd, w_cmd = previous
        else:
            v_cmd, w_cmd = 0.0, 0.0  # the target is lost: stop
        v_c, w_c, saturated = self.limits.apply(v_cmd, w_cmd, previous, dt)
        if fresh and output is not None and state_filter.settled and not saturated:
            # (31) assumes the robot executed (29)-(30): a clipped command would wind dhat up.
            errors, settings = output.errors, state_filter.settings
            self.depth_met = self.depth_met or abs(estimate.depth - controller.dhat) <= settings.depth_met * estimate.depth
            pull = scheduled_depth_pull(estimate.depth_pull, float(errors.ebar2), float(errors.e3),
                                        controller.lateral_gain, settings, self.depth_met)
            controller.adapt(output, dt, (estimate.depth, pull))
        if self.stop_when_lost and self.target_lost:
            v_c = w_c = 0.0
        self.previous = (v_c, w_c)
        return StepRecord(
            t=t, pose=pose, observation=observation, desired=desired, output=output,
            v_c=v_c, w_c=w_c, saturated=saturated, dhat=dhat, lost=self.target_lost, estimate=estimate,
        )

    def sent(self, dt: float) -> None:
        """The last decided command was sent and is held for ``dt`` (s): the filter moves on."""
        if self.state_filter is not None:
            # The filter's state is at its last frame's time: later commands wait (latency). The robot
            # moves as its drive executes the command: through a lag, the filter would read it as depth.
            executed, self.speeds = self.limits.executed(self.speeds, self.previous, dt)
            self.unseen_commands.append(executed)
            if len(self.unseen_commands) > self.latency_steps:
                self.state_filter.predict(*self.unseen_commands.popleft(), dt)
