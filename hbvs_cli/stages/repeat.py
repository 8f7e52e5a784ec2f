"""``hbvs repeat``: track the fitted trajectory with the adaptive controller (29)-(31). ``--sim``: closed loop, a
simulated robot from the taught start plus ``--offset``; ``--replay``: open loop on a recording's frames, nothing
moves; ``--live``: closed loop with a robot (:mod:`.live`)."""

from __future__ import annotations

import math
import time
from contextlib import ExitStack
from typing import Any

import numpy as np

from ..core.controller import ControllerGains
from ..core.depth import check_depth
from ..core.fit_model import FitModel
from ..core.frames import compose_planar_pose
from ..core.laws import gains_for_law, make_controller
from ..core.servo_loop import ServoInput, run_servo
from ..core.simulator import ActuatorLimits, ServoStep, StepRecord
from ..core.control_settings import GAIN_NAMES
from ..core.trajectory import TimeScaledTrajectory
from ..errors import InputError, UsageError
from ..settings.config import load_config
from ..io.fit_file import FitFile, read_fit_file
from ..io.foxglove_scene import SIMULATION_EPOCH_NS, SceneWriter
from ..io.images import bytes_to_store
from ..io.live_view import live_writer
from ..io.mcap import McapWriter, open_output, seconds_to_ns
from ..io.output_target import open_text_output, refuse_overwriting_inputs
from ..io.run_file import RunWriter
from ..settings.commands import DEFAULT_GAINS, REPEAT, RepeatOptions
from ..io.teach_file import TeachReader
from ..perception.tracked import detector_from_model, estimator_from_model
from ..sim import CameraSettings, SimulatedCamera, Simulation, simulation_world
from . import live
from .console import Console
from .frame_decoding import decoded_frames, fit_reference_image, fit_template_image
from .options import parse_interval, parse_offset, parse_pair
from .repeat_route import Tracking, desired_pixels, route_tracking, run_route_repeat
from .repeat_run import (RepeatSummary, Settings, StepLog, Tally, check_simulation_settings, drive_simulation, finish, make_state_filter,
                         run_metadata)

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
        return run_route_repeat(options, settings, fit, console)
    if options.live:
        return _run_live(options, settings, fit, console)
    if options.sim:
        return _run_simulation(options, settings, fit, console)
    return _run_replay(options, settings, fit, console)


def settings_for(options: RepeatOptions, model: FitModel) -> Settings:
    """:func:`resolve_settings` with the fit's suggestions and taught rate."""
    return resolve_settings(options, model.dhat0, 1.0 / model.taught_frame_interval(), model.suggested_gains())


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
    scene, camera, steps = simulation.scene, simulation.camera, simulation.steps
    taught_poses = scene.taught_pose_at_run_time(np.arange(steps) * simulation.dt).tolist()
    height = scene.world.camera_height
    with open_text_output(options.cmd_out, "command stream") as cmd_stream, live_writer(options.foxglove, options.foxglove_speed, console.info) as live:
        with open_output(options.output) as file_writer:
            writer = live(file_writer)
            _note_truncated(writer, options, fit, console)
            run = RunWriter(writer, run_metadata("sim", options, settings, fit, scene.d_true, scene.world), model.camera, SIMULATION_EPOCH_NS)
            scene_3d = SceneWriter(writer)
            scene_3d.start(SIMULATION_EPOCH_NS, height, scene.world, np.array(taught_poses))

            def each(k: int, record: StepRecord) -> None:
                scene_3d.pose(run.log_time_ns(record.t), record.pose)
                if options.record_images:
                    label = f"t = {record.t:.2f} s" + ("  target lost" if record.lost else "")
                    run.image(record.t, *bytes_to_store(camera.image_of(record.pose)), record.observation.pixels,
                              desired_pixels(model, record.desired), label)

            tally, stopped = drive_simulation(console, f"repeat (sim, {settings.law})", steps, simulation.run(),
                                              StepLog(run, settings, model, scene.d_true, cmd_stream), simulation.dt, taught_poses, height, each)
    return finish(console, tally, simulation.controller.dhat, options.output, settings, scene.d_true, stopped)


def _tracking(options: RepeatOptions, settings: Settings, fit: FitFile, filtered: bool) -> Tracking:
    """What ``--live`` (``filtered``: with ``--filter``'s state filter) and ``--replay`` servo with, one target's or a route's."""
    if fit.route_record is not None:
        return route_tracking(options, settings, fit, filtered)
    model = fit.model
    estimator = estimator_from_model(model)
    detector = detector_from_model(model, fit_template_image(fit), seed=options.seed)
    state_filter = make_state_filter(settings, model, estimator) if filtered else None
    sight = live.TargetSight(detector, estimator, TimeScaledTrajectory(model.trajectory, settings.speed))
    return Tracking(sight, make_controller(settings.law, settings.gains, settings.dhat0), state_filter)


class RecordedDrive:
    """The source of ``--replay`` (:class:`~hbvs_cli.core.servo_loop.ServoSource`): a recording's frames at their own
    stamps, measured through the fit's ``sight``. Open loop: the commands are kept, nothing moves."""

    def __init__(self, reader: TeachReader, sight: Any, model: FitModel, run: RunWriter) -> None:
        self.reader, self.sight, self.model, self.run = reader, sight, model, run

    def __iter__(self) -> Any:
        model, reader = self.model, self.reader
        previous_t: float | None = None
        for frame, _, image in decoded_frames(reader.frames(), reader.name, colour=lambda: self.sight.colour):
            camera = reader.camera
            if camera is not None and (camera.width, camera.height) != (model.camera.width, model.camera.height):
                raise InputError(f"{reader.name}: its images are {camera.width}x{camera.height}, the fit's camera {model.camera.width}x{model.camera.height}")
            t = frame.t
            observation = self.sight.observe(image, t)
            if previous_t is None:
                # The replay keeps the recording's stamps: t = 0 is known with the first frame.
                self.run.start(frame.log_time_ns - seconds_to_ns(t))
            dt = t - previous_t if previous_t is not None else 0.0
            previous_t = t
            yield ServoInput(t, dt, observation, self.sight.evaluate(t), np.full(3, np.nan))

    def act(self, record: StepRecord) -> None:
        """Open loop: the command a robot would be sent is recorded, and nothing moves."""


def _run_replay(options: RepeatOptions, settings: Settings, fit: FitFile, console: Console) -> RepeatSummary:
    model = fit.model
    reader = TeachReader(options.replay)
    # The recording's motion is not the commands': no state filter (its prediction assumes they moved the robot).
    tracking = _tracking(options, settings, fit, filtered=False)
    servo = ServoStep(tracking.controller, settings.limits, 0, None, stop_when_lost=True)
    tally = Tally()
    with open_text_output(options.cmd_out, "command stream") as cmd_stream, live_writer(options.foxglove, options.foxglove_speed, console.info) as live:
        with open_output(options.output) as file_writer:
            writer = live(file_writer)
            run = RunWriter(writer, run_metadata("replay", options, settings, fit, None) | tracking.metadata, model.camera, base_ns=None)
            log = tracking.step_log(run, settings, model, cmd_stream)
            with console.progress("repeat (replay)", None) as bar:
                for record in run_servo(RecordedDrive(reader, tracking.sight, model, run), servo):
                    log.step(record)
                    tally.add(record)
                    bar.advance()
            if not tally.series["t"]:
                raise InputError(f"{reader.name}: no frames to replay")
            _note_truncated(writer, options, fit, console, reader)
    return finish(console, tally, tracking.controller.dhat, options.output, settings, None, None)


def _run_live(options: RepeatOptions, settings: Settings, fit: FitFile, console: Console) -> RepeatSummary:
    """``--live``: drive a robot, every frame through the :class:`~hbvs_cli.core.simulator.ServoStep` of ``--sim``."""
    live.check_live_options(options, settings.lost_timeout)
    interface = live.robot_interface(options)
    model = fit.model
    tracking = _tracking(options, settings, fit, filtered=True)
    servo = ServoStep(tracking.controller, settings.limits, 0, tracking.state_filter, stop_when_lost=True)
    tally = Tally()
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
            info = run_metadata("live", options, settings, fit, None) | tracking.metadata | {"live": {
                "source": link.source_name, "cmd_topic": link.commands.topic if link.commands is not None else None,
                "cmd_type": options.cmd_type, "dry_run": options.dry_run, "stale_timeout_s": options.stale_timeout,
            }}
            run = RunWriter(writer, info, model.camera, base_ns=None)
            log = tracking.step_log(run, settings, model, None)
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
    return finish(console, tally, tracking.controller.dhat, options.output, settings, None, loop.stopped)

