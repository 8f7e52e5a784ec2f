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
from ..core.estimation import Observation
from ..core.simulator import NOT_YET, ActuatorLimits, ServoStep, StepRecord
from ..core.state_filter import ServoStateFilter
from ..core.trajectory import DesiredTrajectory, TimeScaledTrajectory
from ..core.unicycle import integrate_unicycle
from ..errors import InvalidValueError
from .simulated_camera import SimulatedCamera
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
    servo = ServoStep(controller, limits, latency_steps, state_filter)
    for k in range(steps):
        t = k * dt
        pending.append(sense(np.array(pose), t))
        observation = pending.popleft() if len(pending) > latency_steps else NOT_YET
        desired = DesiredState(*(column[k] for column in columns))
        record = servo.decide(t, np.array(pose), observation, desired, dt)
        yield record
        servo.sent(dt)
        pose = integrate_unicycle(pose, record.v_c, record.w_c, dt)


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
