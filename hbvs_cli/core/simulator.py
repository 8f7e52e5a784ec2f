"""The closed loop: sense, control, actuate, move; one camera frame at a time.

Every control period ``dt`` the simulator asks a sensing function for a measurement of
the current pose (exact points, noisy points or a whole rendered image run through a
detector: the caller decides), the controller answers with (v_c, w_c), the actuator limits
clip them, and the unicycle integrates them exactly while they are held for ``dt``
(:mod:`hbvs_cli.core.unicycle`).

When the sensing function reports the target lost, the robot is commanded to stop and the
adaptation is frozen; it resumes when the target is back. When a frame is dropped (never
arrives), or a few in a row are rejected as outliers, the last command is held and the
adaptation is frozen for those periods: stopping for one bad frame would only make the
robot lag its trajectory. A dropped frame carries no news about the target, so it keeps
the lost state of the last frame that arrived: a drop during an occlusion is still lost
time (the lost timeout keeps counting), never a "target back".

With a state filter (:mod:`hbvs_cli.core.state_filter`) the law acts on its estimate, and
through frames that give no measurement (dropped, occluded, rejected) on its prediction for
as long as the prediction's standard deviation stays small; only then does the robot stop.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import InvalidValueError
from .controller import AdaptiveTrackingController, ControlOutput, DesiredState, Measurement
from .estimation import Observation, ObservationStatus
from .state_filter import FilterEstimate, FilterOutcome, ServoStateFilter
from .trajectory import DesiredTrajectory
from .unicycle import integrate_unicycle


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
        return self.observation.status == ObservationStatus.DROPPED and self.observation is not _NOT_YET


SenseFunction = Callable[[NDArray[np.float64], float], Observation]

#: Consecutive outlier frames through which the last command is held before stopping.
MAX_HELD_OUTLIERS = 3

#: What the controller sees before the first (latency-delayed) frame arrives.
_NOT_YET = Observation(None, status=ObservationStatus.DROPPED)


def run_closed_loop(
    sense: SenseFunction,
    trajectory: DesiredTrajectory,
    controller: AdaptiveTrackingController,
    start_pose: ArrayLike,
    dt: float,
    duration: float,
    limits: ActuatorLimits | None = None,
    latency_steps: int = 0,
    state_filter: ServoStateFilter | None = None,
) -> Iterator[StepRecord]:
    """Simulate the closed loop, yielding one :class:`StepRecord` per control period.

    Parameters
    ----------
    sense : callable
        ``(pose, t) -> Observation``.
    trajectory : DesiredTrajectory
    controller : AdaptiveTrackingController
        Its dhat is updated in place.
    start_pose : array_like, shape (3,)
    dt : float
        Control period (s).
    duration : float
        Seconds to simulate.
    limits : ActuatorLimits, optional
    latency_steps : int
        The controller acts on the observation taken this many periods earlier; before
        the first one arrives it holds still.
    state_filter : ServoStateFilter, optional
        When given, the law acts on its estimate (docs/method.md, "State filter"): each
        frame is fused at the time it was taken, the estimate is carried over the commands
        sent since (latency), and through dropped frames and rejected ones the law runs on
        the prediction with the adaptation frozen. Without it the law acts on each raw
        measurement, as in the paper.
    """
    if dt <= 0.0 or not np.isfinite(dt):
        raise InvalidValueError(f"the control period must be positive, got {dt}")
    if latency_steps < 0:
        raise InvalidValueError("--latency must be zero or a positive number of frames")
    limits = limits or ActuatorLimits()
    pose = tuple(float(v) for v in np.asarray(start_pose, dtype=float))
    steps = int(round(duration / dt))
    # The control instants are known in advance: evaluate the desired trajectory at all of
    # them at once (vectorised) instead of once per step.
    times = np.arange(steps) * dt
    schedule = trajectory.evaluate(times)
    columns = [np.atleast_1d(np.asarray(getattr(schedule, name), dtype=float)).tolist() for name in _DESIRED_FIELDS]
    pending: deque[Observation] = deque()
    servo = ServoStep(controller, limits, latency_steps, state_filter)
    for k in range(steps):
        t = k * dt
        pending.append(sense(np.array(pose), t))
        observation = pending.popleft() if len(pending) > latency_steps else _NOT_YET
        desired = DesiredState(*(column[k] for column in columns))
        record = servo.decide(t, np.array(pose), observation, desired, dt)
        yield record
        servo.sent(dt)
        pose = integrate_unicycle(pose, record.v_c, record.w_c, dt)


class ServoStep:
    """One camera frame's decision: filter, law, limits, adaptation (the loop's body).

    The simulator (:func:`run_closed_loop`) and the live loop on a robot
    (:mod:`hbvs_cli.stages.live`) both call :meth:`decide` with each frame's observation and
    then :meth:`sent` once the command is out, so that they act identically on the same
    frames.

    Parameters
    ----------
    controller : AdaptiveTrackingController
        Its dhat is updated in place.
    limits : ActuatorLimits
    latency_steps : int
        Frames between taking a frame and acting on it (the filter carries its estimate
        over the commands sent since).
    state_filter : ServoStateFilter or None
    """

    def __init__(self, controller: AdaptiveTrackingController, limits: ActuatorLimits, latency_steps: int = 0,
                 state_filter: ServoStateFilter | None = None) -> None:
        self.controller = controller
        self.limits = limits
        self.latency_steps = latency_steps
        self.state_filter = state_filter
        #: The last command sent (m/s, rad/s).
        self.previous = (0.0, 0.0)
        self.rejected_in_a_row = 0
        self.target_lost = False
        # Commands sent since the frame being fused was taken (latency_steps of them).
        self.unseen_commands: deque[tuple[float, float]] = deque()

    def decide(self, t: float, pose: NDArray[np.float64], observation: Observation, desired: DesiredState, dt: float) -> StepRecord:
        """The command for ``observation`` (taken at ``t``, s) while ``desired`` is wanted.

        ``dt`` (s) is the control period: the time the command will be held. ``pose`` is
        only recorded (the true pose in simulation, NaN on a robot).
        """
        controller, state_filter, previous = self.controller, self.state_filter, self.previous
        dhat = controller.dhat
        output = None
        # A dropped frame changes neither the lost state nor the run of rejected frames:
        # both describe the frames that arrived.
        if observation.status != ObservationStatus.DROPPED:
            self.rejected_in_a_row = self.rejected_in_a_row + 1 if observation.status == ObservationStatus.OUTLIER else 0
            self.target_lost = observation.lost
        coasting = 0 < self.rejected_in_a_row <= MAX_HELD_OUTLIERS or (observation.status == ObservationStatus.DROPPED and not self.target_lost)
        estimate = None
        fresh = predicted = False
        if state_filter is not None:
            if observation.status == ObservationStatus.OK:
                fresh = state_filter.correct(observation.measurement, observation.residual, dt) != FilterOutcome.GATED
            estimate = state_filter.estimate(list(self.unseen_commands), dt, dhat, previous)
            # No usable frame (dropped, occluded, rejected): the law acts on the
            # prediction while it is trusted, with the adaptation frozen.
            predicted = not fresh and state_filter.trusted(estimate)
        if estimate is not None and not state_filter.settled:
            # Soft start: the feedback of (29)-(30) is faded in over the filter's settling
            # time, from the taught commands (25), while the first frames are averaged.
            output = controller.step(estimate.measurement, desired, dt, adapt=False)
            v_ff, w_ff = controller.feedforward(desired)
            share = state_filter.settling_fraction
            v_cmd = v_ff + share * (float(output.v_c) - v_ff)
            w_cmd = w_ff + share * (float(output.w_c) - w_ff)
        elif fresh or predicted:
            output = controller.step(estimate.measurement, desired, dt, adapt=False)
            v_cmd, w_cmd = float(output.v_c), float(output.w_c)
        elif state_filter is None and observation.status == ObservationStatus.OK:
            output = controller.step(observation.measurement, desired, dt)
            v_cmd, w_cmd = float(output.v_c), float(output.w_c)
        elif coasting:
            v_cmd, w_cmd = previous
        else:
            v_cmd, w_cmd = controller.hold()
        v_c, w_c, saturated = self.limits.apply(v_cmd, w_cmd, previous, dt)
        if fresh and output is not None and state_filter.settled and not saturated:
            # (31) assumes the robot executed (29)-(30): a clipped command would wind dhat up.
            controller.adapt(output, dt)
        self.previous = (v_c, w_c)
        return StepRecord(
            t=t, pose=pose, observation=observation, desired=desired, output=output,
            v_c=v_c, w_c=w_c, saturated=saturated, dhat=dhat, target_lost=self.target_lost, estimate=estimate,
        )

    def sent(self, dt: float) -> None:
        """The last decided command was sent and is held for ``dt`` (s): the filter moves on."""
        if self.state_filter is not None:
            # The filter's state is at the time its last frame was taken: it moves on with
            # the command sent then, and the later ones wait (latency).
            self.unseen_commands.append(self.previous)
            if len(self.unseen_commands) > self.latency_steps:
                self.state_filter.predict(*self.unseen_commands.popleft(), dt, self.controller.dhat)


_DESIRED_FIELDS = ("theta_d", "x_hd1", "x_hd2", "theta_d_dot", "x_hd1_dot", "x_hd2_dot")
