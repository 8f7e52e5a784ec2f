"""``hbvs teach``: record a taught run (simulated, video, images, camera or ROS 2 bag)."""

from __future__ import annotations

import math
from contextlib import ExitStack
from dataclasses import replace
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from ..core.camera import DEFAULT_CAMERA, CameraIntrinsics
from ..core.frames import compose_planar_pose
from ..core.path import PRESETS, CommandProfile, preset_profile
from ..sim.world import World, default_world
from ..errors import InputError, UsageError
from ..io import sources
from ..io.calibration import load_calibration, save_calibration_ros
from ..io.foxglove_scene import SIMULATION_EPOCH_NS
from ..io.images import STORE_FORMATS, bytes_to_store
from ..io.limits import step_count
from ..stop_signals import Terminated
from ..io.mcap import open_output, seconds_to_ns
from ..io.dds_discovery import dds_settings
from ..io.output_target import refuse_overwriting_inputs
from ..io.path_csv import load_command_profile
from ..io.ros2_names import check_topic_names
from ..settings.commands import DEFAULT_FPS, SIMULATION_DEFAULTS, TeachOptions
from ..io.teach_file import TeachWriter
from ..io.video_out import video_output
from ..sim.render import make_renderer
from ..sim.route_world import RouteWorld, make_route_renderer, simulated_route
from .console import Console
from .options import parse_offset, recorded_settings

#: Flush a teach file's chunk at least this often: a crash loses at most this much.
TEACH_CHUNK_BYTES = 512 * 1024
#: Options of each recorded source recorded in its metadata (beside the source's own description).
SOURCE_SETTINGS = ("calibration", "fps", "duration", "image_format", "jpeg_quality", "gray")


def _recorded(options: TeachOptions) -> dict[str, Any]:
    """The options recorded in the teach file's metadata: a simulated teach's all, a recorded source's only those that apply to it."""
    recorded = recorded_settings(options)
    kind = options.source_kind()
    if kind == "sim":
        # Simulated frames are gray whatever --gray says; "sim" is true with or without --sim. The extra outputs are
        # left out, as the output is: the same drive, the same bytes. A route brings its own path and targets; without
        # one, a single target's bytes are as before routes.
        left_out = {"cmd_topic", "gray", "ros2_image", "ros2_cmd", "video_out", "calibration_out"} | (
            {"path", "target", "dots", "texture"} if options.route is not None else {"route"})
        return {**{key: value for key, value in recorded.items() if key not in left_out}, "sim": True}
    keep = {kind, *SOURCE_SETTINGS} | ({"topic", "cmd_topic"} if kind == "bag" else set()) | (
        {"ros2_image", "ros2_cmd"} if kind == "ros2" else set())
    return {key: value for key, value in recorded.items() if key in keep}


def run_teach(options: TeachOptions, console: Console) -> None:
    """Record the taught run described by ``options`` into ``options.output``."""
    if options.image_format not in STORE_FORMATS:
        raise UsageError(f"--format must be {', '.join(STORE_FORMATS)}, got {options.image_format!r}")
    for name, value in (("--fps", options.fps), ("--duration", options.duration), ("--noise", options.noise), ("--exposure", options.exposure)):
        if value is not None and not math.isfinite(value):
            raise UsageError(f"{name} must be a finite number, got {value}")
    path_file = options.path if options.path not in PRESETS else None
    refuse_overwriting_inputs([("-o", options.output), ("--video-out", options.video_out), ("--calibration-out", options.calibration_out)],
                              [("--video", options.video), ("--bag", options.bag), ("--texture", options.texture),
                               ("--calibration", options.calibration), ("--path", path_file)])
    kind = options.source_kind()
    if options.cmd_topic is not None and kind != "bag":
        raise UsageError(f"--cmd-topic goes with --bag, not --{kind}")
    if options.ros2_cmd is not None and kind != "ros2":
        raise UsageError(f"--ros2-cmd goes with --ros2-image, not --{kind}")
    if kind == "ros2":
        check_topic_names((options.ros2_image, "--ros2-image"), (options.ros2_cmd, "--ros2-cmd"))
    if kind == "sim":
        if options.route is not None:
            given = [f"--{name}" for name in ("path", "target", "dots", "texture") if getattr(options, name) is not None]
            if given:
                raise UsageError(f"--route brings its own path and targets: leave out {', '.join(given)}")
        _teach_simulated(options.for_simulation(), console)
    else:
        _teach_from_source(kind, options, console)


def resolve_path(spec: str, fps: float, duration: float | None) -> tuple[CommandProfile, tuple[float, float, float], str]:
    """The taught commands and start pose of ``--path`` (a preset name or a CSV file)."""
    if spec in PRESETS:
        return (*preset_profile(spec, fps, duration), spec)
    candidate = Path(spec)
    if candidate.suffix.lower() == ".csv" or candidate.exists():
        profile = _cut_profile(load_command_profile(candidate), duration)
        # A CSV path starts 6 m in front of the target, facing it.
        return profile, (0.0, 0.0, 0.0), str(candidate)
    raise UsageError(f"unknown --path {spec!r}: choose a preset ({', '.join(PRESETS)}) or give a CSV file with columns t,v,w")


def _cut_profile(profile: CommandProfile, duration: float | None) -> CommandProfile:
    """``profile`` cut at ``duration`` (s) when it is shorter (None: whole)."""
    if duration is None or duration >= profile.t_end:
        return profile
    keep = profile.t < duration
    if not np.any(keep):
        raise UsageError("--duration is shorter than the first command")
    return CommandProfile(t=profile.t[keep], v=profile.v[keep], w=profile.w[keep], t_end=duration)


def _teach_simulated(options: TeachOptions, console: Console) -> None:
    camera = _load_camera(options.calibration) if options.calibration is not None else DEFAULT_CAMERA
    world: World | RouteWorld
    if options.route is not None:
        world = simulated_route(options.route, camera)
        profile = _cut_profile(world.profile, options.duration)
        start_pose, path_name = tuple(world.start_pose), f"route {options.route}"
        renderer = make_route_renderer(world, options.noise, options.blur, options.exposure, options.noise_grain)
    else:
        if options.texture is not None and options.target != "texture":
            raise UsageError("--texture goes with --target texture")
        texture = "builtin" if options.texture is None else str(options.texture)
        world = default_world(options.target, camera=camera, dots=options.dots, texture=texture)
        if options.path in PRESETS:  # a preset is sampled at --fps: bound it before sampling
            planned = options.duration if options.duration is not None else PRESETS[options.path].duration
            step_count(planned, options.fps, "the simulated teach (its duration times --fps)")
        profile, start_pose, path_name = resolve_path(options.path, options.fps, options.duration)
        renderer = make_renderer(world, options.noise, options.blur, options.exposure, options.noise_grain)
    if options.offset is not None:
        # A second drive by hand never starts exactly where the first did.
        start_pose = tuple(compose_planar_pose(start_pose, parse_offset(options.offset)))
    duration = profile.duration if options.duration is None else min(options.duration, profile.duration)
    step_count(duration, options.fps, "the simulated teach (its duration times --fps)")
    frame_count = max(int(np.floor(duration * options.fps + 1e-9)), 1)
    times = np.arange(frame_count) / options.fps
    poses = profile.poses_at(times, start_pose)
    v_cmd, w_cmd = profile.commands_at(times)
    out_of_view = [float(t) for t, pose in zip(times, poses) if not world.in_view(pose, margin_px=2.0)]
    if out_of_view:
        console.warn(
            f"the target leaves the camera's view for {len(out_of_view)} of {frame_count} frames "
            f"(first at t = {out_of_view[0]:.2f} s); fit will leave those frames out"
        )
    rng = np.random.default_rng(options.seed)
    settings = _recorded(options) | {"path_name": path_name, "start_pose": list(start_pose), "duration_s": duration, "frames": frame_count}
    with ExitStack() as outputs:
        video = None if options.video_out is None else outputs.enter_context(
            video_output(options.video_out, options.fps, (world.camera.width, world.camera.height)))
        writer = outputs.enter_context(open_output(options.output, chunk_size=TEACH_CHUNK_BYTES))
        teach = TeachWriter(writer, "sim", settings, world)
        teach.calibration(world.camera, SIMULATION_EPOCH_NS)
        with console.progress("teach (sim)", frame_count) as bar:
            for t, pose, v, w in zip(times, poses, v_cmd, w_cmd):
                image = renderer.render(pose, rng)
                if video is not None:
                    video(image)
                data, image_format = bytes_to_store(image, image_format=options.image_format, jpeg_quality=options.jpeg_quality)
                teach.frame(
                    SIMULATION_EPOCH_NS + seconds_to_ns(t), data, image_format,
                    pose=tuple(pose), camera_height=world.camera_height, command=(float(v), float(w)),
                )
                bar.advance()
    if options.calibration_out is not None:
        # The simulation renders with this very camera: its intrinsics are exact.
        save_calibration_ros(replace(world.camera, sigma=(0.0,) * 4), options.calibration_out, camera_name="hbvs_simulated")
    extras = "".join(f", {what} {path}" for what, path in (("video", options.video_out), ("calibration", options.calibration_out))
                     if path is not None)
    seen = f"{len(world.worlds)} targets" if isinstance(world, RouteWorld) else f"{options.target} target"
    console.info(f"teach: {frame_count} frames ({duration:.1f} s, {seen}, path {path_name}) -> {options.output}{extras}")


def _load_camera(path: Path, source: sources.FrameSource | None = None, console: Console | None = None) -> CameraIntrinsics:
    notes: list[str] = []
    camera = load_calibration(path, image_size=getattr(source, "image_size", None), notes=notes)
    for note in notes if console is not None else ():
        console.warn(note)
    return camera


def _open_source(kind: str, options: TeachOptions) -> sources.FrameSource:
    if kind == "ros2":
        from ..io.sources.ros2_topic import Ros2TopicSource  # lazy: an optional extra

        return Ros2TopicSource(options.ros2_image, options.ros2_cmd, options.duration)
    spec: Any = {"video": options.video, "images": options.images, "camera": options.camera, "bag": options.bag}[kind]
    fps = DEFAULT_FPS if kind == "images" and options.fps is None else options.fps
    if kind == "camera":
        # What repeat --live --camera takes: an index, a device path, a URL; a video file is a video.
        device = str(spec).strip()
        if Path(device).is_file():
            return sources.open_source("video", device, fps=fps)
        spec = int(device) if device.isdigit() else device
    return sources.open_source(kind, spec, fps=fps, duration=options.duration, topic=options.topic, cmd_topic=options.cmd_topic)


def _teach_from_source(kind: str, options: TeachOptions, console: Console) -> None:
    given = [f"--{name.replace('_', '-')}" for name in SIMULATION_DEFAULTS if getattr(options, name) is not None]
    if given:
        verb = "describes" if len(given) == 1 else "describe"
        raise UsageError(f"{', '.join(given)} {verb} the simulated robot and camera, not --{kind}: leave {'it' if len(given) == 1 else 'them'} out")
    if options.fps is not None and kind in ("camera", "bag", "ros2"):
        clock = "the clock when each frame arrives" if kind == "camera" else "the bag's header stamps" if kind == "bag" else "their header stamps"
        raise UsageError(f"--fps does not go with --{kind}: its frames are timestamped by {clock}")
    if kind == "ros2":
        console.info(f"teach: waiting for {options.ros2_image}; {dds_settings().description}")
    source = _open_source(kind, options)
    camera = _load_camera(options.calibration, source, console) if options.calibration is not None else getattr(source, "camera", None)
    if camera is None:
        problem = getattr(source, "camera_problem", None)
        hint = f" ({problem})" if problem else " (the bag has no CameraInfo topic)" if kind == "bag" else ""
        raise UsageError(f"--calibration FILE is required for --{kind}{hint}")
    frames = 0
    last_t = 0.0
    interrupted = False
    with open_output(options.output, chunk_size=TEACH_CHUNK_BYTES) as writer:
        teach = TeachWriter(writer, kind, _recorded(options) | {"source": source.describe()}, frame_id=getattr(source, "frame_id", None))
        with console.progress(f"teach ({kind})", source.describe().get("frames")) as bar:
            iterator: Iterator[sources.SourceFrame] = iter(source)
            try:
                for frame in iterator:
                    # Frames at t = 0, 1/fps, ... strictly before the end: 5 s at 30 fps is 150.
                    if options.duration is not None and frame.t >= options.duration - 1e-9:
                        break
                    height, width = frame.image.shape[:2]
                    if (width, height) != (camera.width, camera.height):
                        raise InputError(f"{source.describe().get('path', 'source')}: frames are {width}x{height} but the calibration "
                                         f"is for {camera.width}x{camera.height}; use the calibration of this camera and resolution")
                    encoded = frame.encoded if frame.format in ("png", "jpeg") else None
                    data, image_format = bytes_to_store(frame.image, encoded, frame.format, options.image_format, options.jpeg_quality, options.gray)
                    log_time_ns = frame.stamp_ns if frame.stamp_ns is not None else seconds_to_ns(frame.t)
                    if frames == 0:
                        # At the first frame's time: frames keep their source's stamps, which a live source knows
                        # only once the first arrives (logged at 0, the recording started in 1970).
                        teach.calibration(camera, log_time_ns)
                    teach.frame(log_time_ns, data, image_format, command=frame.command)
                    frames += 1
                    last_t = frame.t
                    bar.advance()
            except (KeyboardInterrupt, Terminated):
                if kind not in ("camera", "ros2"):
                    raise
                # Ctrl-C or SIGTERM is how a live recording ends, wherever it lands: keep what was recorded.
                interrupted = True
        if frames == 0:
            raise InputError(f"{source.describe().get('path', kind)}: no frames could be read")
    note = " (stopped by a signal)" if interrupted else ""
    bad_stamps = source.describe().get("bad_stamps")
    if bad_stamps:
        console.warn(f"teach: {bad_stamps} frames left out: their stamps were not newer than the last, or ran ahead of this "
                     "host's clock (a camera clock fault)")
    console.info(f"teach: {frames} frames ({last_t:.1f} s from {kind}){note} -> {options.output}")
