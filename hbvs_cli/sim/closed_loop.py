"""The closed loop of ``repeat --sim``: sense, control, actuate, move; one camera frame at a time.

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

:class:`Simulation` holds what the loop runs on: the scene, the simulated camera, the
time-scaled trajectory and the controller.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..core.controller import AdaptiveTrackingController, DesiredState
from ..core.estimation import Observation, ObservationStatus
from ..core.simulator import MAX_HELD_OUTLIERS, NOT_YET, ActuatorLimits, StepRecord
from ..core.state_filter import FilterOutcome, ServoStateFilter
from ..core.trajectory import DesiredTrajectory, TimeScaledTrajectory
from ..core.unicycle import integrate_unicycle
from ..errors import InvalidValueError
from .camera import SimulatedCamera
from .scene import Scene

SenseFunction = Callable[[NDArray[np.float64], float], Observation]


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
    previous = (0.0, 0.0)
    rejected_in_a_row = 0
    target_lost = False
    # Commands sent since the frame being fused was taken (latency_steps of them).
    unseen_commands: deque[tuple[float, float]] = deque()
    for k in range(steps):
        t = k * dt
        pending.append(sense(np.array(pose), t))
        observation = pending.popleft() if len(pending) > latency_steps else NOT_YET
        desired = DesiredState(*(column[k] for column in columns))
        dhat = controller.dhat
        output = None
        # A dropped frame changes neither the lost state nor the run of rejected frames:
        # both describe the frames that arrived.
        if observation.status != ObservationStatus.DROPPED:
            rejected_in_a_row = rejected_in_a_row + 1 if observation.status == ObservationStatus.OUTLIER else 0
            target_lost = observation.lost
        coasting = 0 < rejected_in_a_row <= MAX_HELD_OUTLIERS or (observation.status == ObservationStatus.DROPPED and not target_lost)
        estimate = None
        fresh = predicted = False
        if state_filter is not None:
            if observation.status == ObservationStatus.OK:
                fresh = state_filter.correct(observation.measurement, observation.residual, dt) != FilterOutcome.GATED
            estimate = state_filter.estimate(list(unseen_commands), dt, dhat, previous)
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
        v_c, w_c, saturated = limits.apply(v_cmd, w_cmd, previous, dt)
        if fresh and output is not None and state_filter.settled and not saturated:
            # (31) assumes the robot executed (29)-(30): a clipped command would wind dhat up.
            controller.adapt(output, dt)
        yield StepRecord(
            t=t, pose=np.array(pose), observation=observation, desired=desired, output=output,
            v_c=v_c, w_c=w_c, saturated=saturated, dhat=dhat, target_lost=target_lost, estimate=estimate,
        )
        previous = (v_c, w_c)
        if state_filter is not None:
            # The filter's state is at the time its last frame was taken: it moves on with
            # the command sent then, and the later ones wait (latency).
            unseen_commands.append(previous)
            if len(unseen_commands) > latency_steps:
                state_filter.predict(*unseen_commands.popleft(), dt, controller.dhat)
        pose = integrate_unicycle(pose, v_c, w_c, dt)


_DESIRED_FIELDS = ("theta_d", "x_hd1", "x_hd2", "theta_d_dot", "x_hd1_dot", "x_hd2_dot")


@dataclass
class Simulation:
    """Everything a closed-loop run needs.

    Attributes
    ----------
    scene : Scene
    camera : SimulatedCamera
    trajectory : TimeScaledTrajectory
    controller : AdaptiveTrackingController
    start_pose : ndarray, shape (3,)
        ``(x, y, phi)`` (m, m, rad) in W.
    dt, duration : float
        Control period and run length (s).
    limits : ActuatorLimits
    latency : int
        Measurement latency (frames).
    state_filter : ServoStateFilter or None
    """

    scene: Scene
    camera: SimulatedCamera
    trajectory: TimeScaledTrajectory
    controller: AdaptiveTrackingController
    start_pose: np.ndarray
    dt: float
    duration: float
    limits: ActuatorLimits
    latency: int = 0
    state_filter: ServoStateFilter | None = None

    @property
    def steps(self) -> int:
        return int(round(self.duration / self.dt))

    def run(self) -> Iterator[StepRecord]:
        """The closed loop's step records (a generator): sense, control, limits, move."""
        return run_closed_loop(
            self.camera.observe, self.trajectory, self.controller, self.start_pose, self.dt, self.duration,
            self.limits, self.latency, self.state_filter,
        )
