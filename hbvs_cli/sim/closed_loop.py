"""A closed-loop run of ``repeat --sim``, set up and ready to step.

The loop itself (sense, filter, control, limits, move) is
:func:`hbvs_cli.core.simulator.run_closed_loop`; this holds what it runs on: the scene, the
simulated camera, the time-scaled trajectory and the controller.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import numpy as np

from ..core.controller import AdaptiveTrackingController
from ..core.simulator import ActuatorLimits, StepRecord, run_closed_loop
from ..core.state_filter import ServoStateFilter
from ..core.trajectory import TimeScaledTrajectory
from .camera import SimulatedCamera
from .scene import Scene


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
