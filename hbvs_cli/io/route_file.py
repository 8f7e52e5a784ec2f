"""The route file (issue 47), what ``hbvs fit`` writes for a route teach and ``hbvs repeat`` reads: a fit file with
one ``hbvs.FitModel`` per segment (each a single-target fit in its target's own world, :mod:`.fit_file`) and the
``/fit/route`` record (docs/files.md); a route of one segment writes none, so it is exactly a fit file."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from ..core.fit_model import FitModel
from ..core.route import RouteFit, Segment, Transition
from ..errors import RecordingError
from .fit_file import FILE_KIND, FitFile, checked_model_message
from .images import encode_image, write_compressed_image
from .messages import CAMERA_FRAME
from .mcap import time_message
from .teach_file import PARSE_ERRORS
from .topics import MODEL_TOPIC, ROUTE_TOPIC, TEMPLATE_IMAGE_TOPIC, TOPICS


@dataclass(frozen=True)
class RouteFile(RouteFit):
    """A route file read: a :class:`~..core.route.RouteFit` whose ``fits`` are each segment's model (:attr:`models`)."""

    #: The simulated route (the teach file's description) and its taught poses (K, 4): t (s), x, y, phi in its frame R.
    world: dict[str, Any] | None = None
    taught_poses: np.ndarray | None = None
    #: Each segment's detector template (compressed image bytes; None: its kind uses none, or a file from before they were kept).
    templates: tuple[bytes | None, ...] = ()

    @property
    def models(self) -> list[FitModel]:
        return self.fits


def _transition_from_record(record: dict[str, Any]) -> Transition:
    origin = np.asarray(record["origin_over_depth"], dtype=float)
    covariance = np.asarray(record["covariance"], dtype=float)
    ratio = float(record["depth_ratio"])
    if origin.shape != (2,) or covariance.shape != (3, 3) or not (math.isfinite(ratio) and ratio > 0):
        raise ValueError("a transition needs a positive depth_ratio, a 2-vector origin_over_depth and a 3x3 covariance")
    return Transition(ratio, *(float(record[name]) for name in ("depth_ratio_std", "heading", "heading_std")), origin, covariance,
                      int(record["frames"]), float(record["residual_rms"]))


def write_route(writer: Any, models: Sequence[FitModel], segments: Sequence[Segment], references: Sequence[int],
                transitions: Sequence[Transition], log_times: Sequence[int], source: str, world: dict[str, Any] | None = None,
                taught_poses: np.ndarray | None = None, templates: Sequence[np.ndarray | None] | None = None) -> None:
    """Each segment's model (stamped ``log_times[i]``, ns, its last frame's) checked as
    :func:`~.fit_file.checked_model_message` does, and its detector's template image
    (``templates[i]``, None for a kind without one; lossless), then the ``hbvs.Route`` message (one segment: none):
    the segments (frames of the drive; ``template``: the index of each one's template among the file's template
    images, or None), the transitions and, for a simulated route, its description and taught poses (what
    ``repeat --sim`` drives in and is judged against)."""
    schemas = TOPICS[FILE_KIND]
    indices: list[int | None] = []
    for model, stamp, template in zip(models, log_times, [None] * len(models) if templates is None else templates):
        writer.write(MODEL_TOPIC, schemas[MODEL_TOPIC], int(stamp), checked_model_message(model, int(stamp), source))
        if template is not None:
            write_compressed_image(writer, TEMPLATE_IMAGE_TOPIC, int(stamp), encode_image(template, "png"), "png", CAMERA_FRAME)
        indices.append(None if template is None else sum(index is not None for index in indices))
    if len(segments) > 1:
        writer.write(ROUTE_TOPIC, schemas[ROUTE_TOPIC], int(log_times[-1]), {
            "world": world, "taught_poses": None if taught_poses is None else np.asarray(taught_poses).tolist(),
            "timestamp": time_message(int(log_times[-1])),
            "segments": [{"target": s.target, "first": s.first, "last": s.last, "overlap_last": s.overlap_last,
                          "reference": int(r), "template": template} for s, r, template in zip(segments, references, indices)],
            # Each transition's fields as JSON numbers (heading in rad, origin over d*_i, the covariance of (u_1, u_2, rho)).
            "transitions": [{name: value.tolist() if isinstance(value, np.ndarray) else value
                             for name, value in vars(transition).items()} for transition in transitions],
        })


def route_of(fit: FitFile, name: str) -> RouteFile:
    """The models, segments and transitions of a fit file read (a single-target fit file: a
    route of one segment; ``name``: the file's, for messages); :class:`RecordingError` when its route record is malformed or inconsistent."""
    models, route = fit.segment_models, fit.route_record
    if route is None:
        return RouteFile([Segment(0, 0, models[0].frames.total - 1)], models, [models[0].reference_index], [],
                         templates=tuple(fit.templates[-1:]) or (None,))
    try:
        segments = [Segment(int(s["target"]), int(s["first"]), int(s["last"]),
                            None if s["overlap_last"] is None else int(s["overlap_last"])) for s in route["segments"]]
        references = [int(s["reference"]) for s in route["segments"]]
        transitions = [_transition_from_record(record) for record in route["transitions"]]
        taught = None if route.get("taught_poses") is None else np.asarray(route["taught_poses"], dtype=float).reshape(-1, 4)
        templates = tuple(None if s.get("template") is None else fit.templates[int(s["template"])] for s in route["segments"])
    except PARSE_ERRORS as exc:
        raise RecordingError(f"{name}: the route record is malformed: {exc}") from None
    if not len(segments) == len(models) == len(transitions) + 1:
        raise RecordingError(f"{name}: {len(models)} fit models for a route of {len(segments)} segments "
                             f"and {len(transitions)} transitions")
    return RouteFile(segments, models, references, transitions, route.get("world"), taught, templates)
