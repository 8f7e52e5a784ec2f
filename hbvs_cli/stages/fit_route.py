"""``hbvs fit`` on a route teach (issue 47): one detector per target, the drive split into
segments (:func:`~hbvs_cli.core.route.split_route`), each segment fitted by the single-target
fit in its target's own world (handed in by :mod:`.fit`) and each
transition estimated from both segments' splines over their overlap; written as a route file
(:mod:`hbvs_cli.io.route_file`).

Routes are simulated so far: a target's detector starts on the first frame whose recorded
pose sees it wholly and large (its points there are the simulated ``seen_pixels`` a
single-target fit also starts from) and looks for it while the pose has it in view."""

from __future__ import annotations

from typing import Any, Callable, Iterator

import numpy as np
from rich.table import Table

from ..core.fit_model import FitModel
from ..core.route import estimate_transitions, largest_view, split_route, view_spans
from ..errors import MalformedDataError, RecordingError
from ..io.fit_file import FILE_KIND
from ..io.messages import CAMERA_FRAME
from ..io.topics import CALIBRATION_TOPIC, TOPICS
from ..perception.target_kinds import SpecRequest, target_kind
from ..perception.tracked import TrackedDetector
from ..settings.commands import FitOptions
from ..sim.route_world import MIN_SPAN_PX, RouteWorld, recorded_route
from .console import Console


def is_route(world_description: Any) -> bool:
    """True for a teach file's route description (teach --route), as opposed to one target's."""
    return isinstance(world_description, dict) and "targets" in world_description


def fit_route_teach(reader: Any, writer: Any, frames: Iterator[Any], bar: Any, console: Console,
                    checked_frame: Callable[[Any, np.ndarray], Any], segment_model: Callable[..., FitModel],
                    options: FitOptions) -> list[FitModel]:
    """Fit the route of ``reader`` (its decoded ``frames``, each passed to ``checked_frame``)
    and write its route file into ``writer`` (metadata written already); the fit's summary on
    stderr. ``segment_model(arrays, reference_index, spec, world_description, name)``: the
    single-target fit of one segment's frames (:func:`.fit._segment_model`). The models, in order."""
    from ..io.calibration import calibration_to_foxglove
    from ..io.route_file import write_route

    camera = reader.camera
    try:
        route = recorded_route(reader.world_description, camera)
    except MalformedDataError as exc:
        raise RecordingError(f"{reader.name}: {exc}") from None
    detectors: list[TrackedDetector | None] = [None] * len(route.worlds)
    rows: list[tuple[float, int, Any, Any]] = []
    seen: list[list[np.ndarray]] = [[] for _ in route.worlds]
    for frame, _, image in frames:
        checked_frame(frame, image)
        if frame.pose is None:
            raise RecordingError(f"{reader.name}: frame {frame.index} has no pose: a route is fitted from a simulated teach")
        if not rows:
            writer.write(CALIBRATION_TOPIC, TOPICS[FILE_KIND][CALIBRATION_TOPIC], frame.log_time_ns,
                         calibration_to_foxglove(camera, CAMERA_FRAME, frame.log_time_ns))
        rows.append((frame.t, frame.log_time_ns, frame.pose, frame.command))
        for index, pixels in enumerate(_detected(route, detectors, image, np.asarray(frame.pose), options.seed, console)):
            seen[index].append(pixels)
        bar.advance()
    if not rows:
        raise RecordingError(f"{reader.name}: no complete image in the recording")
    t = np.array([row[0] for row in rows])
    log_time = np.array([row[1] for row in rows], dtype=np.int64)
    poses = np.array([row[2] for row in rows], dtype=float)
    commands = np.array([row[3] if row[3] is not None else (np.nan, np.nan) for row in rows], dtype=float)
    pixels = [np.array(points) for points in seen]
    spans = np.column_stack([view_spans(points) for points in pixels])
    try:
        segments = split_route(spans >= MIN_SPAN_PX, spans)
    except MalformedDataError as exc:
        raise RecordingError(f"{reader.name}: {exc}") from None
    models, references = [], []
    for segment in segments:
        frames_of = slice(segment.first, segment.last + 1)
        arrays = {"t": t[frames_of], "log_time": log_time[frames_of], "pixels": pixels[segment.target][frames_of],
                  "pose": route.local_pose(segment.target, poses[frames_of]), "command": commands[frames_of]}
        reference = largest_view(arrays["pixels"])
        models.append(segment_model(arrays, reference, detectors[segment.target].spec, route.worlds[segment.target].to_dict(),
                                    f"{reader.name} (segment {len(models) + 1})"))
        references.append(segment.first + reference)
    transitions = estimate_transitions(t, segments, [model.trajectory for model in models])
    write_route(writer, models, segments, references, transitions, [log_time[s.last] for s in segments], reader.name,
                reader.world_description, np.column_stack([t, poses]))
    _print_route_summary(console, route, segments, models, transitions, t, options)
    return models


def _detected(route: RouteWorld, detectors: list[TrackedDetector | None], image: np.ndarray, pose: np.ndarray, seed: int,
              console: Console) -> Iterator[np.ndarray]:
    """Each target's pixels in ``image`` (NaN where it is not in view or not found); a target's
    detector is made on the first frame that sees it wholly and at least :data:`MIN_SPAN_PX` across."""
    spans = route.spans(pose)
    for index, world in enumerate(route.worlds):
        points = int(world.target.points_world.shape[0])
        if detectors[index] is None and spans[index] >= MIN_SPAN_PX:
            local = route.local_pose(index, pose)
            request = SpecRequest([image], route.camera, marker_id=world.target.marker_id, seen_pixels=world.pixels(local),
                                  info=console.info)
            detectors[index] = TrackedDetector(target_kind(world.target.kind).spec(request), route.camera, seed=seed)
        detector = detectors[index]
        yield detector.detect(image) if detector is not None and spans[index] > 0 else np.full((points, 2), np.nan)


def _print_route_summary(console: Console, route: RouteWorld, segments: list[Any], models: list[Any], transitions: list[Any],
                         t: np.ndarray, options: FitOptions) -> None:
    """One row per segment: its target, span of the drive, F*_i, dhat(0) (d* as fit estimated it) and the transition into it."""
    table = Table(title=f"hbvs fit (route {route.name}): {options.input} -> {options.output}", header_style="bold")
    for column in ("segment", "target", "t (s)", "F* at (s)", "dhat(0) (m)", "rho = d*_i/d*_i-1", "heading (deg)"):
        table.add_column(column)
    for number, (segment, model) in enumerate(zip(segments, models)):
        into = transitions[number - 1] if number else None
        table.add_row(str(number + 1), f"{segment.target + 1} ({model.target_kind})", f"{t[segment.first]:.1f}-{t[segment.last]:.1f}",
                      f"{model.reference_t:.1f}", f"{model.dhat0:.3f}",
                      "" if into is None else f"{into.depth_ratio:.3f} +- {into.depth_ratio_std:.3f}",
                      "" if into is None else f"{np.degrees(into.heading):.2f} +- {np.degrees(into.heading_std):.2f}")
    console.print(table)
