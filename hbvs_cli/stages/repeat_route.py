"""``hbvs repeat --sim`` on a route file (issue 47): :func:`~hbvs_cli.sim.route_loop.run_route`
segment by segment (each its own F*_i, n*_i, gains and state filter; dhat (31) carried over by
the transition's rho at each switch), written as a run file that ``hbvs report`` reads. The
Lyapunov function (36) is logged per segment, against that segment's true d*_i; the run's
metadata say where the switches were planned and each segment's true depth."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from ..core.control_settings import FILTER_EKF
from ..core.frames import compose_planar_pose
from ..core.laws import gains_for_law, make_controller
from ..core.route import RouteFit
from ..errors import UsageError
from ..io.fit_file import FitFile
from ..io.foxglove_scene import SIMULATION_EPOCH_NS
from ..io.mcap import open_output
from ..io.messages import LOG_INFO
from ..io.output_target import open_text_output
from ..io.route_file import RouteFile, route_of
from ..io.run_file import RunWriter
from ..settings.commands import RepeatOptions
from ..sim.route_loop import run_route, switch_times
from ..sim.route_world import RouteWorld, recorded_route
from ..sim.scene import point_identity
from .console import Console


def taught_pose_at(taught: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The taught pose (K, 3) in the route frame at times ``t`` (s), between the recorded
    frames ``taught`` (F, 4: t, x, y, phi) linearly (phi unwrapped)."""
    phi = np.unwrap(taught[:, 3])
    return np.column_stack([np.interp(t, taught[:, 0], taught[:, 1]), np.interp(t, taught[:, 0], taught[:, 2]),
                            np.interp(t, taught[:, 0], phi)])


def segment_truths(route: RouteWorld, plan: RouteFile) -> tuple[list[float], list[np.ndarray]]:
    """Each segment's true d*_i (m), its target seen from the taught pose of its F*_i (7), and
    the permutation of its target's points into its fit's order (its detector's)."""
    depths, orders = [], []
    for segment, reference, model in zip(plan.segments, plan.references, plan.models):
        world, local = route.worlds[segment.target], route.local_pose(segment.target, plan.taught_poses[reference, 1:])
        depths.append(float(world.reference_geometry(local)[2]))
        orders.append(point_identity(world.pixels(local), model.reference_pixels))
    return depths, orders


def run_route_repeat(options: RepeatOptions, settings: Any, fit: FitFile, console: Console, tools: Any) -> Any:
    """Repeat the route of ``fit`` in simulation as ``settings`` (the first segment's, resolved
    by :func:`.repeat.settings_for`) say; ``tools``: repeat's step log, tally and summary
    (:mod:`.repeat` hands them in). The run's summary."""
    plan = route_of(fit, str(options.input))
    if not options.sim:
        raise UsageError("a route file repeats with --sim only; --replay and --live take the fit of one target")
    if plan.world is None or plan.taught_poses is None:
        raise UsageError(f"{options.input}: a route fit without its simulated route: repeat --sim needs a simulated teach's")
    models = plan.models
    route = recorded_route(plan.world, models[0].camera)
    depths, orders = segment_truths(route, plan)
    interval = models[0].taught_frame_interval()
    route_fit = RouteFit(plan.segments, models, plan.references, plan.transitions)
    switches = switch_times(route_fit, np.arange(plan.taught_poses.shape[0]) * interval)
    # Each segment its fit's suggested gains, unless the options or the config set the first's otherwise.
    suggested = [gains_for_law(model.suggested_gains(), settings.law) if model.suggested_gains() is not None else settings.gains
                 for model in models]
    gains = suggested if settings.gains == suggested[0] else [settings.gains] * len(models)
    noise = [tools.detector_noise(model) for model in models] if settings.state_filter == FILTER_EKF else None
    controller = make_controller(settings.law, settings.gains, settings.dhat0)
    start = compose_planar_pose(plan.taught_poses[0, 1:], settings.offset)
    dt = 1.0 / settings.rate
    duration = float(plan.taught_poses[-1, 0]) + dt
    camera, steps = run_route(route, route_fit, switches, controller,
                              start, dt, duration, settings.limits, settings.pixel_noise, options.seed, gains, noise, orders)
    metadata = tools.run_metadata("sim", options, settings, fit, depths[0]) | {
        "d_true": depths[-1],
        "route": {"switch_times": switches.tolist(), "targets": [s.target for s in plan.segments],
                  "target_kinds": [m.target_kind for m in models], "d_true": depths,
                  "depth_ratios": [tr.depth_ratio for tr in plan.transitions]},
    }
    tally = tools.tally()
    height = route.camera_height
    with open_text_output(options.cmd_out, "command stream") as cmd_stream, open_output(options.output) as writer:
        run = RunWriter(writer, metadata, models[0].camera, SIMULATION_EPOCH_NS)
        log = tools.step_log(run, settings, models[0], depths[0], cmd_stream)
        switched = 0
        lost = tools.lost_watch(settings.lost_timeout, dt, log)
        with console.progress(f"repeat (sim, route of {len(models)} segments)", int(duration / dt)) as bar:
            for record in steps:
                while switched < len(camera.switches):  # a switch: V (36) against the new segment's d* and gains
                    when, segment, before, after = camera.switches[switched]
                    log.d_true, log.settings = depths[segment], replace(settings, gains=gains[segment])
                    log.event(when, LOG_INFO, f"segment {segment + 1} (target {plan.segments[segment].target + 1}, "
                              f"{models[segment].target_kind}): dhat {before:.3f} -> {after:.3f} m by rho {after / before:.4f}")
                    switched += 1
                log.step(record)
                taught = taught_pose_at(plan.taught_poses, np.array([record.t]))[0]
                run.poses(record.t, record.pose, taught, height)
                tally.add(record, taught)
                bar.advance()
                if lost.stops(record):
                    break
    return tools.finish(console, tally, controller, options.output, settings, depths[-1], lost.stopped)
