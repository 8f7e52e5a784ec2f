"""``hbvs fit``: from a teach recording to the desired trajectory of Remark 1: the target's points per frame,
then H_d (16)-(18), one plane normal n*, (theta_d, x_hd) and their smoothing splines, d* (25) and condition (35).
Reads and writes streams: constant memory."""

from __future__ import annotations

import math
import threading
from contextlib import contextmanager
from dataclasses import dataclass, replace
from functools import partial
from itertools import chain, islice
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from .. import __version__
from ..core.camera import UNSTATED_CALIBRATION_PROBE_PX, CameraIntrinsics
from ..core.depth import DepthEstimate, depth_from_taught_commands, depth_from_target_size
from ..core.desired import DesiredFit, fit_desired_trajectory
from ..core.fit_model import DepthEstimates, FitModel, SensorSettings
from ..core.gains import GainSuggestion
from ..errors import GeometryError, HbvsError, InputError, InsufficientDataError, RecordingError, UsageError
from ..settings.commands import MAX_DEPTH, MIN_DEPTH, FitOptions
from .console import Console
from .options import recorded_settings
from ..perception.target_kinds import TARGET_KINDS, target_kind
from ..perception.tracked import DetectorSpec, TrackedDetector, target_candidates
from ..thread_pool import StopSafePool
from .auto_target import NoTargetThroughout, followed_frames, judge, parse_board, picked, spec_of_kind
from .fit_route import fit_route_teach, is_route
from .frame_decoding import FrameLog, decoded_frames
from ..io.topics import ANNOTATIONS_TOPIC, CALIBRATION_TOPIC, IMAGE_TOPIC, MODEL_TOPIC, REFERENCE_IMAGE_TOPIC, TEMPLATE_IMAGE_TOPIC, TOPICS
from ..io.foxglove_scene import SceneWriter
from ..sim.world import World, world_from_description

#: Why --target-points and a kind whose points have no metric size do not go together
#: (refused before and after auto picks), ``{}`` the kind.
NO_LAYOUT = "--target-points needs dots, markers or a board: a {}'s points are not printed anywhere"
#: dhat(0) when nothing better is known (no commands, no --target-size): a guess, said so.
FALLBACK_DHAT0 = 2.0


@dataclass
class FitSummary:
    output: str
    model: Any


#: Largest spline penalty accepted (s^3): far beyond a straight line already, and below
#: the overflow of the penalised system (1e308 made scipy's solver fail).
MAX_SMOOTHING = 1e12


def parse_smoothing(text: str) -> float | None:
    if text.strip().lower() == "auto":
        return None
    try:
        value = float(text)
    except ValueError:
        raise UsageError(f"--smoothing must be 'auto' or a number, got {text!r}") from None
    if not np.isfinite(value) or value < 0 or value > MAX_SMOOTHING:
        raise UsageError(f"--smoothing must be 'auto' or a number from 0 to {MAX_SMOOTHING:g}, got {text!r}")
    return value


def parse_reference(spec: str) -> int | None:
    """Frame index of ``--reference first|last|INDEX`` ("05" is 5; None: the last), its range checked later."""
    key = spec.strip().lower()
    if key == "last":
        return None
    try:
        return 0 if key == "first" else int(key)
    except ValueError:
        raise UsageError(f"--reference must be first, last or a frame index, got {spec!r}") from None


def recorded_frame_count(source: str) -> int | None:
    """How many images a teach file's MCAP summary counts (None for stdin or no usable summary); never fails."""
    from ..io.mcap import read_summary

    if source == "-" or not Path(source).is_file():
        return None
    try:
        channels = read_summary(source)
    except HbvsError:
        return None
    counts = [channel.message_count for channel in channels or [] if channel.topic == IMAGE_TOPIC]
    return counts[0] if counts and counts[0] else None


def run_fit(options: FitOptions, console: Console) -> FitSummary:
    """Fit a teach recording into the fit file. Footage on which ``--target auto`` finds no one target
    throughout is fitted again as a route (:mod:`.fit_route`); if that fails too, the first failure is the error."""
    with _one_thread_each():
        try:
            return _run_fit(options, console)
        except InputError as lost:  # the fit's InsufficientDataError, said in its words (:func:`_fit`), is its context
            lost_on_the_way = getattr(lost.__context__, "facts", {}).get("reason") in ("lost", "gap")
            if options.target != "auto" or options.input == "-" or not (isinstance(lost, NoTargetThroughout) or lost_on_the_way):
                raise
            try:
                return _run_fit(options, console, as_route=True)
            except HbvsError:
                raise lost from None


@contextmanager
def _one_thread_each() -> Iterator[None]:
    """OpenCV's and BLAS's thread pools off while fitting, restored after: the frame loop and the decoding
    thread already keep two cores busy. scipy's BLAS, loaded later, is limited in :func:`_fit`."""
    import cv2
    from threadpoolctl import threadpool_limits

    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    _reuse_freed_frames()
    try:
        with threadpool_limits(limits=1, user_api="blas"):
            yield
    finally:
        cv2.setNumThreads(threads)


def _reuse_freed_frames() -> None:
    """glibc's malloc keeps freed frame-sized arrays for reuse (mallopt(3)) instead of page-faulting them in
    anew each frame. Both limits are needed; without glibc nothing is done."""
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt  # the process's own C library
    except (OSError, AttributeError, TypeError):
        return
    if mallopt(-3, 4 << 20):  # M_MMAP_THRESHOLD: arrays below 4 MB from the heap
        mallopt(-1, 32 << 20)  # M_TRIM_THRESHOLD: up to 32 MB of freed heap kept


def _run_fit(options: FitOptions, console: Console, as_route: bool = False) -> FitSummary:
    from ..io.fit_file import checked_model_message, write_desired_signals
    from ..io.images import sniff_format, write_compressed_image
    from ..io.mcap import open_output
    from ..io.messages import CAMERA_FRAME, annotations_message
    from ..io.teach_file import TeachReader
    from ..io.calibration import calibration_to_foxglove
    from ..io.output_target import refuse_overwriting_inputs

    parse_smoothing(options.smoothing)  # refused before the recording is read; each fit parses it again
    if options.target != "auto" and options.target not in TARGET_KINDS:
        raise UsageError(f"--target must be one of auto, {', '.join(TARGET_KINDS)}, got {options.target!r}")
    if options.target_size is not None and not (math.isfinite(options.target_size) and options.target_size > 0):
        raise UsageError(f"--target-size must be a positive length in metres, got {options.target_size}")
    _check_kind_options(options)
    known_layout = _read_known_layout(options)
    refuse_overwriting_inputs([("-o", options.output)], [("input", options.input)])
    reader = TeachReader(options.input)
    topics = TOPICS["fit"]
    log: FrameLog | None = None
    detector: TrackedDetector | None = None
    pull: Any = None  # the kind's image_shift accumulator
    reference_image: bytes | None = None
    wanted_index = parse_reference(options.reference)  # the frame whose image is kept as F*'s (last: each frame's in turn)
    with open_output(options.output) as writer:
        writer.metadata("hbvs", {"file_kind": "fit", "hbvs_version": __version__, "settings": recorded_settings(options), "input": reader.name})
        with console.progress("fit", recorded_frame_count(options.input)) as bar:
            # Colour until the target is known, then only for dots seen in colour; none once the first frames came out gray.
            gray_source = False
            frames = _checked_frames(reader, decoded_frames(
                reader.frames(), reader.name,
                colour=lambda: detector.spec.contrast == "colour" if detector is not None else not gray_source,
            ))
            # --target auto judges the first few frames together: peek at them, then go on.
            first = list(islice(frames, AUTO_FRAMES))
            gray_source = all(image.ndim == 2 for _, _, image in first)
            rest: Iterator[tuple[Any, bytes, np.ndarray]] = frames
            if first:
                frame = first[0][0]
                camera = reader.camera
                writer.write(CALIBRATION_TOPIC, topics[CALIBRATION_TOPIC], frame.log_time_ns,
                             calibration_to_foxglove(camera, CAMERA_FRAME, frame.log_time_ns))
                if as_route or is_route(reader.world_description):  # several targets: segment by segment
                    models = fit_route_teach(reader, writer, chain(first, frames), bar, console,
                                             partial(_drive_fit, reader, options, console), options)
                    return FitSummary(output=options.output, model=models[0])
                world = None if reader.world_description is None else world_from_description(reader.world_description, reader.name)
                sample = partial(followed_frames, options.input, recorded_frame_count(options.input), not gray_source,
                                 [(f.t, im) for f, _, im in first])
                pick = partial(_detector_spec, options, world, [im for _, _, im in first], camera, frame.pose, console, sample)
                if gray_source:  # what is decoded meanwhile is decoded as the detector will want it
                    spec, rest = _picked_while_reading(pick, frames, READ_AHEAD_BYTES)
                else:
                    spec = pick()
                detector = TrackedDetector(spec, camera, seed=options.seed)
                # Saturated dots: the pull all of them share (bloom), for the uncertainty.
                shift = target_kind(spec.kind).image_shift
                pull = shift(spec) if shift is not None else None
            for frame, data, image in chain(first, rest):
                assert detector is not None
                pixels = detector.detect(image)
                if pull is not None:
                    pull.add(image, pixels)
                if log is None:
                    log = FrameLog(pixels.shape[0])
                log.add(frame.t, frame.log_time_ns, pixels, frame.pose, frame.command)
                if wanted_index is None or frame.index == wanted_index:
                    reference_image = data
                if options.copy_images:
                    write_compressed_image(writer, IMAGE_TOPIC, frame.log_time_ns, data, sniff_format(data) or "jpeg", CAMERA_FRAME)
                # At the teach image's log time: Foxglove overlays these on it when both files are open.
                writer.write(
                    ANNOTATIONS_TOPIC, topics[ANNOTATIONS_TOPIC], frame.log_time_ns,
                    annotations_message(frame.log_time_ns, pixels),
                )
                bar.advance()
        if log is None or log.count == 0:
            cut = " (it ends before its end record: a crashed recorder?)" if reader.truncated else ""
            raise RecordingError(f"{reader.name}: no complete image in the recording{cut}")
        if reader.truncated:
            writer.input_ended_early(reader.name, options.allow_truncated)
            console.warn(f"{reader.name} ends before its end record (a crashed recorder?): recovered {log.count} complete frames")
        assert detector is not None
        arrays = log.arrays()
        reference_index = log.count - 1 if wanted_index is None else wanted_index
        if not 0 <= reference_index < log.count:
            raise UsageError(f"--reference {options.reference} is out of range: the recording has {log.count} frames "
                             f"(0 to {log.count - 1})")
        layout = None if known_layout is None else _ordered_layout(known_layout, arrays["pixels"][reference_index], camera, detector.spec, options)
        result, model = _drive_fit(reader, options, console, arrays, reference_index, detector.spec, reader.world_description,
                                   reader.name, layout, pull.pull_px if pull is not None else 0.0)
        write_desired_signals(writer, arrays["t"], arrays["log_time"], result)
        if model.taught_path is not None:  # the 3D scene: the target and the taught path
            height = world.camera_height if world is not None else 0.0
            SceneWriter(writer).start(int(arrays["log_time"][0]), height, world, arrays["pose"])
        end_ns = int(arrays["log_time"][-1])
        for topic, payload, k in ((REFERENCE_IMAGE_TOPIC, reference_image, reference_index),
                                  (TEMPLATE_IMAGE_TOPIC, first[0][1], 0)):  # the detector's template: the first frame
            stamp = int(arrays["log_time"][k])
            write_compressed_image(writer, topic, stamp, payload, sniff_format(payload) or "jpeg", CAMERA_FRAME)
        writer.write(MODEL_TOPIC, topics[MODEL_TOPIC], end_ns, checked_model_message(model, end_ns, reader.name))
    _print_summary(console, model, result, options)
    return FitSummary(output=options.output, model=model)


def _drive_fit(reader: Any, options: FitOptions, console: Console, arrays: dict[str, np.ndarray], reference_index: int,
               spec: DetectorSpec, world_description: dict[str, Any] | None, name: str, layout: np.ndarray | None = None,
               image_shift_px: float = 0.0) -> tuple[DesiredFit, FitModel]:
    """The fit of one target's drive (``arrays``: its frames, ``pose`` in its own world) and its model."""
    camera = reader.camera
    calibration = _calibration_uncertainty(reader)
    result = _fit(arrays, reference_index, camera, options, console, name, spec, layout, image_shift_px, calibration)
    spec = replace(spec, initial_pixels=result.initial_pixels)
    depth, dhat0, dhat0_source = _depth(result, arrays, spec, options, console, layout=layout)
    if calibration[0] == "unstated" and result.uncertainty is not None:
        console.warn(f"the calibration states no standard deviations of its intrinsics, so n*'s band counts the image noise only: "
                     f"{UNSTATED_CALIBRATION_PROBE_PX:g} px of error on the principal point (and on fx, fy) would add "
                     f"{result.uncertainty.calibration_normal_sigma_deg:.1f} deg to n* (1 sigma); give teach ... --calibration FILE "
                     "with its std_deviations_intrinsics (docs/walkthrough.md)")
    return result, FitModel(
        target_kind=spec.kind,
        camera=camera,
        reference_index=reference_index,
        reference_t=float(arrays["t"][reference_index]),
        **{name: getattr(result, name) for name in ("reference_pixels", "m_ref", "normal", "normal_margin", "trajectory", "residual_px")},
        dhat0=dhat0,
        dhat0_source=dhat0_source,
        depth=depth,
        frames=replace(result.frames, truncated_input=reader.truncated),
        condition35=result.condition,
        detector=spec,
        world_description=world_description,
        taught_path=_taught_path(arrays, reference_index) if np.all(np.isfinite(arrays["pose"])) else None,
        render=_render_settings(reader),
        gains=_suggested_gains(result, camera),
        uncertainty=result.uncertainty.summary(calibration[0]) if result.uncertainty is not None else None,
    )


def _checked_frames(reader: Any, frames: Iterator[Any]) -> Iterator[Any]:
    """``frames`` of the recording, each after its camera and of its size."""
    for frame, data, image in frames:
        camera = reader.camera
        if camera is None:
            raise RecordingError(f"{reader.name}: the recording has no camera calibration before its first image")
        if image.shape[:2] != (camera.height, camera.width):
            raise RecordingError(
                f"{reader.name}: frame {frame.index} is {image.shape[1]}x{image.shape[0]}, the calibration says {camera.width}x{camera.height}"
            )
        yield frame, data, image


#: Decoded pixels fit may hold while the target is being picked (bytes; why: docs/performance.md).
READ_AHEAD_BYTES = 128 << 20


def _picked_while_reading(pick: Callable[[], DetectorSpec], frames: Iterator[Any], budget: int
                          ) -> tuple[DetectorSpec, Iterator[Any]]:
    """The fit's solvers loaded and ``pick()`` here, where a stop signal interrupts them, while a second thread takes
    frames (up to ``budget`` bytes); then the frames taken and the rest, in order. An error reading is raised at its turn."""
    taken: list[Any] = []
    over = threading.Event()

    def take() -> None:
        size = 0
        while not over.is_set() and size < budget and (item := next(frames, None)) is not None:
            taken.append(item)
            size += item[2].nbytes

    with StopSafePool(max_workers=1, thread_name_prefix="hbvs-read-ahead") as pool:
        reading = pool.submit(take)
        try:
            _load_solvers()  # its 0.3 s while frames are read ahead, not when nothing else runs
            spec = pick()
        finally:
            over.set()
    failure = reading.exception()

    def in_turn() -> Iterator[Any]:
        yield from taken
        if failure is not None:
            raise failure
        yield from frames

    return spec, in_turn()


def _load_solvers() -> None:
    """Import the fit's solvers: scipy.linalg (and its BLAS), .optimize and .interpolate."""
    import scipy.interpolate  # noqa: F401
    import scipy.linalg  # noqa: F401
    import scipy.optimize  # noqa: F401


def _read_known_layout(options: FitOptions) -> np.ndarray | None:
    """--target-points: the target points' positions on the wall (m), or None."""
    if options.target_points is None:
        return None
    if options.target != "auto" and target_kind(options.target).size_pair is None:
        raise UsageError(NO_LAYOUT.format(options.target))
    from ..io.target_points import read_target_points

    return read_target_points(options.target_points)


def _ordered_layout(layout: np.ndarray, reference_pixels: np.ndarray, camera: CameraIntrinsics, spec: DetectorSpec,
                    options: FitOptions) -> np.ndarray:
    """--target-points in the detector's order, matched to F*'s points by their layout."""
    from ..core.camera import measured_pixels_to_normalized
    from ..core.known_points import match_layout

    if target_kind(spec.kind).size_pair is None:
        raise UsageError(NO_LAYOUT.format(spec.kind))
    if layout.shape[0] != reference_pixels.shape[0]:
        raise UsageError(f"--target-points {options.target_points} has {layout.shape[0]} points, the {spec.kind} target {reference_pixels.shape[0]}")
    if not np.all(np.isfinite(reference_pixels)):
        return layout  # the target is not whole in F*: the fit says so in its own words
    seen = measured_pixels_to_normalized(camera, reference_pixels)[:, 1:]
    try:
        return layout[match_layout(layout, seen)]
    except GeometryError as exc:
        raise InputError(f"--target-points {options.target_points}: {exc}") from None


def _fit(arrays: dict[str, np.ndarray], reference_index: int, camera: CameraIntrinsics, options: FitOptions, console: Console,
         name: str, spec: DetectorSpec, layout: np.ndarray | None = None, image_shift_px: float = 0.0,
         calibration: tuple[str, tuple[float, ...]] = ("exact", ())) -> DesiredFit:
    """:func:`~hbvs_cli.core.desired.fit_desired_trajectory` of the frames, its warnings on stderr, too little data
    said in the options' words (bench/demo_rounding.py wraps it). scipy is imported by the main thread, never by a
    second one: a stop signal inside an import can leave its lock held and the threads deadlocked."""
    from threadpoolctl import threadpool_limits

    # The target's parts of known shape (each marker's square, a board's grid), or the layout (--target-points).
    shapes = [(range(layout.shape[0]), layout)] if layout is not None else target_kind(spec.kind).shapes(spec)
    smoothing = parse_smoothing(options.smoothing)
    _load_solvers()  # (done already if read ahead) before BLAS is limited: threadpoolctl limits the libraries loaded
    try:
        # scipy's BLAS on one thread too: its threads made the decompositions of tall Jacobians slower, not faster.
        with threadpool_limits(limits=1, user_api="blas"):
            return fit_desired_trajectory(arrays["t"], arrays["pixels"], reference_index, camera, smoothing,
                                          max_lost=options.max_lost, max_gap=options.max_gap,
                                          warn=console.warn if layout is None else layout_given_warn(console.warn),
                                          shapes=shapes, errors=target_kind(spec.kind).errors, image_shift_px=image_shift_px,
                                          calibration_sigma=calibration[1], calibration_counted=calibration[0] != "unstated")
    except InsufficientDataError as exc:
        raise InputError(f"{name}: {_insufficient_data_message(exc, options)}") from None


def _calibration_uncertainty(reader: Any) -> tuple[str, tuple[float, ...]]:
    """How well the intrinsics are known: ``("exact", ())`` for a simulated teach, ``("stated", sigma)``, or
    ``("unstated", probe)``: a what-if error on fx, fy, cx and cy reported beside the band, not counted in it."""
    if reader.world_description is not None:
        return "exact", ()
    if reader.camera.sigma:
        return "stated", reader.camera.sigma
    return "unstated", (UNSTATED_CALIBRATION_PROBE_PX,) * 4


#: The fit's advice to give the target's geometry, which --target-points has given already.
KNOWN_GEOMETRY_ADVICE = "the target's known geometry (--target-size, or --target-points FILE for dots, markers or boards), "


def layout_given_warn(warn: Callable[[str], None]) -> Callable[[str], None]:
    """``warn`` for a fit given --target-points: its warnings no longer advise giving the target's geometry."""
    def told(message: str) -> None:
        warn(message.replace(KNOWN_GEOMETRY_ADVICE, "").replace("what would pin it:", "the layout is given (--target-points); what would pin it more:"))
    return told


def _insufficient_data_message(exc: InsufficientDataError, options: FitOptions) -> str:
    facts = exc.facts
    reason = facts.get("reason")
    if reason == "not_in_reference":
        return f"{exc}; choose another with --reference"
    if reason == "lost":
        return (f"the target is missing from {100 * facts['lost_fraction']:.0f} % of the frames "
                f"(more than --max-lost {100 * options.max_lost:.0f} %)")
    if reason == "gap":
        return (f"the target is missing from t = {facts['start']:.2f} s to {facts['end']:.2f} s ({facts['longest']:.2f} s), longer than "
                f"--max-gap {options.max_gap:g} s can bridge")
    return str(exc)


def _suggested_gains(result: DesiredFit, camera: CameraIntrinsics) -> GainSuggestion:
    """Gains from the median |x_hd1_dot| and the detector's noise (docs/method.md "Choosing the gains"), with the
    heading tolerance that theta_d's uncertainty allows (the report's default where that is larger)."""
    from ..core.gains import heading_tolerance, noise_from_residual, suggest_gains
    from ..report.build import DEFAULT_TOLERANCES

    noise_px = noise_from_residual(result.residual_px.rms, result.m_ref.shape[0])
    sigma_deg = float(np.degrees(np.max(result.uncertainty.smooth_theta_sigma))) if result.uncertainty is not None else float("nan")
    suggestion = suggest_gains(result.condition.percentiles["p50"], noise_px, result.m_ref, result.normal, camera.mean_focal)
    return replace(suggestion, heading_tolerance_deg=heading_tolerance(DEFAULT_TOLERANCES["heading_deg"], sigma_deg))


def _render_settings(reader: Any) -> SensorSettings | None:
    """The simulated sensor of the teach (:data:`~hbvs_cli.io.teach_file.RENDER_SETTINGS`), for repeat to reuse."""
    from ..io.teach_file import RENDER_SETTINGS

    settings = reader.info.get("settings") if reader.info else None
    if reader.world_description is None or not isinstance(settings, dict):
        return None
    return SensorSettings(**{key: float(settings[key]) for key in RENDER_SETTINGS if key in settings})


#: Frames ``--target auto`` looks at before it picks a kind.
AUTO_FRAMES = 5


def _kind_options(options: FitOptions) -> list[str]:
    """The kind options given: --marker-dict, --marker-id, --board."""
    return [name for name in ("marker_dict", "marker_id", "board") if getattr(options, name) is not None]


def _check_kind_options(options: FitOptions) -> None:
    """The kind options: only for a kind that takes them all; a known dictionary, an id in it, a board of 3x3 or more."""
    given = _kind_options(options)
    kinds = TARGET_KINDS.values() if options.target == "auto" else [target_kind(options.target)]
    if not any(set(given) <= kind.options for kind in kinds):
        refused = [name for name in given if options.target == "auto" or name not in target_kind(options.target).options]
        names = " and ".join("--" + name.replace("_", "-") for name in refused)
        raise UsageError(f"{names} {'is' if len(refused) == 1 else 'are'} not for --target {options.target}"
                         + (" (no one kind takes them all: choose --target)" if options.target == "auto" else ""))
    if options.board is not None:
        parse_board(options.board)
    if options.marker_dict is None and options.marker_id is None:
        return
    from ..perception.aruco import DEFAULT_DICTIONARY, dictionary_name, dictionary_size

    name = dictionary_name(options.marker_dict or DEFAULT_DICTIONARY)
    if options.marker_id is not None and not 0 <= options.marker_id < dictionary_size(name):
        raise UsageError(f"--marker-id {options.marker_id} is not in {name} (0-{dictionary_size(name) - 1})")


def _detector_spec(
    options: FitOptions, world: World | None, images: list[np.ndarray], camera: CameraIntrinsics, pose: Any, console: Console,
    sample: Callable[[], Iterator[tuple[float, np.ndarray]]],
) -> DetectorSpec:
    """What to detect: the world of a simulated teach says it, else the images (``--target auto``: candidates from the
    first few, judged on the frames ``sample()`` spreads over the drive, :mod:`.auto_target`; the pick said on stderr)."""
    kind = options.target
    given = set(_kind_options(options))
    if kind == "auto" and world is None:
        if given:  # the first kind registered that takes them all (checked before): markers for --marker-dict alone
            kind = next(name for name, taker in TARGET_KINDS.items() if given <= taker.options)
        else:
            candidates = target_candidates(images, camera, seed=options.seed)
            spec_of = lambda choice: spec_of_kind(choice.kind, choice.details, options, images, camera, console)  # noqa: E731
            best, reason = picked(judge(candidates, spec_of, sample(), camera, options.max_lost, options.seed),
                                  candidates, options.max_lost)
            console.info(f"--target auto picked {best.choice.kind}: {reason}")
            return best.spec
    elif kind == "auto":
        kind = world.target.kind
    if world is not None and world.target.kind != kind:
        raise UsageError(f"--target {kind} contradicts the recording, whose target is {world.target.kind}")
    return spec_of_kind(kind, {}, options, images, camera, console, world, pose)


def _taught_path(arrays: dict[str, np.ndarray], reference_index: int) -> Any:
    from ..core.fit_model import TaughtPath

    commands = arrays["command"]
    if not np.all(np.isfinite(commands)):
        commands = np.zeros_like(commands)
    poses = arrays["pose"]
    return TaughtPath(t=arrays["t"], v=commands[:, 0], w=commands[:, 1], start_pose=poses[0], reference_pose=poses[reference_index])


def _depth(result: DesiredFit, arrays: dict[str, np.ndarray], spec: DetectorSpec, options: FitOptions, console: Console,
           layout: np.ndarray | None = None) -> tuple[DepthEstimates, float, str]:
    """d* from the taught commands (25), --target-size (between the kind's ``size_pair``) or --target-points
    (``layout``: its two points farthest apart); dhat(0), the estimate of d*, and its source."""
    from_commands: DepthEstimate | None = None
    chosen: DepthEstimate | None = None
    commands = arrays["command"][result.span]
    if commands.size and np.all(np.isfinite(commands)):
        v, w = commands.T
        desired = result.trajectory.evaluate(arrays["t"][result.span])
        try:
            from_commands = depth_from_taught_commands(v, w, desired.x_hd2, desired.x_hd1_dot)
            chosen = from_commands
        except GeometryError as exc:
            console.warn(f"no depth from the taught commands: {exc}")
    pair = None
    if options.target_size is not None:
        size_pair = target_kind(spec.kind).size_pair
        if size_pair is None:
            raise UsageError(f"--target-size needs dots, markers or a board; a {spec.kind} target's points have no metric size")
        pair, scale = size_pair(spec, result.m_ref, result.normal)
        size = options.target_size * scale
    elif layout is not None:
        gaps = np.linalg.norm(layout[:, None, :] - layout[None, :, :], axis=-1)
        pair = tuple(int(k) for k in np.unravel_index(int(np.argmax(gaps)), gaps.shape))
        size = float(gaps[pair])
    if pair is not None:
        chosen = depth_from_target_size(result.m_ref, result.normal, pair, size)
    estimates = DepthEstimates(from_commands, chosen if pair is not None else None, pair)
    if chosen is None:
        console.warn(
            f"no taught commands, no --target-size and no --target-points: the initial depth estimate dhat(0) = {FALLBACK_DHAT0} m is a guess; "
            "the adaptive law (31) will learn d*, but give --dhat0 to repeat if you know better"
        )
        return estimates, FALLBACK_DHAT0, "guess"
    # A finite d* beyond repeat's --dhat0 bounds is refused here, in words about its source (no depth at all: the model's).
    if math.isfinite(chosen.dhat0) and chosen.dhat0 > 0 and not MIN_DEPTH <= chosen.dhat0 <= MAX_DEPTH:
        given, hint = (("the taught commands (25)", "are they in m/s and rad/s?") if chosen.source == "commands" else
                       ("--target-size" if options.target_size is not None else "--target-points", "is the size in metres?"))
        raise InputError(f"d* from {given} is {chosen.dhat0:.3g} m, outside the {MIN_DEPTH:g} to {MAX_DEPTH:g} m repeat accepts "
                         f"as --dhat0: {hint}")
    return estimates, float(chosen.dhat0), chosen.source


def _print_summary(console: Console, model: FitModel, result: DesiredFit, options: FitOptions) -> None:
    from rich.table import Table

    from ..core.gains import dhat0_range_text
    from ..report.build import DEFAULT_TOLERANCES

    frames = model.frames
    condition = result.condition
    table = Table(title=f"hbvs fit: {options.input} -> {options.output}", show_header=True, header_style="bold")
    table.add_column("quantity")
    table.add_column("value", justify="right")
    table.add_row("frames used / total", f"{frames.used} / {frames.total}")
    table.add_row("frames lost (not found / outliers)", f"{frames.lost} ({frames.lost - frames.outliers} / {frames.outliers})")
    table.add_row("longest gap bridged", f"{frames.longest_gap_s:.2f} s")
    table.add_row("target", f"{model.target_kind}, {model.m_ref.shape[0]} points")
    table.add_row("reference frame F*", f"{model.reference_index} (t = {model.reference_t:.2f} s)")
    table.add_row("residual (RMS / max)", f"{model.residual_px.rms:.3f} / {model.residual_px.max:.3f} px")
    table.add_row("plane normal n* (in F*)", "[" + ", ".join(f"{v:+.3f}" for v in model.normal) + f"]  margin {model.normal_margin:.3f}")
    if model.uncertainty is not None:
        u = model.uncertainty
        table.add_row("n* uncertainty (1 sigma)", f"{u.normal_sigma_deg:.2f} deg (point noise {u.point_noise_px:.3f} px)")
        if u.calibration == "unstated":
            table.add_row("calibration (not stated)", f"not counted; {UNSTATED_CALIBRATION_PROBE_PX:g} px would add {u.calibration_normal_sigma_deg:.2f} deg")
        elif u.calibration is not None:
            table.add_row("... of it from the calibration", f"{u.calibration_normal_sigma_deg:.2f} deg ({u.calibration})")
        if u.theta_d_sigma_deg is not None and u.x_hd1_sigma is not None:
            table.add_row("theta_d / x_hd1 sigma (median, max)",
                          f"{u.theta_d_sigma_deg.median:.3f}, {u.theta_d_sigma_deg.max:.3f} deg / "
                          f"{u.x_hd1_sigma.median:.1e}, {u.x_hd1_sigma.max:.1e}")
    lambdas = ", ".join(f"{name} {ch.smoothing:.3g}" for name, ch in model.trajectory.channels.items())
    table.add_row("spline smoothing lambda (s^3)", lambdas + (" (GCV)" if options.smoothing == "auto" else ""))
    table.add_row("x_hd2 from (25): residual RMS", f"{model.trajectory.x_hd2_residual_rms:.2e}")
    table.add_row("condition (35): min |x_hd1_dot|", f"{condition.min_abs_xhd1_dot:.4f} 1/s")
    table.add_row("|x_hd1_dot| p5 / median / p95", f"{condition.percentiles['p5']:.4f} / {condition.percentiles['p50']:.4f} / {condition.percentiles['p95']:.4f} 1/s")
    if model.depth.commands is not None:
        e = model.depth.commands
        table.add_row("d* from taught commands (25)", f"{e.dhat0:.3f} +- {e.standard_error:.3f} m")
    if model.depth.target_size is not None:
        given = "--target-size" if options.target_size is not None else "--target-points"
        table.add_row(f"d* from {given}", f"{model.depth.target_size.dhat0:.3f} m")
    source = model.dhat0_source
    if source == "target-size" and options.target_size is None:
        source = "--target-points"   # d* from the layout's two points farthest apart
    table.add_row("suggested dhat(0)", f"{model.dhat0:.3f} m ({source})")
    g = model.gains
    assert g is not None  # fit always suggests gains
    table.add_row(
        "suggested k_v, k_w, k_2, gamma",
        f"{g.gains.k_v:g}, {g.gains.k_w:g}, {g.gains.k_2:.0f}, {g.gains.gamma:.0f} (for {g.design_noise_px:.2f} px, {dhat0_range_text()})",
    )
    if g.heading_tolerance_deg > DEFAULT_TOLERANCES["heading_deg"]:
        table.add_row("suggested heading tolerance",
                      f"{g.heading_tolerance_deg:.2f} deg (95 % of theta_d's uncertainty: report --tolerance heading_deg={g.heading_tolerance_deg:.2f})")
    console.print(table)
    if condition.path_stops:
        percent = 100 * condition.stopped_fraction
        share = f"{percent:.0f}" if percent >= 1 else f"{percent:.1g}"  # a brief stop is not "0 %"
        console.warn(
            f"the taught path stops: |x_hd1_dot| < {condition.threshold:g} 1/s for {share} % of it "
            f"(longest {condition.longest_stop_s:.1f} s). The lateral error e2 cannot converge there (condition (35))"
        )
