"""``hbvs fit`` on a route teach (issue 47): one detector per target, the drive split into segments, each fitted
by the single-target fit in its target's own world, each transition estimated from both segments' splines over
their overlap. Without true poses (:class:`ImageFollower`) the targets are found in the images alone."""

from __future__ import annotations

from collections import deque
from dataclasses import replace
from typing import Any, Callable, Iterator

import cv2
import numpy as np
from rich.table import Table

from ..core.fit_model import FitModel
from ..core.route import bridge_brief_gaps, estimate_transitions, split_route, view_spans
from ..core.desired import MIN_PARTIAL_POINTS
from ..errors import HbvsError, InputError, MalformedDataError, RecordingError
from ..io.route_file import write_route
from ..perception.tracked import TrackedDetector, target_candidates
from ..report.table import print_table
from ..settings.commands import FitOptions
from ..sim.route_world import MIN_SPAN_PX, recorded_route
from .auto_target import spec_of_kind
from .console import Console
from .frame_decoding import FrameLog


def is_route(world_description: Any) -> bool:
    """True for a teach file's route description (teach --route), as opposed to one target's."""
    return isinstance(world_description, dict) and "targets" in world_description


def fit_route_teach(reader: Any, writer: Any, frames: Iterator[Any], bar: Any, console: Console,
                    segment_fit: Callable[..., tuple[Any, FitModel]], options: FitOptions) -> list[FitModel]:
    """Fit the route of ``reader`` (its decoded, checked ``frames``) into ``writer`` (metadata and calibration written
    already) and return the models, in order. ``segment_fit(arrays, reference_index, spec, world_description, name)``: one
    segment's fit and model (:func:`.fit._drive_fit`)."""
    follower: SimulatedFollower | ImageFollower | None = None
    log = FrameLog(0)
    for frame, _, image in frames:
        if follower is None:
            follower = (ImageFollower(reader.camera, options, console) if frame.pose is None
                        else SimulatedFollower(reader, options, console))
        if (frame.pose is None) != isinstance(follower, ImageFollower):
            raise RecordingError(f"{reader.name}: frame {frame.index} {'lacks' if frame.pose is None else 'has'} the true pose "
                                 "its first frame " + ("had" if frame.pose is None else "lacked"))
        log.add(frame.t, frame.log_time_ns, np.empty((0, 2)), frame.pose, frame.command)
        follower.add(image, frame.pose)
        bar.advance()
    assert follower is not None  # fit hands over a frame at least
    drive = log.arrays()
    t, log_time, poses = drive["t"], drive["log_time"], drive["pose"]
    pixels = follower.pixels()
    spans = np.column_stack([view_spans(points, MIN_PARTIAL_POINTS) for points in pixels])
    try:
        segments = split_route(bridge_brief_gaps(spans >= MIN_SPAN_PX, t, options.max_gap), spans)
    except MalformedDataError as exc:
        raise RecordingError(f"{reader.name}: {exc}") from None
    route = follower.route if isinstance(follower, SimulatedFollower) else None
    fits, models, references = [], [], []
    for segment in segments:
        frames_of = slice(segment.first, segment.last + 1)
        arrays = {name: column[frames_of] for name, column in drive.items()} | {"pixels": pixels[segment.target][frames_of]}
        if route is not None:
            arrays["pose"] = route.local_pose(segment.target, arrays["pose"])
        reference = int(np.argmax(view_spans(arrays["pixels"])))  # the nearer and larger, the better measured
        fit, model = segment_fit(arrays, reference, follower.detectors[segment.target].spec,
                                 None if route is None else route.worlds[segment.target].to_dict(), f"{reader.name} (segment {len(models) + 1})")
        fits.append(fit)
        models.append(model)
        references.append(segment.first + reference)
    transitions = estimate_transitions(t, segments, fits)
    write_route(writer, models, segments, references, transitions, [log_time[s.last] for s in segments], reader.name,
                reader.world_description, None if route is None else np.column_stack([t, poses]),
                [follower.detectors[s.target].template_image for s in segments])
    _print_route_summary(console, "images" if route is None else route.name, segments, models, transitions, t, options)
    return models


class SimulatedFollower:
    """Each target of the simulated route the teach ``reader`` recorded followed by its detector from the first frame that
    sees it wholly and large."""

    def __init__(self, reader: Any, options: FitOptions, console: Console) -> None:
        try:
            self.route = recorded_route(reader.world_description, reader.camera)
        except MalformedDataError as exc:
            raise RecordingError(f"{reader.name}: {exc}") from None
        self.options, self.console = options, console
        self.detectors: list[TrackedDetector | None] = [None] * len(self.route.worlds)
        self.seen: list[list[np.ndarray]] = [[] for _ in self.route.worlds]

    def add(self, image: np.ndarray, pose: Any) -> None:
        """Each target's pixels in ``image`` (NaN where it is not in view or not found)."""
        pose = np.asarray(pose)
        spans = self.route.spans(pose)
        for index, world in enumerate(self.route.worlds):
            points = int(world.target.points_world.shape[0])
            if self.detectors[index] is None and spans[index] >= MIN_SPAN_PX:
                spec = spec_of_kind(world.target.kind, {}, self.options, [image], self.route.camera, self.console, world,
                                    self.route.local_pose(index, pose))  # as a single target's simulated fit picks it
                self.detectors[index] = TrackedDetector(spec, self.route.camera, seed=self.options.seed)
            detector = self.detectors[index]
            self.seen[index].append(detector.detect(image) if detector is not None and spans[index] > 0 else np.full((points, 2), np.nan))

    def pixels(self) -> list[np.ndarray]:
        """Each target's pixels (frames, N, 2)."""
        return [np.array(points) for points in self.seen]


#: A target whose points come this near the image's edge (px) is lost, as a followed one is (tests/test_footage_routes.py).
EDGE_MARGIN_PX = 10.0
#: A target found again after a loss is its own only if an affine map of its last layout fits the new points this
#: well (largest residual over the points' span).
REFOUND_LAYOUT_TOLERANCE = 0.05


def affine_misfit(layout: np.ndarray, points: np.ndarray) -> float:
    """The largest residual of the affine map from ``layout`` to ``points`` (N, 2 each) over their span (0 for 3 points)."""
    design = np.column_stack([layout, np.ones(len(layout))])
    mapping, *_ = np.linalg.lstsq(design, points, rcond=None)
    return float(np.max(np.linalg.norm(design @ mapping - points, axis=1)) / max(view_spans(points[None])[0], 1e-9))


#: A photograph's detector takes a new template when its target appears this many times as large as in its template.
RETEMPLATE_GROWTH = 1.5
#: Frames an image-only route fit looks for new targets in at a time (and how often).
SEARCH_FRAMES = 8
#: A followed target is painted out of the searched frames this much beyond its points (fraction of their distance from their centre, and px).
PAINT_MARGIN = (0.3, 12.0)


class ImageFollower:
    """The targets of a drive found and followed from its images alone (no true pose; docs/results.md). Every detector
    runs on every frame, so that a target lost and seen again keeps its name."""

    def __init__(self, camera: Any, options: FitOptions, console: Console) -> None:
        self.camera, self.options, self.console = camera, options, console
        self.detectors: list[TrackedDetector] = []
        self.found: list[dict[int, np.ndarray]] = []
        self.recent: deque[tuple[int, np.ndarray]] = deque(maxlen=SEARCH_FRAMES)
        self.count = 0

    def add(self, image: np.ndarray, pose: Any = None) -> None:
        """Follow every target into ``image``; look for a new one every :data:`SEARCH_FRAMES` frames."""
        index, self.count = self.count, self.count + 1
        self.recent.append((index, image))
        for number, (detector, found) in enumerate(zip(self.detectors, self.found)):
            found[index] = self._trusted(detector, detector.detect(image), found.get(index - 1), found)
            self.detectors[number] = self._retemplated(detector, image, found[index])
        if index % SEARCH_FRAMES == SEARCH_FRAMES - 1:
            self._search()

    def _retemplated(self, detector: TrackedDetector, image: np.ndarray, points: np.ndarray) -> TrackedDetector:
        """``detector``, or for a photograph seen :data:`RETEMPLATE_GROWTH` times as large as in its template, one whose
        template is ``image`` at ``points``: a template far smaller than the view aligns poorly."""
        template = detector.spec.template_pixels
        if (not detector.kind.uses_template or template is None or not np.all(np.isfinite(points))
                or view_spans(points[None])[0] < RETEMPLATE_GROWTH * view_spans(np.asarray(template)[None])[0]):
            return detector
        spec = replace(detector.spec, template_pixels=points)
        return TrackedDetector(spec, self.camera, seed=self.options.seed, template_image=image)

    def _trusted(self, detector: TrackedDetector, points: np.ndarray, before: np.ndarray | None, found: dict[int, np.ndarray]) -> np.ndarray:
        """``points`` as found, or NaN when they cannot be the target's: a point within :data:`EDGE_MARGIN_PX` of the
        edge (the track is lost there: one followed out of the view drifts), or, found again after a loss, points
        whose layout no affine map of their last one explains (blobs of another target, not its dots)."""
        lost = np.full_like(points, np.nan)
        seen = np.all(np.isfinite(points), axis=1)
        if np.count_nonzero(seen) < MIN_PARTIAL_POINTS:
            return lost
        size = np.array([self.camera.width, self.camera.height], dtype=float)
        if np.any(points[seen] < EDGE_MARGIN_PX) or np.any(points[seen] > size - 1 - EDGE_MARGIN_PX):
            detector.lose_track()
            return lost
        if before is not None and np.isfinite(before).any():
            return points
        last = next((found[k] for k in sorted(found, reverse=True) if np.isfinite(found[k]).any()), None)
        both = seen if last is None else seen & np.all(np.isfinite(last), axis=1)
        return points if last is None or affine_misfit(last[both], points[both]) <= REFOUND_LAYOUT_TOLERANCE else lost

    def _search(self) -> None:
        """Follow the new targets the recent frames show in most of them: each part that stands out from its background
        and holds no followed target is searched alone (markers hide dots); a photograph only where no other kind is
        seen (a poster's own print), each once half :data:`MIN_SPAN_PX` across (smaller, a board's markers are not decoded)."""
        painted = [self._painted_out(index, image) for index, image in self.recent]
        centres = [np.nanmean(found[index], axis=0) for found in self.found for index, _ in self.recent
                   if index in found and np.isfinite(found[index]).any()]
        masks = [standing_out(image) for _, image in self.recent]  # a followed target's panel stays whole
        for region in parts(masks):
            if any(region[int(y), int(x)] for x, y in centres if 0 <= y < region.shape[0] and 0 <= x < region.shape[1]):
                continue  # a target followed already
            alone = [_alone(image, region & mask) for image, mask in zip(painted, masks)]
            try:
                found = target_candidates(alone[::2], self.camera, seed=self.options.seed).found
            except InputError:  # none there
                continue
            # photographs last, and none where another kind is seen (its own print, until that is large enough)
            printed = [choice for choice in found if choice.kind != "texture"] or found
            any(self._followed(choice, alone) for choice in printed
                if choice.points is not None and view_spans(choice.points[None])[0] >= MIN_SPAN_PX / 2)

    def _followed(self, choice: Any, alone: list[np.ndarray]) -> bool:
        """Whether ``choice``'s detector, started on the first recent frame ``alone``, finds it in most (then followed)."""
        try:
            spec = spec_of_kind(choice.kind, choice.details, self.options, alone, self.camera, self.console)
            detector = TrackedDetector(spec, self.camera, seed=self.options.seed, template_image=alone[0])
            detector.detect(alone[0])  # acquired alone, then followed in the frames as they are (the fill pulls points near it)
            found = {index: detector.detect(image) for index, image in self.recent}
        except HbvsError:  # e.g. too few dots for a dot target
            return False
        seen = [np.count_nonzero(np.all(np.isfinite(points), axis=1)) >= MIN_PARTIAL_POINTS for points in found.values()]
        if 2 * sum(seen) <= len(seen):
            return False
        self.detectors.append(detector)
        self.found.append(found)
        return True

    def _painted_out(self, index: int, image: np.ndarray) -> np.ndarray:
        """``image`` (recent frame ``index``) with every followed target's hull, grown by :data:`PAINT_MARGIN`, painted out."""
        painted = image.copy()
        for found in self.found:
            # where it was found in this frame, else in the nearest recent frame
            nearest = sorted((abs(k - index), k) for k, _ in self.recent if k in found and np.isfinite(found[k]).all(axis=1).sum() >= 3)
            if not nearest:
                continue
            points = found[nearest[0][1]]
            points = points[np.all(np.isfinite(points), axis=1)]
            centre = points.mean(axis=0)
            grown = centre + (points - centre) * (1 + PAINT_MARGIN[0]) + PAINT_MARGIN[1] * np.sign(points - centre)
            cv2.fillConvexPoly(painted, cv2.convexHull(grown.astype(np.int32)), np.atleast_1d(_background(image)).tolist())
        return painted

    def pixels(self) -> list[np.ndarray]:
        """Each target's pixels (frames, N, 2), NaN before it was found."""
        return [np.array([found.get(k, np.full((detector.spec.n_points, 2), np.nan)) for k in range(self.count)])
                for detector, found in zip(self.detectors, self.found)]


#: A part of an image stands out from its background when it differs from the image's median by this much (gray levels)...
STAND_OUT_LEVELS = 24
#: ... closing gaps of up to this many px, less this many px of its edge.
STAND_OUT_GAP_PX, STAND_OUT_EDGE_PX = 15, 3


def _background(image: np.ndarray, part: np.ndarray | None = None) -> np.ndarray:
    """The median level (gray) or colour of ``image`` (inside ``part``, a bool mask, when it holds any pixel)."""
    pixels = image[part] if part is not None and part.any() else image.reshape(-1, *image.shape[2:])
    return np.median(pixels, axis=0).astype(image.dtype)


def _alone(image: np.ndarray, part: np.ndarray) -> np.ndarray:
    """``image`` painted outside ``part`` (bool mask) in its median level inside: no edge where ``part`` ends."""
    return np.where(part if image.ndim == 2 else part[..., None], image, _background(image, part))


def standing_out(image: np.ndarray) -> np.ndarray:
    """Where ``image`` stands out from its background (bool, the image's shape), less its blurred edge (a dark line
    around a light poster that a dot detector would count)."""
    differs = np.abs(image.astype(np.int16) - _background(image).astype(np.int16)) > STAND_OUT_LEVELS
    differs = (differs.any(axis=2) if differs.ndim == 3 else differs).astype(np.uint8)
    closed = cv2.morphologyEx(differs, cv2.MORPH_CLOSE, np.ones((STAND_OUT_GAP_PX, STAND_OUT_GAP_PX), np.uint8))
    return cv2.erode(closed, np.ones((2 * STAND_OUT_EDGE_PX + 1,) * 2, np.uint8)).astype(bool)


def parts(masks: list[np.ndarray]) -> list[np.ndarray]:
    """The connected parts (bool masks) of the union of ``masks`` at least :data:`MIN_SPAN_PX` across."""
    count, labels, stats, _ = cv2.connectedComponentsWithStats(np.logical_or.reduce(masks).astype(np.uint8))
    return [labels == label for label in range(1, count)
            if max(stats[label, cv2.CC_STAT_WIDTH], stats[label, cv2.CC_STAT_HEIGHT]) >= MIN_SPAN_PX]


def _print_route_summary(console: Console, route_name: str, segments: list[Any], models: list[Any], transitions: list[Any],
                         t: np.ndarray, options: FitOptions) -> None:
    """One row per segment: its target, span of the drive, F*_i, dhat(0) (d* as fit estimated it) and the transition into it."""
    table = Table(title=f"hbvs fit (route {route_name}): {options.input} -> {options.output}", header_style="bold")
    for column in ("segment", "target", "t (s)", "F* at (s)", "dhat(0) (m)", "rho = d*_i/d*_i-1", "heading (deg)"):
        table.add_column(column)
    for number, (segment, model) in enumerate(zip(segments, models)):
        into = transitions[number - 1] if number else None
        table.add_row(str(number + 1), f"{segment.target + 1} ({model.target_kind})", f"{t[segment.first]:.1f}-{t[segment.last]:.1f}",
                      f"{model.reference_t:.1f}", f"{model.dhat0:.3f}",
                      "" if into is None else f"{into.depth_ratio:.3f} +- {into.depth_ratio_std:.3f}",
                      "" if into is None else f"{np.degrees(into.heading):.2f} +- {np.degrees(into.heading_std):.2f}")
    print_table(console, table, keys=2)
