"""``repeat --sim`` along a route (issue 47; docs/routes.md, "Repeat"): the paper's controller segment by segment
in the one loop (:meth:`~hbvs_cli.sim.closed_loop.SimulatedRobot.run`), segment k against its own F*_k (Remark 1,
(14)); at a switch dhat (31) is carried over (:class:`SegmentSwitch`) and nothing the law sees jumps
(:meth:`RouteTrajectory.hand_over`, :class:`SegmentFilters`), (36) holding per segment."""

from __future__ import annotations

from dataclasses import fields, replace
from typing import Any, Iterator, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..core.control_settings import ControllerGains
from ..core.controller import AdaptiveTrackingController, DesiredState, Measurement
from ..core.estimation import Observation, ObservationStatus, PlanarPoseEstimator
from ..core.route import RouteFit, Transition
from ..core.servo_loop import ServoInput
from ..core.simulator import ActuatorLimits, StepRecord
from ..core.state_filter import FilterEstimate, FilterOutcome, ServoStateFilter
from ..core.trajectory import DesiredTrajectory
from ..errors import InvalidValueError
from .closed_loop import SimulatedRobot
from .route_world import RouteWorld


#: Where in an overlap a repeat switches (0: as soon as the next target is seen well, 1: as the
#: last one leaves): late, the next target large (bench/route_corridor.py, before the
#: hand-over of the filter: 8 of 10 seeds within 2 cm at 0.9, 5 at 0.5).
SWITCH_FRACTION = 0.9


def switch_times(fitted: RouteFit, t: ArrayLike, fraction: float = SWITCH_FRACTION) -> NDArray[np.float64]:
    """The taught instant of each switch (s): ``fraction`` of the way through each overlap,
    late enough that the next target looks large, early enough that the one being left is
    still inside the view for a robot off its taught path."""
    t = np.asarray(t, dtype=float)
    return np.array([(1.0 - fraction) * t[segment.first] + fraction * t[segment.overlap_last] for segment in fitted.segments[1:]])


#: Seconds over which a switch's discrepancy between the segments' desired signals fades out.
SWITCH_FADE_S = 3.0


def fading(tau: float) -> float:
    """The share left of what a switch fades out, the fraction ``tau`` (0-1) into its fade:
    ``1 - 3 tau^2 + 2 tau^3``, from 1 to 0 with zero slope at both ends (C1)."""
    return 1.0 - 3.0 * tau**2 + 2.0 * tau**3


class RouteTrajectory:
    """The desired signals of a route: segment k's (against its F*_k) from switch k - 1 to
    switch k (:meth:`evaluate`); :meth:`hand_over` and :meth:`blended` make the law's error
    continuous across a switch."""

    def __init__(self, trajectories: Sequence[DesiredTrajectory], switches: ArrayLike, fade: float = SWITCH_FADE_S,
                 speed: float = 1.0) -> None:
        if not np.isfinite(speed) or speed <= 0.0:
            raise InvalidValueError(f"--speed must be a positive number, got {speed}")
        self.trajectories = list(trajectories)
        #: The switches in the route's (taught) time, s.
        self.switches = np.asarray(switches, dtype=float)
        #: ``speed`` times the taught pace: run time t is the route's ``start + speed t``.
        self.speed, self.start = float(speed), float(self.trajectories[0].t_start)
        self.t_start = 0.0
        self.t_end = (float(self.trajectories[-1].t_end) - self.start) / self.speed
        self.fade = fade
        #: Per switch made: its time (s), its fade's length (s) and the discrepancy faded out
        #: (DesiredState's fields: theta_d, x_hd, their rates).
        self.fades: list[tuple[float, float, NDArray[np.float64]]] = []

    def route_time(self, t: ArrayLike) -> NDArray[np.float64]:
        """The route's (taught) time (s) at run time ``t`` (s)."""
        return self.start + self.speed * np.asarray(t, dtype=float)

    def run_time(self, route_t: ArrayLike) -> NDArray[np.float64]:
        """The run time (s) at the route's time ``route_t`` (s)."""
        return (np.asarray(route_t, dtype=float) - self.start) / self.speed

    def segment_at(self, t: ArrayLike) -> NDArray[np.intp]:
        """The segment in force at run times ``t`` (s)."""
        return np.searchsorted(self.switches, self.route_time(t), side="right")

    def evaluate(self, t: ArrayLike) -> DesiredState:
        """The desired signals at run times ``t`` (s), their rates per second of the run."""
        t = np.asarray(t, dtype=float)
        flat = np.atleast_1d(t)
        segment = self.segment_at(flat)
        columns = {field.name: np.empty(flat.shape) for field in fields(DesiredState)}
        for index, trajectory in enumerate(self.trajectories):
            chosen = segment == index
            if np.any(chosen):
                state = trajectory.evaluate(self.route_time(flat[chosen]))
                for name, column in columns.items():
                    column[chosen] = getattr(state, name) * (self.speed if name.endswith("_dot") else 1.0)
        values = [column.reshape(t.shape) for column in columns.values()]
        return DesiredState(*(float(value) if value.ndim == 0 else value for value in values))

    def fade_after(self, segment: int, t: float) -> float:
        """How long (s of the run) a switch to ``segment`` at run time ``t`` (s) fades out its
        discrepancy: :attr:`fade` s of the route, cut short by the next switch; the state
        filter's fade (:meth:`SegmentFilters.switch`) runs on this same clock."""
        ends = self.switches[segment:]
        return min(self.fade, (ends[0] if ends.size else np.inf) - float(self.route_time(t))) / self.speed

    def hand_over(self, segment: int, t: float, transition: Transition, before: ArrayLike | None = None,
                  after: ArrayLike | None = None) -> None:
        """The switch to ``segment`` at run time ``t`` (s): F's estimate (theta, x_h1, x_h2) the law saw
        against F*_{k-1}, ``before`` (none: the desired state), and the one it will see against
        F*_k, ``after`` (none: ``before`` carried by ``transition``,
        :meth:`~hbvs_cli.core.route.Transition.in_next`; :meth:`SegmentFilters.switch`'s). The
        discrepancy it stores, faded out by :meth:`blended`, keeps e1, e3 (19) and ebar2 (27),
        V's (36) terms, what they were: it holds the two fits' and the transition's
        disagreement, and the error's new scale (d*_k) and lever (F*_k's origin)."""
        length = self.fade_after(segment, t) * self.speed
        t = float(self.route_time(t))  # the discrepancy and its fade kept in the route's time
        old, new = self.trajectories[segment - 1].evaluate(t), self.trajectories[segment].evaluate(t)
        desired = np.array((old.theta_d, old.x_hd1, old.x_hd2), dtype=float)
        before = desired if before is None else np.asarray(before, dtype=float)
        if after is None:
            theta, x_h, _ = transition.in_next(before[0], before[1:])
            after = np.array((theta, *x_h))
        e3, e1, e2 = before - desired  # (theta, x_h1, x_h2) order
        theta_d, x_hd1 = after[0] - e3, after[1] - e1
        x_hd2 = after[2] - (e2 - desired[1] * e3) - x_hd1 * e3
        # The old desired rates in F*_k: the time derivative of in_next's x_h.
        lever = transition.in_next(desired[0], desired[1:])[2]
        rates = np.array((old.x_hd1_dot, old.x_hd2_dot)) / transition.depth_ratio + lever * old.theta_d_dot
        carried = np.array((theta_d, x_hd1, x_hd2, old.theta_d_dot, *rates), dtype=float)
        discrepancy = carried - [float(getattr(new, field.name)) for field in fields(DesiredState)]
        self.fades.append((t, length, discrepancy))

    def blended(self, desired: DesiredState, t: float) -> DesiredState:
        """``desired`` (this route's at run time ``t``, s) plus what is left of each switch's
        discrepancy (:func:`fading`), its rate (per second of the run) added to the desired rates."""
        values = np.array([getattr(desired, field.name) for field in fields(DesiredState)], dtype=float)
        route_t = float(self.route_time(t))
        for start, length, discrepancy in self.fades:
            tau = (route_t - start) / length
            if 0.0 <= tau < 1.0:
                values[:3] += fading(tau) * discrepancy[:3]
                values[3:] += self.speed * (fading(tau) * discrepancy[3:] + 6.0 * (tau**2 - tau) / length * discrepancy[:3])
        return DesiredState(*values.tolist())


class RouteRobot(SimulatedRobot):
    """The simulated robot along a route: its frames' desired states :meth:`RouteTrajectory.blended`
    (each sensed, so each switch made, before its desired state is handed to the law)."""

    def __iter__(self) -> Iterator[ServoInput]:
        for step in super().__iter__():
            yield replace(step, desired=self.trajectory.blended(step.desired, step.t))


class SegmentSwitch:
    """The switches of a route's repeat (every mode's): at each, the controller's dhat (and the
    floor its projection keeps, from dhat0) is carried over by the transition's rho, its gains
    become the segment's (``gains``, one per segment, if given) and so does the state filter
    (:attr:`filters`, if set). ``switches`` logs ``(t, segment, dhat before, after)``."""

    def __init__(self, transitions: Sequence[Transition], controller: AdaptiveTrackingController,
                 gains: Sequence[ControllerGains] | None, route_trajectory: RouteTrajectory) -> None:
        self.transitions, self.controller, self.gains = list(transitions), controller, gains
        #: The desired signals each switch is handed over in (:meth:`RouteTrajectory.hand_over`).
        self.route_trajectory = route_trajectory
        self.active = 0
        self.switches: list[tuple[float, int, float, float]] = []
        #: One state filter per segment, when run with filters (:func:`run_route`).
        self.filters: SegmentFilters | None = None

    def advance(self, t: float) -> None:
        """Switch to the next segment at run time ``t`` (s): the state filter goes on from the
        last one's estimate, and the desired signals are handed over from it."""
        transition = self.transitions[self.active]
        before = self.controller.dhat
        self.controller.dhat = transition.carried_depth(before)
        self.controller.dhat0 = transition.carried_depth(self.controller.dhat0)
        self.active += 1
        if self.gains is not None:
            self.controller.gains = self.gains[self.active]
        fade = self.route_trajectory.fade_after(self.active, t)
        estimates = None if self.filters is None else self.filters.switch(self.active, self.controller.dhat, transition, fade)
        self.route_trajectory.hand_over(self.active, t, transition, *(estimates or ()))
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
        super().__init__(fitted.transitions, controller, gains, trajectory)
        self.route, self.fitted, self.orders = route, fitted, orders
        self.estimators = [PlanarPoseEstimator(route.camera, fit.m_ref, fit.normal, converge=True) for fit in fitted.fits]
        self.pixel_noise = pixel_noise
        self.rng = np.random.default_rng(seed)

    def observe(self, pose: NDArray[np.float64], t: float) -> Observation:
        segment = int(self.route_trajectory.segment_at(t))
        while self.active < segment:
            self.advance(t)
        # The active segment's target seen from ``pose``, through its estimator.
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
              filter_noise: Sequence[float] | None = None, orders: Sequence[NDArray[np.intp]] | None = None,
              speed: float = 1.0) -> tuple[RouteCamera, Iterator[StepRecord]]:
    """The closed loop along ``route`` from ``start_pose`` (x, y, phi in its frame R), one
    :class:`~hbvs_cli.core.simulator.StepRecord` per period ``dt`` (s) for ``duration`` (s);
    the camera keeps the log of the switches. ``filter_noise`` (normalised units, one per
    segment): a state filter per segment, each going on from the last one's estimate
    (:meth:`SegmentFilters.switch`). ``orders``: as :class:`RouteCamera` takes them.
    ``speed``: times the taught pace (``switches`` stay in the route's time, ``duration`` is the run's)."""
    trajectory = RouteTrajectory([fit.trajectory for fit in fitted.fits], switches, speed=speed)
    camera = RouteCamera(route, fitted, trajectory, controller, pixel_noise, seed, gains, orders)
    if gains is not None:
        controller.gains = gains[0]
    if filter_noise is not None:
        camera.filters = SegmentFilters([ServoStateFilter(fit.m_ref, fit.normal, noise) for fit, noise in zip(fitted.fits, filter_noise)])
    robot = RouteRobot(camera.observe, trajectory, start_pose, dt, duration)
    return camera, robot.run(controller, limits or ActuatorLimits(), camera.filters)


class SegmentFilters:
    """The state filter of the segment in force: one :class:`~hbvs_cli.core.state_filter.ServoStateFilter`
    per segment (each estimates against its own F*), the loop seeing the active one. During
    a switch's fade (``fade`` s of the run) the law's estimate leaves out the :func:`fading` share of what the
    new target's frames corrected of the carried one, as :meth:`RouteTrajectory.blended` fades the
    desired signals' discrepancy (docs/routes.md, "Repeat")."""

    def __init__(self, filters: Sequence[ServoStateFilter]) -> None:
        self.filters = list(filters)
        self.active = 0
        #: The last switch's fade (s of the run).
        self.fade = SWITCH_FADE_S
        #: Seconds since the last switch, and the corrections (theta, x_h1, x_h2) fused since.
        self.since, self.corrections = np.inf, np.zeros(3)

    def switch(self, segment: int, dhat: float, transition: Transition,
               fade: float) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        """Hand the loop segment ``segment``'s filter, which goes on from the last one's estimate
        carried over by ``transition`` (:meth:`~hbvs_cli.core.route.Transition.carried_state`),
        or, if that one has none, starts its depth at ``dhat`` (m): at a switch the next target
        is still small and far, and a restart from its first frames would jump. The last
        one's (theta, x_h1, x_h2) and the carried ones, or None."""
        before, self.active = self.filters[self.active], segment
        if before.full_state is None:
            self.filters[segment].expect_depth(dhat)
            return None
        state, covariance = before.full_state
        carried, spread = transition.carried_state(state, covariance)
        reference = transition.carried_state(state, np.zeros((4, 4)))[1]
        self.filters[segment].take_over(carried, spread, before, np.sqrt(np.maximum(np.diag(spread - reference)[:3], 0.0)))
        self.since, self.corrections, self.fade = 0.0, np.zeros(3), fade
        return state[:3], carried[:3]

    def correct(self, measured: Measurement, residual: float, dt: float) -> FilterOutcome:
        """The active filter's :meth:`~hbvs_cli.core.state_filter.ServoStateFilter.correct`, what it moved kept while fading."""
        active = self.filters[self.active]
        before = active.state
        outcome = active.correct(measured, residual, dt)
        if before is not None and self.since < self.fade:
            self.corrections += active.state - before
        return outcome

    def predict(self, v: float, w: float, dt: float) -> None:
        """The active filter's prediction; the kept corrections turn with the camera, as x_h does (5), (23)."""
        self.filters[self.active].predict(v, w, dt)
        c, s = np.cos(w * dt), np.sin(w * dt)
        self.corrections[1:] = c * self.corrections[1] + s * self.corrections[2], -s * self.corrections[1] + c * self.corrections[2]
        self.since += dt

    def estimate(self, commands: Any, dt: float) -> FilterEstimate | None:
        """The active filter's estimate for the law, less what is left of the corrections since the switch."""
        estimate = self.filters[self.active].estimate(commands, dt)
        if estimate is None or self.since >= self.fade:
            return estimate
        measured = estimate.measurement
        theta, x_h1, x_h2 = (measured.theta, measured.x_h1, measured.x_h2) - fading(self.since / self.fade) * self.corrections
        return replace(estimate, measurement=Measurement(theta=theta, x_h1=x_h1, x_h2=x_h2))

    def __getattr__(self, name: str) -> Any:
        return getattr(self.filters[self.__dict__["active"]], name)
