"""``hbvs repeat``: track the fitted trajectory with the adaptive controller (29)-(31). ``--sim``: closed loop, a
simulated robot from the taught start plus ``--offset``; ``--replay``: open loop on a recording's frames, nothing
moves; ``--live``: closed loop with a robot (:mod:`.live`)."""

from __future__ import annotations

import math
import time
from contextlib import ExitStack
from dataclasses import asdict, dataclass, replace
from typing import IO, Any, Iterator

import numpy as np

from .. import __version__
from ..core.controller import ControllerGains, lyapunov
from ..core.depth import check_depth
from ..core.fit_model import FitModel
from ..core.frames import compose_planar_pose
from ..core.laws import gains_for_law, make_controller
from ..core.metrics import final_value
from ..core.servo_loop import ServoInput, run_servo
from ..core.simulator import ActuatorLimits, ServoStep, StepRecord
from ..core.control_settings import FILTER_EKF, GAIN_NAMES
from ..core.trajectory import TimeScaledTrajectory
from ..sim.world import World
from ..errors import InputError, TargetLostError, UsageError
from ..settings.config import load_config
from ..io.fit_file import FitFile, fit_summary_records, read_fit_file
from ..io.foxglove_scene import SIMULATION_EPOCH_NS, SceneWriter
from ..io.images import bytes_to_store
from ..io.limits import step_count
from ..io.live_view import live_writer
from ..io.mcap import McapWriter, open_output, seconds_to_ns
from ..io.messages import LOG_INFO, LOG_WARNING
from ..io.output_target import open_text_output, refuse_overwriting_inputs
from ..io.route_file import route_of
from ..io.run_file import RunWriter
from ..settings.commands import DEFAULT_GAINS, REPEAT, SIM_FAULTS, RepeatOptions
from ..io.teach_file import TeachReader
from ..perception.tracked import detector_from_model, estimator_from_model
from ..sim import CameraSettings, Scene, SimulatedCamera, Simulation, simulation_world
from ..sim.route_loop import run_route
from ..sim.route_world import recorded_route
from . import live
from .console import Console
from .frame_decoding import decoded_frames, fit_reference_image, fit_template_image
from .options import parse_interval, parse_offset, parse_pair
from .repeat_route import (SwitchLog, desired_pixels, detector_noise, make_state_filter, make_tracking, planned_switches,
                           route_metadata, segment_gains, segment_truths, taught_pose_at)

@dataclass(frozen=True)
class Settings:
    """The resolved settings of a run: defaults, then the TOML config, then the options."""

    gains: ControllerGains
    law: str
    dhat0: float
    speed: float
    limits: ActuatorLimits
    latency: int
    rate: float
    perception: str
    pixel_noise: float
    offset: tuple[float, float, float]
    lost_timeout: float
    state_filter: str = FILTER_EKF

    def as_dict(self) -> dict[str, Any]:
        offset = {"dx_m": self.offset[0], "dy_m": self.offset[1], "dtheta_deg": math.degrees(self.offset[2])}
        return asdict(self) | {"gains": self.gains.as_dict(), "offset": offset}


@dataclass
class RepeatSummary:
    steps: int
    output: str
    final_errors: dict[str, float]
    dhat: float
    stopped: bool


def _limit(value: float | None, option: str) -> float | None:
    """A limit option (a number, checked as it was read): None or inf -> unlimited (None); 0 or less is refused."""
    if value is not None and value <= 0:
        raise UsageError(f"{option} must be positive (m/s, rad/s, m/s^2), or inf for no limit; got {value!r}")
    return None if value is None or math.isinf(value) else float(value)


def resolve_settings(options: RepeatOptions, dhat0_suggested: float, taught_rate: float,
                     suggested_gains: ControllerGains | None = None) -> Settings:
    """Defaults < ``--config`` < command-line options (an option not given is None); both checked as they were read."""
    config: dict[str, Any] = load_config(options.config) if options.config is not None else {}

    def pick(name: str, fallback: Any = None) -> Any:
        return REPEAT[name].resolve(getattr(options, name), config, fallback)

    law = pick("law")
    # The fit's suggestion (from x_hd1_dot and the detector's noise) unless the user sets gains.
    defaults = suggested_gains if suggested_gains is not None else DEFAULT_GAINS
    gains = gains_for_law(ControllerGains(**{name: pick(name, getattr(defaults, name)) for name in GAIN_NAMES}), law)
    dhat0 = check_depth(float(pick("dhat0", dhat0_suggested)), "--dhat0")
    rate = float(pick("rate", taught_rate))
    if not (math.isfinite(rate) and rate > 0):
        raise UsageError(f"--rate must be positive, got {rate}")
    limits = ActuatorLimits(max_v=_limit(pick("max_v"), "--max-v"), max_w=_limit(pick("max_w"), "--max-w"),
                            max_accel=_limit(pick("max_accel"), "--max-accel"), lag_s=float(pick("base_lag")))
    return Settings(
        gains=gains, law=law, dhat0=dhat0, speed=float(pick("speed")), limits=limits, latency=int(pick("latency")), rate=rate,
        perception=str(pick("perception")), pixel_noise=float(pick("pixel_noise")), offset=parse_offset(str(pick("offset"))),
        lost_timeout=float(pick("lost_timeout")), state_filter=str(pick("state_filter")),
    )


def run_repeat(options: RepeatOptions, console: Console, fit: FitFile | None = None) -> RepeatSummary:
    """Run the repeat phase as ``options`` say; write the run file. ``fit``: ``options.input`` already read."""
    if int(options.sim) + int(options.replay is not None) + int(options.live) != 1:
        raise UsageError("choose one mode: --live (closed loop with a robot), --sim (closed loop, simulated) or --replay FILE "
                         "(open loop on a recording)")
    if options.cmd_out == "-" and options.output == "-":
        raise UsageError("--cmd-out - and -o - would both write to stdout; send one of them to a file")
    refuse_overwriting_inputs(
        [("-o", options.output), ("--cmd-out", options.cmd_out)],
        [("input", options.input), ("--replay", options.replay), ("--config", options.config), ("--calibration", options.calibration)],
    )
    if fit is None:
        fit = read_fit_file(options.input)
    settings = settings_for(options, fit.model)
    if fit.route_record is not None and options.sim:  # a route: segment by segment
        return _run_route_simulation(options, settings, fit, console)
    if options.live:
        return _run_live(options, settings, fit, console)
    if options.sim:
        return _run_simulation(options, settings, fit, console)
    return _run_replay(options, settings, fit, console)


def settings_for(options: RepeatOptions, model: FitModel) -> Settings:
    """:func:`resolve_settings` with the fit's suggestions and taught rate."""
    return resolve_settings(options, model.dhat0, 1.0 / model.taught_frame_interval(), model.suggested_gains())


class _StepLog:
    """Each step record as run file messages and a command; events when the target is lost or back, etc."""

    def __init__(self, run: RunWriter, settings: Settings, model: FitModel, d_true: float | None, cmd_stream: IO[str] | None) -> None:
        self.run, self.settings, self.model, self.d_true, self.cmd_stream = run, settings, model, d_true, cmd_stream
        self.event = run.event
        self.was_saturated = self.was_lost = self.was_dropped = False
        self.lost_reason = ""

    def step(self, record: StepRecord) -> None:
        t = record.t
        desired = record.desired
        output = record.output
        measurement = record.measurement
        errors = output.errors if output is not None else None
        V = None
        if errors is not None and self.d_true is not None:
            V = lyapunov(errors, record.dhat, self.d_true, self.settings.gains)
        # A dropped frame keeps the lost state and reason of the last frame that arrived.
        if not record.dropped:
            self.lost_reason = record.observation.status if record.lost else ""
        if record.lost and not self.was_lost:
            action = "driving on the state filter's prediction" if output is not None else "stopping"
            self.event(t, LOG_WARNING, f"target lost ({self.lost_reason}): {action}, adaptation frozen")
        elif not record.lost and self.was_lost:
            self.event(t, LOG_INFO, "target back: tracking resumed")
        self.was_lost = record.lost
        if record.dropped and not self.was_dropped:
            self.event(t, LOG_INFO, "camera frame dropped: " + ("target still lost" if record.lost else "holding the last command"))
        self.was_dropped = record.dropped
        if record.saturated and not self.was_saturated:
            self.event(t, LOG_INFO, "command saturated by the actuator limits")
        self.was_saturated = record.saturated
        # The run file's state, in its order of fields (the bytes depend on it).
        values = {
            **{name: getattr(measurement, name) if measurement else None for name in ("x_h1", "x_h2", "theta")},
            **{name: getattr(desired, name) for name in ("x_hd1", "x_hd2", "theta_d", "x_hd1_dot", "x_hd2_dot", "theta_d_dot")},
            **{name: getattr(errors, name) if errors else None for name in ("e1", "e2", "ebar2", "e3")},
            "v_c": record.v_c, "w_c": record.w_c,
            "v_law": float(output.v_c) if output is not None else None,
            "w_law": float(output.w_c) if output is not None else None,
            "saturated": bool(record.saturated),
            "dhat": float(record.dhat),
            "target_lost": bool(record.lost),
            "lost_reason": self.lost_reason if record.lost else "",
            "frame_dropped": bool(record.dropped),
            "residual": float(record.observation.residual),
            "V": V,
        }
        estimate = record.estimate
        if estimate is None:
            values |= {"filter": "", "theta_est": None, "x_h1_est": None, "x_h2_est": None,
                       "theta_std": None, "x_h1_std": None, "x_h2_std": None, "noise_px": None}
        else:
            state = estimate.measurement
            std = estimate.std.tolist()
            values |= {
                "filter": estimate.outcome,
                "theta_est": float(state.theta), "x_h1_est": float(state.x_h1), "x_h2_est": float(state.x_h2),
                "theta_std": std[0], "x_h1_std": std[1], "x_h2_std": std[2],
                "noise_px": estimate.noise * self.model.camera.mean_focal,
            }
        self.run.state(t, values)
        self.run.command(t, record.v_c, record.w_c, record.saturated)
        live.write_command(self.cmd_stream, t, record.v_c, record.w_c)


def _note_truncated(writer: McapWriter, options: RepeatOptions, fit: FitFile, console: Console, replay: TeachReader | None = None) -> None:
    """Keep an existing output when an input ended early (unless --allow-truncated); warn."""
    names = []
    if getattr(fit, "truncated", False):
        names.append("stdin" if options.input == "-" else str(options.input))
    if replay is not None and replay.truncated:
        names.append(replay.name)
    for name in names:
        writer.input_ended_early(name, options.allow_truncated)
        console.warn(f"{name} ends before its end record (the writer upstream stopped?): used what it holds")


def check_simulation_settings(settings: Settings, model: FitModel, taught_s: float | None = None) -> None:
    """The checks of a closed-loop run's settings that need the fit; ``taught_s``: the taught duration (s) of a route."""
    if not (math.isfinite(settings.speed) and settings.speed > 0):
        raise UsageError(f"--speed must be a finite positive multiple of the taught pace, got {settings.speed}")
    step_count(
        (model.trajectory.t_end - model.trajectory.t_start if taught_s is None else taught_s) / settings.speed, settings.rate,
        "the run (the taught duration over --speed, times --rate)",
    )


def prepare_simulation(options: RepeatOptions, settings: Settings, fit: FitFile) -> Simulation:
    """The world, camera, trajectory and controller of ``repeat --sim`` (no file is opened)."""
    model = fit.model
    check_simulation_settings(settings, model)
    scene = simulation_world(model, fit_reference_image(fit), options.depth, settings.speed, options.input)
    trajectory = TimeScaledTrajectory(model.trajectory, settings.speed)
    start_pose = compose_planar_pose(scene.taught_pose_at_run_time(0.0), settings.offset)
    if not scene.world.in_view(start_pose, margin_px=0.0):
        raise UsageError("the target is not in view from the start pose; use a smaller --offset")
    sensor = CameraSettings(
        perception=settings.perception, pixel_noise=settings.pixel_noise, seed=options.seed,
        occlusions=tuple(parse_interval(text, "--occlude") for text in options.occlude),
        drop_rate=options.drop_rate, outlier_rate=options.outlier_rate,
        exposure_step=None if options.exposure_step is None else parse_pair(
            options.exposure_step, "--exposure-step", "T:FACTOR", "(s, factor)", "T >= 0 and FACTOR > 0", lambda at, gain: at >= 0 and gain > 0),
        record_images=options.record_images,
    )
    detector = detector_from_model(model, fit_template_image(fit), seed=options.seed, windowed=True) if settings.perception == "images" else None
    camera = SimulatedCamera(scene, model, sensor, estimator_from_model(model), detector)
    state_filter = make_state_filter(settings, model, camera.estimator)
    return Simulation(
        scene=scene, camera=camera, trajectory=trajectory, controller=make_controller(settings.law, settings.gains, settings.dhat0),
        start_pose=start_pose, dt=1.0 / settings.rate, duration=trajectory.t_end - trajectory.t_start, limits=settings.limits,
        latency=settings.latency, state_filter=state_filter,
    )


def _run_simulation(options: RepeatOptions, settings: Settings, fit: FitFile, console: Console) -> RepeatSummary:
    model = fit.model
    simulation = prepare_simulation(options, settings, fit)
    scene, camera, controller, dt, steps = simulation.scene, simulation.camera, simulation.controller, simulation.dt, simulation.steps
    taught_poses = scene.taught_pose_at_run_time(np.arange(steps) * dt).tolist()
    tally = _Tally()
    with open_text_output(options.cmd_out, "command stream") as cmd_stream, live_writer(options.foxglove, options.foxglove_speed, console.info) as view:
        with open_output(options.output) as file_writer:
            writer = view(file_writer)
            _note_truncated(writer, options, fit, console)
            run = RunWriter(writer, _run_metadata("sim", options, settings, fit, scene.d_true, scene), model.camera, SIMULATION_EPOCH_NS)
            log = _StepLog(run, settings, model, scene.d_true, cmd_stream)
            lost = live.LostWatch(settings.lost_timeout, log)
            height = scene.world.camera_height
            scene_3d = SceneWriter(writer)
            scene_3d.start(SIMULATION_EPOCH_NS, height, scene.world, np.array(taught_poses))
            with console.progress(f"repeat (sim, {settings.law})", steps) as bar:
                for k, record in enumerate(simulation.run()):
                    log.step(record)
                    run.poses(record.t, record.pose, taught_poses[k], height)
                    scene_3d.pose(run.log_time_ns(record.t), record.pose)
                    if options.record_images:
                        label = f"t = {record.t:.2f} s" + ("  target lost" if record.lost else "")
                        run.image(record.t, *bytes_to_store(camera.image_of(record.pose)), record.observation.pixels,
                                  desired_pixels(model, record.desired), label)
                    tally.add(record, taught_poses[k])
                    bar.advance()
                    if lost.stops(record, dt):
                        break
    return _finish(console, tally, controller, options.output, settings, scene.d_true, lost.stopped)


def _run_route_simulation(options: RepeatOptions, settings: Settings, fit: FitFile, console: Console) -> RepeatSummary:
    """Repeat the route of ``fit`` in simulation (:mod:`.repeat_route`)."""
    plan = route_of(fit, str(options.input))
    if plan.world is None or plan.taught_poses is None:
        raise UsageError(f"{options.input}: a route fit without its simulated route: repeat --sim needs a simulated teach's")
    unsupported = [name for name, asked in (
        ("--latency", settings.latency > 0), ("--occlude", bool(options.occlude)), ("--drop-rate", options.drop_rate > 0),
        ("--outlier-rate", options.outlier_rate > 0), ("--exposure-step", options.exposure_step is not None),
        ("--record-images", options.record_images), ("--depth", options.depth is not None)) if asked]
    if unsupported:
        raise UsageError(f"{options.input}: repeat --sim on a route measures its targets' exact points; "
                         f"{', '.join(unsupported)} {'applies' if len(unsupported) == 1 else 'apply'} to one target's run only")
    if options.perception == "images":
        console.info("repeat --sim on a route projects its targets' points (--perception points); "
                     "robot-sim renders the route for --live")
    settings = replace(settings, perception="points")  # what the run file's settings then say
    models = plan.models
    route = recorded_route(plan.world, models[0].camera)
    depths, orders = segment_truths(route, plan)
    switches = planned_switches(plan)
    gains = segment_gains(settings, plan)
    noise = [detector_noise(model) for model in models] if settings.state_filter == FILTER_EKF else None
    controller = make_controller(settings.law, settings.gains, settings.dhat0)
    start = compose_planar_pose(plan.taught_poses[0, 1:], settings.offset)
    taught_s = float(plan.taught_poses[-1, 0]) - models[0].trajectory.t_start
    check_simulation_settings(settings, models[0], taught_s)
    dt = 1.0 / settings.rate
    duration = taught_s / settings.speed + dt
    camera, steps = run_route(route, plan, switches, controller, start, dt, duration, settings.limits,
                              settings.pixel_noise, options.seed, gains, noise, orders, settings.speed)
    metadata = _run_metadata("sim", options, settings, fit, depths[0]) | {
        "d_true": depths[-1], "route": route_metadata(plan, camera.route_trajectory.run_time(switches), depths)}
    tally = _Tally()
    with open_text_output(options.cmd_out, "command stream") as cmd_stream, open_output(options.output) as writer:
        run = RunWriter(writer, metadata, models[0].camera, SIMULATION_EPOCH_NS)
        log = SwitchLog(_StepLog(run, settings, models[0], depths[0], cmd_stream), camera, plan, depths, settings)
        lost = live.LostWatch(settings.lost_timeout, log)
        with console.progress(f"repeat (sim, route of {len(models)} segments)", int(duration / dt)) as bar:
            for record in steps:
                log.step(record)
                taught = taught_pose_at(plan.taught_poses, np.atleast_1d(camera.route_trajectory.route_time(record.t)))[0]
                run.poses(record.t, record.pose, taught, route.camera_height)
                tally.add(record, taught)
                bar.advance()
                if lost.stops(record, dt):
                    break
    return _finish(console, tally, controller, options.output, settings, depths[-1], lost.stopped)


class _Tally:
    """What the one-line summary needs, per step; its "final" errors are the report's (:func:`hbvs_cli.core.metrics.final_value`)."""

    def __init__(self) -> None:
        self.series: dict[str, list[float]] = {name: [] for name in ("t", "e1", "e2", "e3_deg", "position_m", "heading_deg")}

    def add(self, record: StepRecord, taught: list[float] | None = None) -> None:
        errors = record.output.errors if record.output is not None else None
        values = dict.fromkeys(self.series, math.nan) | {"t": record.t}
        if errors is not None:
            values.update(e1=float(errors.e1), e2=float(errors.e2), e3_deg=math.degrees(float(errors.e3)))
        if taught is not None:
            values["position_m"] = math.hypot(record.pose[0] - taught[0], record.pose[1] - taught[1])
            values["heading_deg"] = math.degrees(float(np.angle(np.exp(1j * (record.pose[2] - taught[2])))))
        for name, value in values.items():
            self.series[name].append(float(value))


def _run_metadata(mode: str, options: RepeatOptions, settings: Settings, fit: FitFile, d_true: float | None, scene: Scene | None = None) -> dict[str, Any]:
    model = fit.model
    return {
        "file_kind": "run", "hbvs_version": __version__, "mode": mode, "law": settings.law, "gains": settings.gains.as_dict(),
        "settings": settings.as_dict() | {
            "seed": options.seed, "input": str(options.input), "replay": str(options.replay) if options.replay else None,
            "faults": {name: getattr(options, name) for name in SIM_FAULTS},
            "record_images": options.record_images,
        },
        "d_true": d_true, "dhat0": settings.dhat0, "target_kind": model.target_kind,
    } | fit_summary_records(model) | ({"top_view": _top_view(scene.world)} if scene is not None else {})


def _top_view(world: World) -> dict[str, Any]:
    """The wall and the target from above (m, world frame), for the report's top view."""
    poster = world.target.poster
    ends = [poster.center + side * 0.5 * poster.width * poster.right for side in (-1.0, 1.0)]
    return {
        "wall_x": float(world.wall_x),
        "poster_y": [float(end[1]) for end in ends],
        "target_xy": [[float(x), float(y)] for x, y in world.target.points_world[:, :2]],
    }


def _finish(console: Console, tally: _Tally, controller: Any, output: str, settings: Settings, d_true: float | None,
            stopped: str | None) -> RepeatSummary:
    """The run's summary, printed; TargetLostError when the run was ``stopped`` (why)."""
    t = tally.series["t"]
    finals = {name: final_value(t, series) for name, series in tally.series.items() if t and name != "t"}
    e = {name: final for name, final in finals.items() if final is not None}
    summary = RepeatSummary(steps=len(t), output=output, final_errors=e, dhat=controller.dhat, stopped=stopped is not None)
    parts = [f"repeat: {summary.steps} steps ({settings.law})"]
    final = []
    if "e1" in e:
        final.append(f"|e1| {e['e1']:.3g}, |e2| {e['e2']:.3g}, |e3| {e['e3_deg']:.3g} deg")
    if "position_m" in e:
        final.append(f"position {100 * e['position_m']:.3g} cm, |heading| {e['heading_deg']:.3g} deg")
    if final:
        parts.append("final (mean over the last 5 %, as in hbvs report): " + ", ".join(final))
    parts.append(f"dhat {summary.dhat:.3f} m" + (f" (d* {d_true:.3f} m)" if d_true is not None else ""))
    console.info("; ".join(parts) + f" -> {summary.output}")
    if stopped is not None:
        raise TargetLostError(f"{stopped}; the run up to then is in {output}")
    return summary


def replay_frames(reader: TeachReader, sight: Any, model: FitModel, run: RunWriter) -> Iterator[ServoInput]:
    """The frames of ``--replay``: a recording's at their own stamps, measured through the fit's ``sight``; no ``act``
    (:class:`~hbvs_cli.core.servo_loop.ServoSource`): open loop, the commands are kept, nothing moves."""
    previous_t: float | None = None
    for frame, _, image in decoded_frames(reader.frames(), reader.name, colour=lambda: sight.colour):
        camera = reader.camera
        if camera is not None and (camera.width, camera.height) != (model.camera.width, model.camera.height):
            raise InputError(f"{reader.name}: its images are {camera.width}x{camera.height}, the fit's camera {model.camera.width}x{model.camera.height}")
        t = frame.t
        observation = sight.observe(image, t)
        if previous_t is None:
            # The replay keeps the recording's stamps: t = 0 is known with the first frame.
            run.start(frame.log_time_ns - seconds_to_ns(t))
        dt = t - previous_t if previous_t is not None else 0.0
        previous_t = t
        yield ServoInput(t, dt, observation, sight.evaluate(t), np.full(3, np.nan))


def _run_replay(options: RepeatOptions, settings: Settings, fit: FitFile, console: Console) -> RepeatSummary:
    model = fit.model
    reader = TeachReader(options.replay)
    # The recording's motion is not the commands': no state filter (its prediction assumes they moved the robot).
    tracking = make_tracking(options, settings, fit, filtered=False)
    controller = tracking.controller
    servo = ServoStep(controller, settings.limits, 0, None, stop_when_lost=True)
    tally = _Tally()
    with open_text_output(options.cmd_out, "command stream") as cmd_stream, live_writer(options.foxglove, options.foxglove_speed, console.info) as view:
        with open_output(options.output) as file_writer:
            writer = view(file_writer)
            run = RunWriter(writer, _run_metadata("replay", options, settings, fit, None) | tracking.metadata, model.camera, base_ns=None)
            log = tracking.step_log(_StepLog(run, settings, model, None, cmd_stream))
            with console.progress("repeat (replay)", None) as bar:
                for record in run_servo(replay_frames(reader, tracking.sight, model, run), servo):
                    log.step(record)
                    tally.add(record)
                    bar.advance()
            if not tally.series["t"]:
                raise InputError(f"{reader.name}: no frames to replay")
            _note_truncated(writer, options, fit, console, reader)
    return _finish(console, tally, controller, options.output, settings, None, None)


def _run_live(options: RepeatOptions, settings: Settings, fit: FitFile, console: Console) -> RepeatSummary:
    """``--live``: drive a robot, every frame through the :class:`~hbvs_cli.core.simulator.ServoStep` of ``--sim``."""
    live.check_live_options(options, settings.lost_timeout)
    interface = live.robot_interface(options)
    model = fit.model
    tracking = make_tracking(options, settings, fit, filtered=True)
    controller = tracking.controller
    servo = ServoStep(controller, settings.limits, 0, tracking.state_filter, stop_when_lost=True)
    tally = _Tally()
    loop: live.LiveLoop | None = None
    run: RunWriter | None = None
    stop_reason: str | None = None
    with ExitStack() as stack:
        link = interface.open(options, stack, settings.lost_timeout, console.info)
        # Kept, finished, whatever ends the run: the record of what a robot was sent is never lost.
        cmd_stream = stack.enter_context(open_text_output(options.cmd_out, "command stream", keep_on_error=True))
        out = live.CommandOut(link.commands, cmd_stream, options.dry_run, options.stale_timeout)
        try:
            out.stop(0.0)  # whatever the robot did before, it starts from rest
            # The run file first: whatever stops the run from here on is recorded in it.
            # --foxglove: the run served as it is written (already real time: no pacing).
            view = stack.enter_context(live_writer(options.foxglove, 0.0, console.info))
            writer = view(stack.enter_context(open_output(options.output, keep_on_error=True)))
            info = _run_metadata("live", options, settings, fit, None) | tracking.metadata | {"live": {
                "source": link.source_name, "cmd_topic": link.commands.topic if link.commands is not None else None,
                "cmd_type": options.cmd_type, "dry_run": options.dry_run, "stale_timeout_s": options.stale_timeout,
            }}
            run = RunWriter(writer, info, model.camera, base_ns=None)
            log = tracking.step_log(_StepLog(run, settings, model, None, None))
            source, camera = link.open_camera()
            live.check_camera(camera, model.camera, "the live camera's calibration")
            status = stack.enter_context(console.status_line())
            loop = live.LiveLoop(source, tracking.sight, model, servo, out, run, log, tally, options, settings,
                                 status=status, warn=console.warn)
            console.info(f"repeat --live: waiting for the target near its taught start ({live.START_FRAMES} frames in a row)")
            loop.wait_for_start()
            console.info("repeat --live: started" + (" (dry run: publishing zeros)" if options.dry_run else ""))
            loop.drive()
        except BaseException as exc:
            stop_reason = live.stop_reason(exc)
            raise
        finally:
            t = loop.now() if loop is not None else 0.0
            out.stop(t)
            out.close()
            if run is not None:
                run.start(time.time_ns())  # (no-op once the first frame set t = 0)
                run.command(t, 0.0, 0.0, False)
                reason = stop_reason or (loop.stopped if loop is not None else None)
                if reason is not None:
                    run.stopped(t, reason)
    return _finish(console, tally, controller, options.output, settings, None, loop.stopped)

