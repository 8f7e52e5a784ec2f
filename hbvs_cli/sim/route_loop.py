"""``repeat --sim`` along a route (issue 47): the paper's controller segment by segment, in the
one loop (:func:`~hbvs_cli.sim.closed_loop.run_closed_loop`, so
:func:`~hbvs_cli.core.servo_loop.run_servo`).

Segment k runs against its own F*_k: its desired signals (Remark 1) and its target's
measurement (14) through its own n*_k. At the switch to k + 1 (a taught instant late in the
overlap, where both targets were seen) the desired signals and the measurement change
reference together, and the adaptive estimate (31) carries over as ``rho_k dhat``
(:meth:`~hbvs_cli.core.route.Transition.carried_depth`), so the law goes on with the depth of
the new segment. The Lyapunov function (36) holds per segment.
"""

from __future__ import annotations

from dataclasses import fields
from typing import Any, Iterator, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..core.control_settings import ControllerGains
from ..core.controller import AdaptiveTrackingController, DesiredState
from ..core.estimation import Observation, ObservationStatus, PlanarPoseEstimator
from ..core.route import RouteFit, Transition
from ..core.simulator import ActuatorLimits, StepRecord
from ..core.state_filter import ServoStateFilter
from ..core.trajectory import DesiredTrajectory
from .closed_loop import run_closed_loop
from .route_world import RouteWorld


#: Where in an overlap a repeat switches (0: as soon as the next target is seen well, 1: as the
#: last one leaves): late, the next target large (bench/route_corridor.py: 8 of 10 seeds within
#: 2 cm at 0.9, 5 at 0.5).
SWITCH_FRACTION = 0.9


def switch_times(fitted: RouteFit, t: ArrayLike, fraction: float = SWITCH_FRACTION) -> NDArray[np.float64]:
    """The taught instant of each switch (s): ``fraction`` of the way through each overlap,
    late enough that the next target looks large, early enough that the one being left is
    still inside the view for a robot off its taught path."""
    t = np.asarray(t, dtype=float)
    return np.array([(1.0 - fraction) * t[segment.first] + fraction * t[segment.overlap_last] for segment in fitted.segments[1:]])


class RouteTrajectory:
    """The desired signals of a route: segment k's (against its F*_k) from switch k - 1 to switch k."""

    def __init__(self, trajectories: Sequence[DesiredTrajectory], switches: ArrayLike) -> None:
        self.trajectories = list(trajectories)
        self.switches = np.asarray(switches, dtype=float)
        self.t_start = float(self.trajectories[0].t_start)
        self.t_end = float(self.trajectories[-1].t_end)

    def segment_at(self, t: ArrayLike) -> NDArray[np.intp]:
        """The segment in force at times ``t`` (s)."""
        return np.searchsorted(self.switches, np.asarray(t, dtype=float), side="right")

    def evaluate(self, t: ArrayLike) -> DesiredState:
        t = np.asarray(t, dtype=float)
        flat = np.atleast_1d(t)
        segment = self.segment_at(flat)
        columns = {field.name: np.empty(flat.shape) for field in fields(DesiredState)}
        for index, trajectory in enumerate(self.trajectories):
            chosen = segment == index
            if np.any(chosen):
                state = trajectory.evaluate(flat[chosen])
                for name, column in columns.items():
                    column[chosen] = getattr(state, name)
        values = [column.reshape(t.shape) for column in columns.values()]
        return DesiredState(*(float(value) if value.ndim == 0 else value for value in values))


class SegmentSwitch:
    """The switches of a route's repeat (every mode's): at each, the controller's dhat (and the
    floor its projection keeps, from dhat0) is carried over by the transition's rho, its gains
    become the segment's (``gains``, one per segment, if given) and so does the state filter
    (:attr:`filters`, if set). ``switches`` logs ``(t, segment, dhat before, after)``."""

    def __init__(self, transitions: Sequence[Transition], controller: AdaptiveTrackingController,
                 gains: Sequence[ControllerGains] | None = None) -> None:
        self.transitions, self.controller, self.gains = list(transitions), controller, gains
        self.active = 0
        self.switches: list[tuple[float, int, float, float]] = []
        #: One state filter per segment, when run with filters (:func:`run_route`).
        self.filters: SegmentFilters | None = None

    def advance(self, t: float) -> None:
        """Switch to the next segment at time ``t`` (s)."""
        transition = self.transitions[self.active]
        before = self.controller.dhat
        self.controller.dhat = transition.carried_depth(before)
        self.controller.dhat0 = transition.carried_depth(self.controller.dhat0)
        self.active += 1
        if self.gains is not None:
            self.controller.gains = self.gains[self.active]
        if self.filters is not None:
            self.filters.switch(self.active, self.controller.dhat)
        self.switches.append((t, self.active, before, self.controller.dhat))


class RouteCamera(SegmentSwitch):
    """What the robot sees along a route: the target of the segment in force, its exact pixels
    plus Gaussian noise (``pixel_noise`` px), measured through that segment's estimator, each
    switch made (:class:`SegmentSwitch`) at the trajectory's. ``orders``: each segment's
    permutation of its target's points into its fit's order (a detector's,
    :func:`~.scene.point_identity`; none: the world's order)."""

    def __init__(self, route: RouteWorld, fitted: RouteFit, trajectory: RouteTrajectory,
                 controller: AdaptiveTrackingController, pixel_noise: float = 0.0, seed: int = 0,
                 gains: Sequence[ControllerGains] | None = None, orders: Sequence[NDArray[np.intp]] | None = None) -> None:
        super().__init__(fitted.transitions, controller, gains)
        self.route, self.fitted, self.trajectory = route, fitted, trajectory
        self.orders = orders
        self.estimators = [PlanarPoseEstimator(route.camera, fit.m_ref, fit.normal) for fit in fitted.fits]
        self.pixel_noise = pixel_noise
        self.rng = np.random.default_rng(seed)

    def observe(self, pose: NDArray[np.float64], t: float) -> Observation:
        segment = int(self.trajectory.segment_at(t))
        while self.active < segment:
            self.advance(t)
        target = self.fitted.segments[self.active].target
        world = self.route.worlds[target]
        local = self.route.local_pose(target, pose)
        if not world.in_view(local, margin_px=0.0):
            return Observation(None, status=ObservationStatus.OCCLUDED)
        pixels = world.pixels(local) if self.orders is None else world.pixels(local)[self.orders[self.active]]
        if self.pixel_noise > 0:
            pixels = pixels + self.rng.normal(0.0, self.pixel_noise, pixels.shape)
        return self.estimators[self.active].from_pixels(pixels)


def run_route(route: RouteWorld, fitted: RouteFit, switches: ArrayLike, controller: AdaptiveTrackingController,
              start_pose: ArrayLike, dt: float, duration: float, limits: ActuatorLimits | None = None,
              pixel_noise: float = 0.0, seed: int = 0, gains: Sequence[ControllerGains] | None = None,
              filter_noise: Sequence[float] | None = None, orders: Sequence[NDArray[np.intp]] | None = None
              ) -> tuple[RouteCamera, Iterator[StepRecord]]:
    """The closed loop along ``route`` from ``start_pose`` (x, y, phi in its frame R), one
    :class:`~hbvs_cli.core.simulator.StepRecord` per period ``dt`` (s) for ``duration`` (s);
    the camera keeps the log of the switches. ``filter_noise`` (normalised units, one per
    segment): a state filter per segment, each new one started at the carried dhat, whose soft
    start fades its feedback in from the taught commands: what smooths a switch. ``orders``: as
    :class:`RouteCamera` takes them."""
    trajectory = RouteTrajectory([fit.trajectory for fit in fitted.fits], switches)
    camera = RouteCamera(route, fitted, trajectory, controller, pixel_noise, seed, gains, orders)
    if gains is not None:
        controller.gains = gains[0]
    if filter_noise is not None:
        camera.filters = SegmentFilters([ServoStateFilter(fit.m_ref, fit.normal, noise) for fit, noise in zip(fitted.fits, filter_noise)])
    return camera, run_closed_loop(camera.observe, trajectory, controller, start_pose, dt, duration, limits, state_filter=camera.filters)


class SegmentFilters:
    """The state filter of the segment in force: one :class:`~hbvs_cli.core.state_filter.ServoStateFilter`
    per segment (each estimates against its own F*), the loop seeing the active one."""

    def __init__(self, filters: Sequence[ServoStateFilter]) -> None:
        self.filters = list(filters)
        self.active = 0

    def switch(self, segment: int, dhat: float) -> None:
        """Hand the loop segment ``segment``'s filter, its depth started at ``dhat`` (m)."""
        self.active = segment
        self.filters[segment].expect_depth(dhat)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.filters[self.__dict__["active"]], name)
