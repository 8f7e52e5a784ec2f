"""``hbvs repeat`` on a route file (issue 47): segment by segment, each with its own F*_i, n*_i, gains and state
filter, dhat (31) carried over by the transition's rho at each switch. ``--sim`` runs
:func:`~hbvs_cli.sim.route_loop.run_route`; ``--live`` and ``--replay`` switch as it does (:class:`RouteSight`).
V (36) is logged against each segment's true d*_i where the route was simulated."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Callable

import numpy as np

from ..core.camera import normalized_to_pixels
from ..core.control_settings import FILTER_EKF, ControllerGains
from ..core.estimation import Observation, ObservationStatus, PlanarPoseEstimator
from ..core.fit_model import FitModel
from ..core.frames import rotation_z
from ..core.gains import noise_from_residual
from ..core.homography import transfer_points
from ..core.laws import gains_for_law, make_controller
from ..core.route import view_spans
from ..core.state_filter import ServoStateFilter
from ..core.trajectory import TimeScaledTrajectory
from ..errors import RecordingError
from ..io.fit_file import FitFile
from ..io.images import decode_image
from ..io.messages import LOG_INFO
from ..io.route_file import RouteFile, route_of
from ..perception.target_kinds import target_kind
from ..perception.tracked import detector_from_model, estimator_from_model
from ..settings.commands import RepeatOptions
from ..sim.route_loop import SWITCH_FRACTION, RouteTrajectory, SegmentFilters, SegmentSwitch, switch_times
from ..sim.route_world import MIN_SPAN_PX, RouteWorld, recorded_route
from ..sim.scene import point_identity
from .frame_decoding import fit_template_image
from .live import TargetSight


def taught_pose_at(taught: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The taught pose (K, 3) at times ``t`` (s), interpolated in ``taught`` (F, 4: t, x, y, phi; phi unwrapped)."""
    columns = (taught[:, 1], taught[:, 2], np.unwrap(taught[:, 3]))
    return np.column_stack([np.interp(t, taught[:, 0], column) for column in columns])


def segment_truths(route: RouteWorld, plan: RouteFile) -> tuple[list[float], list[np.ndarray]]:
    """Each segment's true d*_i (m) from the taught pose of its F*_i (7), and its target points' order in its fit."""
    depths, orders = [], []
    for segment, reference, model in zip(plan.segments, plan.references, plan.models):
        world, local = route.worlds[segment.target], route.local_pose(segment.target, plan.taught_poses[reference, 1:])
        depths.append(float(world.reference_geometry(local)[2]))
        orders.append(point_identity(world.pixels(local), model.reference_pixels))
    return depths, orders


def segment_gains(settings: Any, plan: RouteFile) -> list[ControllerGains]:
    """Each segment's gains: its fit's suggestion, unless the options or the config set the first's otherwise."""
    suggested = [gains_for_law(model.suggested_gains(), settings.law) if model.suggested_gains() is not None else settings.gains
                 for model in plan.models]
    return suggested if settings.gains == suggested[0] else [settings.gains] * len(plan.models)


def planned_switches(plan: RouteFile, fraction: float = SWITCH_FRACTION) -> np.ndarray:
    """The taught instant of each switch (s), ``fraction`` of the way through each overlap."""
    frames = np.arange(plan.segments[-1].last + 1) * plan.models[0].taught_frame_interval()
    return switch_times(plan, frames, fraction)


def route_metadata(plan: RouteFile, switches: np.ndarray, depths: list[float | None]) -> dict[str, Any]:
    """The run's ``route`` record: the planned switches (s), each segment's target, kind and true d*_i (m), and rho."""
    return {"switch_times": switches.tolist(), "targets": [s.target for s in plan.segments],
            "target_kinds": [m.target_kind for m in plan.models], "d_true": depths,
            "depth_ratios": [tr.depth_ratio for tr in plan.transitions]}


class SwitchLog:
    """A repeat's step ``log`` that records each switch before the step after it: an event, and V (36) from then on
    against the new segment's d*_i (``depths``) and gains."""

    def __init__(self, log: Any, switch: SegmentSwitch, plan: RouteFile, depths: list[float | None], settings: Any) -> None:
        self.log, self.switch, self.plan, self.depths, self.settings = log, switch, plan, depths, settings
        self.logged = 0
        log.d_true = depths[0]

    def step(self, record: Any) -> None:
        while self.logged < len(self.switch.switches):
            when, segment, before, after = self.switch.switches[self.logged]
            self.log.d_true, self.log.settings = self.depths[segment], replace(self.settings, gains=self.switch.gains[segment])
            self.log.event(when, LOG_INFO, f"segment {segment + 1} (target {self.plan.segments[segment].target + 1}, "
                           f"{self.plan.models[segment].target_kind}): dhat {before:.3f} -> {after:.3f} m by rho {after / before:.4f}")
            self.logged += 1
            self.log.run.route_switches([made[0] for made in self.switch.switches[:self.logged]])
        self.log.step(record)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.__dict__["log"], name)


def desired_pixels(model: FitModel, desired: Any) -> np.ndarray:
    """Where the target points should be in the image now: m_d = H_d m* (13)."""
    H_d = rotation_z(float(desired.theta_d)) + np.outer([float(desired.x_hd1), float(desired.x_hd2), 0.0], model.normal)
    return normalized_to_pixels(model.camera, transfer_points(H_d, model.m_ref))


class RouteSight(SegmentSwitch):
    """What ``--live`` and ``--replay`` see along a route (:class:`~.live.TargetSight`'s methods): the segment in
    force, measured against its F*_i; when the next one's detector looks, and when it takes over: docs/routes.md,
    "Repeat" (a robot off its path sees a target leave sooner than planned)."""

    def __init__(self, detectors: list[Any], estimators: list[Any], trajectory: RouteTrajectory, plan: RouteFile,
                 controller: Any, gains: list[ControllerGains]) -> None:
        super().__init__(plan.transitions, controller, gains, trajectory)
        self.detectors, self.estimators, self.models = detectors, estimators, plan.models
        #: The segments whose detector has looked already (the first from the fit's first view).
        self.looked = 1
        #: The planned switches in run time (s); the trajectory's switches not made yet lie at infinity.
        self.planned = trajectory.run_time(planned_switches(plan))
        #: Where each overlap begins, in run time (s): from there a lost target hands over at once.
        self.overlaps = trajectory.run_time(planned_switches(plan, 0.0))
        self.t_start, self.t_end = trajectory.t_start, trajectory.t_end
        self.colour = any(model.detector.contrast == "colour" for model in plan.models)

    def observe(self, image: np.ndarray, t: float) -> Observation:
        last = self.active + 1 == len(self.detectors)
        if not last and t >= self.planned[self.active] and (switched := self._look_ahead(image, t)) is not None:
            return switched
        observation = self._measure(self.active, image)
        if (not last and self.planned[self.active] > t >= self.overlaps[self.active]
                and observation.status != ObservationStatus.OK and (switched := self._look_ahead(image, t)) is not None):
            return switched
        return observation

    def _look_ahead(self, image: np.ndarray, t: float) -> Observation | None:
        """The next segment's target measured, and the switch made, if it is seen well; else None."""
        ahead = self.active + 1
        if self.looked == ahead:  # first looked for where the robot on its track would see it
            desired = self.models[ahead].trajectory.evaluate(float(self.route_trajectory.route_time(t)))
            self.detectors[ahead].initial_prediction = desired_pixels(self.models[ahead], desired)
            self.looked += 1
        observation = self._measure(ahead, image)
        if observation.status != ObservationStatus.OK or view_spans(observation.pixels[None])[0] < MIN_SPAN_PX:
            return None
        self.route_trajectory.switches[self.active] = self.route_trajectory.route_time(t)
        self.advance(t)
        return observation

    def _measure(self, segment: int, image: np.ndarray) -> Observation:
        return self.estimators[segment].from_pixels(self.detectors[segment].detect(image))

    def evaluate(self, t: float) -> Any:
        """The segment in force's desired signals, each switch's discrepancy fading out, as ``--sim``'s."""
        return self.route_trajectory.blended(self.route_trajectory.evaluate(t), t)


@dataclass
class Tracking:
    """What ``--live`` and ``--replay`` servo with; ``step_log(log)``: the log each step goes to."""

    sight: Any
    controller: Any
    state_filter: Any
    metadata: dict[str, Any] = field(default_factory=dict)
    step_log: Callable[[Any], Any] = lambda log: log


#: With the state filter on, the fixed residual gate only catches gross errors (px).
COARSE_RESIDUAL_GATE_PX = 3.0


def make_state_filter(settings: Any, model: FitModel, estimator: PlanarPoseEstimator) -> ServoStateFilter | None:
    """The state filter ``--filter`` asks for (None for ``none``), its noise from the fit's residual (docs/method.md, "State filter")."""
    if settings.state_filter != FILTER_EKF:
        return None
    estimator.residual_gate = max(estimator.residual_gate, COARSE_RESIDUAL_GATE_PX / model.camera.mean_focal)
    return ServoStateFilter(model.m_ref, model.normal, detector_noise(model))


def detector_noise(model: FitModel) -> float:
    """Per-coordinate noise of the fit's detector on the taught images (normalised units)."""
    if not math.isfinite(model.residual_px.rms):
        return 0.0
    return noise_from_residual(model.residual_px.rms, model.m_ref.shape[0]) / model.camera.mean_focal


def make_tracking(options: RepeatOptions, settings: Any, fit: FitFile, filtered: bool) -> Tracking:
    """What ``--live`` (``filtered``: with ``--filter``'s state filter, one per segment of a route) and ``--replay``
    servo with, one target's or a route's."""
    if fit.route_record is None:
        model = fit.model
        estimator = estimator_from_model(model)
        detector = detector_from_model(model, fit_template_image(fit), seed=options.seed)
        state_filter = make_state_filter(settings, model, estimator) if filtered else None
        sight = TargetSight(detector, estimator, TimeScaledTrajectory(model.trajectory, settings.speed))
        return Tracking(sight, make_controller(settings.law, settings.gains, settings.dhat0), state_filter)
    plan = route_of(fit, str(options.input))
    models = plan.models
    gains = segment_gains(settings, plan)
    controller = make_controller(settings.law, gains[0], settings.dhat0)
    estimators = [estimator_from_model(model, converge=True) for model in models]
    trajectory = RouteTrajectory([model.trajectory for model in models], np.full(len(models) - 1, np.inf), speed=settings.speed)
    detectors = []
    for number, model in enumerate(models):
        try:
            detectors.append(detector_from_model(model, _template(plan, number), seed=options.seed))
        except RecordingError as exc:
            raise RecordingError(f"{options.input}: segment {number + 1}: {exc} (fitted before routes kept them: fit it again)") from None
    sight = RouteSight(detectors, estimators, trajectory, plan, controller, gains)
    if filtered and settings.state_filter == FILTER_EKF:
        sight.filters = SegmentFilters([make_state_filter(settings, model, estimator) for model, estimator in zip(models, estimators)])
    depths = ([None] * len(models) if plan.world is None or plan.taught_poses is None
              else segment_truths(recorded_route(plan.world, models[0].camera), plan)[0])
    return Tracking(sight, controller, sight.filters, {"route": route_metadata(plan, sight.planned, depths)},
                    lambda log: SwitchLog(log, sight, plan, depths, settings))


#: What a segment's template keeps around its target's points (px): the alignment's smoothing reaches 4 sigma beyond them.
TEMPLATE_MARGIN_PX = 16


def _template(plan: RouteFile, segment: int) -> np.ndarray | None:
    """Segment ``segment``'s detector template, for a kind that uses one, painted its median level beyond
    :data:`TEMPLATE_MARGIN_PX` around its target: else the route's other targets in it would be matched."""
    data = plan.templates[segment]
    spec = plan.models[segment].detector
    if data is None or not target_kind(spec.kind).uses_template:
        return None
    image = decode_image(data, f"segment {segment + 1}'s template image")
    if spec.template_pixels is None:
        return image
    low = np.maximum(np.floor(spec.template_pixels.min(axis=0)).astype(int) - TEMPLATE_MARGIN_PX, 0)
    high = np.ceil(spec.template_pixels.max(axis=0)).astype(int) + TEMPLATE_MARGIN_PX + 1
    kept = np.full(image.shape, np.median(image), dtype=image.dtype)
    kept[low[1]:high[1], low[0]:high[0]] = image[low[1]:high[1], low[0]:high[0]]
    return kept
