"""The closed loop of ``repeat --sim``, one camera frame at a time: a sensing function
measures the pose, :class:`~hbvs_cli.core.simulator.ServoStep` answers with (v_c, w_c)
(losses and drops as it says), and the unicycle integrates them exactly over ``dt``.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, fields
from typing import Callable, Iterator

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..core.controller import AdaptiveTrackingController, DesiredState
from ..core.estimation import Observation
from ..core.servo_loop import ServoInput, run_servo
from ..core.simulator import NOT_YET, ActuatorLimits, ServoStep, StepRecord
from ..core.state_filter import ServoStateFilter
from ..core.trajectory import DesiredTrajectory, TimeScaledTrajectory
from ..core.unicycle import integrate_unicycle
from .simulated_camera import SimulatedCamera
from .scene import Scene

SenseFunction = Callable[[NDArray[np.float64], float], Observation]


class SimulatedRobot:
    """The source of ``--sim`` (:class:`~hbvs_cli.core.servo_loop.ServoSource`): a unicycle that
    ``sense(pose, t)`` observes every ``dt`` (s) for ``duration`` (s), each observation acted on
    ``latency_steps`` periods late (none before), and that integrates each command exactly."""

    def __init__(self, sense: SenseFunction, trajectory: DesiredTrajectory, start_pose: ArrayLike, dt: float, duration: float,
                 latency_steps: int = 0) -> None:
        # dt is 1 / --rate and latency_steps --latency, both checked as they were read (repeat's resolve_settings).
        self.sense, self.trajectory, self.dt, self.latency_steps = sense, trajectory, dt, latency_steps
        self.pose = tuple(float(v) for v in np.asarray(start_pose, dtype=float))
        self.steps = int(round(duration / dt))

    def __iter__(self) -> Iterator[ServoInput]:
        dt = self.dt
        # The control instants are known in advance: one vectorised evaluation.
        schedule = self.trajectory.evaluate(np.arange(self.steps) * dt)
        columns = [np.atleast_1d(np.asarray(getattr(schedule, field.name), dtype=float)).tolist() for field in fields(DesiredState)]
        pending: deque[Observation] = deque()
        for k in range(self.steps):
            t = k * dt
            pending.append(self.sense(np.array(self.pose), t))
            observation = pending.popleft() if len(pending) > self.latency_steps else NOT_YET
            yield ServoInput(t, dt, observation, DesiredState(*(column[k] for column in columns)), np.array(self.pose))

    def act(self, record: StepRecord) -> None:
        self.pose = integrate_unicycle(self.pose, record.v_c, record.w_c, self.dt)

    def run(self, controller: AdaptiveTrackingController, limits: ActuatorLimits,
            state_filter: ServoStateFilter | None = None) -> Iterator[StepRecord]:
        """The closed loop's step records (a generator): sense, control, ``limits``, move; the law acts on the
        observation ``latency_steps`` periods old (holding still before), or on the ``state_filter``'s
        estimate (docs/method.md, "State filter"), and updates the controller's dhat in place."""
        return run_servo(self, ServoStep(controller, limits, self.latency_steps, state_filter))


@dataclass
class Simulation:
    """Everything a closed-loop run needs: ``start_pose`` (x, y, phi) in W, ``dt`` and
    ``duration`` (s), ``latency`` (frames), and the objects the loop runs on."""

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
        """The closed loop's step records (a generator): :meth:`SimulatedRobot.run`."""
        robot = SimulatedRobot(self.camera.observe, self.trajectory, self.start_pose, self.dt, self.duration,
                               self.latency)
        return robot.run(self.controller, self.limits, self.state_filter)
