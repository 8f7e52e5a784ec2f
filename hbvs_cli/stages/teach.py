"""``hbvs teach``: record a taught run (simulated, video, images, camera or ROS 2 bag)."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from ..core.camera import DEFAULT_CAMERA, CameraIntrinsics
from ..core.path import DEFAULT_PRESET, PRESETS, CommandProfile, preset_profile
from ..core.world import World, default_world
from ..errors import InputError, UsageError
from .console import Console

#: Flush a teach file's chunk at least this often: a crash loses at most this much.
TEACH_CHUNK_BYTES = 512 * 1024
#: Options that describe the simulated robot and camera, and their defaults (None in
#: :class:`TeachOptions` means "not given"). A recorded source refuses them.
SIMULATION_DEFAULTS: dict[str, Any] = {
    "path": DEFAULT_PRESET, "offset": None, "target": "dots", "dots": 3, "texture": None,
    "seed": 0, "noise": 2.0, "blur": 0.0, "exposure": 1.0,
}
#: Frame rate of the simulated camera and of an image folder when --fps is not given (Hz).
DEFAULT_FPS = 30.0
#: Options of each recorded source recorded in its metadata (beside the source's own description).
SOURCE_SETTINGS = ("calibration", "fps", "duration", "image_format", "jpeg_quality")


@dataclass(frozen=True)
class TeachOptions:
    """Everything ``hbvs teach`` was asked to do (see ``hbvs teach --help``)."""

    output: str = "teach.mcap"
    sim: bool = False
    video: Path | None = None
    images: str | None = None
    camera: int | None = None
    bag: Path | None = None
    topic: str | None = None
    path: str | None = None
    offset: str | None = None
    target: str | None = None
    dots: int | None = None
    texture: Path | None = None
    calibration: Path | None = None
    fps: float | None = None
    duration: float | None = None
    seed: int | None = None
    noise: float | None = None
    blur: float | None = None
    exposure: float | None = None
    image_format: str = "auto"
    jpeg_quality: int = 90

    def source_kind(self) -> str:
        """The one source asked for (``sim`` when none is)."""
        given = [name for name, value in (("video", self.video), ("images", self.images), ("camera", self.camera), ("bag", self.bag)) if value is not None]
        if self.sim:
            given.insert(0, "sim")
        if len(given) > 1:
            raise UsageError(f"give exactly one source, got {', '.join('--' + g for g in given)}")
        return given[0] if given else "sim"

    def simulation_options_given(self) -> list[str]:
        """The simulation options that were given (not None), as ``--name``."""
        return [f"--{name}" for name in SIMULATION_DEFAULTS if getattr(self, name) is not None]

    def for_simulation(self) -> TeachOptions:
        """These options with the simulation's defaults filled in where none was given."""
        missing = {name: value for name, value in SIMULATION_DEFAULTS.items() if getattr(self, name) is None}
        return replace(self, **missing, fps=DEFAULT_FPS if self.fps is None else self.fps)

    def settings(self) -> dict[str, Any]:
        """The options as recorded in the teach file's metadata.

        A simulated teach records every option; a recorded source only those that apply
        to it (no simulator settings such as noise or the path).
        """
        from .options import recorded_settings

        recorded = recorded_settings(self)
        kind = self.source_kind()
        if kind == "sim":
            return recorded
        names = {field.name for field in fields(self)}
        keep = {kind, *SOURCE_SETTINGS} | ({"topic"} if kind == "bag" else set())
        return {key: value for key, value in recorded.items() if key in keep and key in names}


@dataclass(frozen=True)
class TeachSummary:
    frames: int
    duration_s: float
    output: str
    source: str


def run_teach(options: TeachOptions, console: Console) -> TeachSummary:
    """Record the taught run described by ``options`` into ``options.output``."""
    from ..io.images import STORE_FORMATS

    from ..io.output_target import refuse_overwriting_inputs

    if options.image_format not in STORE_FORMATS:
        raise UsageError(f"--format must be {', '.join(STORE_FORMATS)}, got {options.image_format!r}")
    if not 1 <= options.jpeg_quality <= 100:
        raise UsageError(f"--quality must be 1 to 100, got {options.jpeg_quality}")
    for name, value in (("--fps", options.fps), ("--duration", options.duration), ("--noise", options.noise), ("--exposure", options.exposure)):
        if value is not None and not math.isfinite(value):
            raise UsageError(f"{name} must be a finite number, got {value}")
    path_file = options.path if options.path not in PRESETS else None
    refuse_overwriting_inputs(
        [("-o", options.output)],
        [("--video", options.video), ("--bag", options.bag), ("--texture", options.texture),
         ("--calibration", options.calibration), ("--path", path_file)],
    )
    kind = options.source_kind()
    if kind == "sim":
        return _teach_simulated(options.for_simulation(), console)
    return _teach_from_source(kind, options, console)


# ----------------------------------------------------------------------------- simulated
def resolve_path(spec: str, fps: float, duration: float | None) -> tuple[CommandProfile, tuple[float, float, float], str]:
    """The taught commands and start pose of ``--path`` (a preset name or a CSV file)."""
    if spec in PRESETS:
        profile, start = preset_profile(spec, fps, duration)
        return profile, start, spec
    candidate = Path(spec)
    if candidate.suffix.lower() == ".csv" or candidate.exists():
        from ..io.path_csv import load_command_profile

        profile = load_command_profile(candidate)
        if duration is not None and duration < profile.t_end:
            profile = _cut_profile(profile, duration)
        # A CSV path starts 6 m in front of the target, facing it.
        return profile, (0.0, 0.0, 0.0), str(candidate)
    raise UsageError(f"unknown --path {spec!r}: choose a preset ({', '.join(PRESETS)}) or give a CSV file with columns t,v,w")


def _cut_profile(profile: CommandProfile, duration: float) -> CommandProfile:
    keep = profile.t < duration
    if not np.any(keep):
        raise UsageError("--duration is shorter than the first command")
    return CommandProfile(t=profile.t[keep], v=profile.v[keep], w=profile.w[keep], t_end=duration)


def simulated_world(options: TeachOptions) -> World:
    """The world of a simulated teach: camera, target kind, texture."""
    camera = _load_camera(options.calibration) if options.calibration is not None else DEFAULT_CAMERA
    texture = "builtin"
    if options.target == "texture" and options.texture is not None:
        texture = str(options.texture)
    elif options.texture is not None:
        raise UsageError("--texture goes with --target texture")
    return default_world(options.target, camera=camera, dots=options.dots, texture=texture)


def load_texture(world: World) -> np.ndarray | None:
    """The poster image of a texture target (None for the built-in pattern)."""
    if world.target.kind != "texture" or world.target.texture == "builtin":
        return None
    import cv2

    path = Path(world.target.texture)
    if not path.is_file():
        raise InputError(f"{path}: texture image not found")
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise InputError(f"{path}: not an image OpenCV can read")
    return image


def make_renderer(world: World, noise: float, blur: float, exposure: float) -> Any:
    """The scene renderer of a world (shared by teach and repeat so both see alike)."""
    from ..perception.poster import PosterRaster
    from ..perception.render import RenderSettings, SceneRenderer

    raster = PosterRaster.from_target(world.target, texture=load_texture(world))
    return SceneRenderer(world, raster, RenderSettings(noise_std=noise, blur_sigma=blur, exposure_gain=exposure))


def _teach_simulated(options: TeachOptions, console: Console) -> TeachSummary:
    from ..io.images import bytes_to_store
    from ..io.limits import step_count
    from ..io.foxglove_scene import SIMULATION_EPOCH_NS
    from ..io.mcap_io import open_output, seconds_to_ns
    from ..io.teach_file import TeachWriter

    if options.calibration is None and options.fps <= 0:
        raise UsageError("--fps must be positive")
    world = simulated_world(options)
    if options.path in PRESETS:  # a preset is sampled at --fps: bound it before sampling
        planned = options.duration if options.duration is not None else PRESETS[options.path].duration
        step_count(planned, options.fps, "the simulated teach (its duration times --fps)")
    profile, start_pose, path_name = resolve_path(options.path, options.fps, options.duration)
    if options.offset is not None:
        from ..core.frames import compose_planar_pose
        from .options import parse_offset

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
    renderer = make_renderer(world, options.noise, options.blur, options.exposure)
    rng = np.random.default_rng(options.seed)
    settings = options.settings() | {
        "path_name": path_name,
        "start_pose": list(start_pose),
        "duration_s": duration,
        "frames": frame_count,
    }
    with open_output(options.output, chunk_size=TEACH_CHUNK_BYTES) as writer:
        teach = TeachWriter(writer, "sim", settings, world)
        teach.calibration(world.camera, SIMULATION_EPOCH_NS)
        with console.progress("teach (sim)", frame_count) as bar:
            for t, pose, v, w in zip(times, poses, v_cmd, w_cmd):
                image = renderer.render(pose, rng)
                data, image_format = bytes_to_store(image, image_format=options.image_format, jpeg_quality=options.jpeg_quality)
                teach.frame(
                    SIMULATION_EPOCH_NS + seconds_to_ns(t), data, image_format,
                    pose=tuple(pose), camera_height=world.camera_height, command=(float(v), float(w)),
                )
                bar.advance()
    console.info(f"teach: {frame_count} frames ({duration:.1f} s, {options.target} target, path {path_name}) -> {options.output}")
    return TeachSummary(frames=frame_count, duration_s=duration, output=options.output, source="sim")


# ----------------------------------------------------------------------------- real sources
def _load_camera(path: Path) -> CameraIntrinsics:
    from ..io.calibration import load_calibration

    return load_calibration(path)


def _open_source(kind: str, options: TeachOptions) -> Any:
    from ..io import sources

    if kind == "video":
        return sources.VideoSource(options.video, fps=options.fps)
    if kind == "images":
        return sources.ImageFolderSource(options.images, fps=DEFAULT_FPS if options.fps is None else options.fps)
    if kind == "camera":
        return sources.CameraSource(options.camera, duration=options.duration)
    return sources.BagSource(options.bag, topic=options.topic)


def _teach_from_source(kind: str, options: TeachOptions, console: Console) -> TeachSummary:
    from ..io.images import bytes_to_store
    from ..io.mcap_io import open_output, seconds_to_ns
    from ..io.teach_file import TeachWriter

    given = options.simulation_options_given()
    if given:
        verb = "describes" if len(given) == 1 else "describe"
        raise UsageError(f"{', '.join(given)} {verb} the simulated robot and camera, not --{kind}: leave {'it' if len(given) == 1 else 'them'} out")
    if options.fps is not None and kind in ("camera", "bag"):
        clock = "the clock when each frame arrives" if kind == "camera" else "the bag's header stamps"
        raise UsageError(f"--fps does not go with --{kind}: its frames are timestamped by {clock}")
    source = _open_source(kind, options)
    camera = _load_camera(options.calibration) if options.calibration is not None else getattr(source, "camera", None)
    if camera is None:
        hint = " (the bag has no CameraInfo topic)" if kind == "bag" else ""
        raise UsageError(f"--calibration FILE is required for --{kind}{hint}")
    frames = 0
    last_t = 0.0
    interrupted = False
    with open_output(options.output, chunk_size=TEACH_CHUNK_BYTES) as writer:
        teach = TeachWriter(writer, kind, options.settings() | {"source": source.describe()})
        teach.calibration(camera)
        total = source.describe().get("frames")
        with console.progress(f"teach ({kind})", total) as bar:
            iterator: Iterator[Any] = iter(source)
            try:
                for frame in iterator:
                    # Frames at t = 0, 1/fps, ... strictly before the end: 5 s at 30 fps is 150.
                    if options.duration is not None and frame.t >= options.duration - 1e-9:
                        break
                    _check_frame_size(frame.image, camera, source)
                    encoded = frame.encoded if frame.format in ("png", "jpeg") else None
                    data, image_format = bytes_to_store(frame.image, encoded, frame.format, options.image_format, options.jpeg_quality)
                    teach.frame(seconds_to_ns(frame.t), data, image_format)
                    frames += 1
                    last_t = frame.t
                    bar.advance()
            except KeyboardInterrupt:
                if kind != "camera":
                    raise
                # Ctrl-C is how a live recording ends, wherever it lands: keep what was recorded.
                interrupted = True
        if frames == 0:
            raise InputError(f"{source.describe().get('path', kind)}: no frames could be read")
    note = " (stopped by Ctrl-C)" if interrupted else ""
    console.info(f"teach: {frames} frames ({last_t:.1f} s from {kind}){note} -> {options.output}")
    return TeachSummary(frames=frames, duration_s=last_t, output=options.output, source=kind)


def _check_frame_size(image: np.ndarray, camera: CameraIntrinsics, source: Any) -> None:
    height, width = image.shape[:2]
    if (width, height) != (camera.width, camera.height):
        raise InputError(
            f"{source.describe().get('path', 'source')}: frames are {width}x{height} but the calibration is for "
            f"{camera.width}x{camera.height}; use the calibration of this camera and resolution"
        )
