"""``--target auto`` judged on the whole drive (docs/targets.md, "Judged on the whole drive"), and the detector of a
target kind from what auto found or the options (fit's and a route's)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Callable, Iterable, Iterator, Sequence

import numpy as np

from ..core.camera import CameraIntrinsics
from ..core.desired import MIN_PARTIAL_POINTS, fit_desired_trajectory
from ..core.metrics import rms
from ..errors import HbvsError, InputError, InsufficientDataError, UsageError
from ..io.teach_file import TeachReader
from ..perception.autodetect import Candidates
from ..perception.target_kinds import TARGET_KINDS, SpecRequest, TargetChoice, target_kind
from ..perception.tracked import DetectorSpec, TrackedDetector
from ..settings.commands import FitOptions
from .console import Console
from .frame_decoding import decode_frame

#: Frames each candidate is followed on at most, evenly strided over the whole recording, by its own tracker from
#: frame to frame as the fit runs it (dots and chessboards keep their points' names).
FOLLOWED_FRAMES = 120
#: Of those, the frames the short joint estimate uses (evenly spread, the first as F*).
JUDGE_FRAMES = 24


class NoTargetThroughout(InputError):
    """No target the first frames show is usable over the whole drive: a route, maybe (:mod:`.fit_route`)."""


@dataclass(frozen=True)
class Judged:
    """One candidate followed over the drive: the frames it was ``seen`` in of ``frames``, and the RMS sigma of
    theta_d (deg) of its short joint estimate, or why it is not usable (``rejected``; then the sigma is NaN)."""

    choice: TargetChoice
    spec: DetectorSpec
    seen: int
    frames: int
    theta_sigma_deg: float = float("nan")
    rejected: str = ""


def followed_frames(source: str, frame_count: int | None, colour: bool, first: Sequence[tuple[float, np.ndarray]]
                    ) -> Iterator[tuple[float, np.ndarray]]:
    """``(t, image)`` of at most :data:`FOLLOWED_FRAMES` frames evenly strided over the recording ``source`` (read
    again), or its ``first`` frames when it cannot be read twice (stdin) or does not say how many frames it holds."""
    if source == "-" or frame_count is None or frame_count <= len(first):
        yield from first
        return
    stride = -(-frame_count // FOLLOWED_FRAMES)
    reader = TeachReader(source)
    for frame in reader.frames():
        if frame.index % stride == 0:
            yield frame.t, decode_frame(frame, reader.name, colour=colour)[1]


def judge(candidates: Candidates, spec_of: Callable[[TargetChoice], DetectorSpec],
          frames: Iterable[tuple[float, np.ndarray]], camera: CameraIntrinsics, max_lost: float, seed: int = 0) -> list[Judged]:
    """Every candidate followed by its own tracker over ``frames`` (``(t, image)``, read once) and judged, in order."""
    specs = [spec_of(choice) for choice in candidates.found]
    detectors: list[TrackedDetector | None] = [TrackedDetector(spec, camera, seed=seed) for spec in specs]
    failures = [""] * len(specs)
    times, pixels = [], [[] for _ in specs]
    for t, image in frames:
        times.append(t)
        for k, detector in enumerate(detectors):
            if detector is None:
                continue
            try:
                pixels[k].append(detector.detect(image))
            except HbvsError as exc:  # e.g. too few dots in the first frame for a dots target
                detectors[k], failures[k] = None, str(exc)
    judged = []
    for choice, spec, found, failure in zip(candidates.found, specs, pixels, failures):
        if failure:
            judged.append(Judged(choice, spec, 0, len(times), rejected=failure))
            continue
        spec, found = _markers_whole_in_the_first_frame(spec, np.stack(found))
        judged.append(_judged(choice, spec, np.asarray(times), found, camera, max_lost))
    return judged


def _markers_whole_in_the_first_frame(spec: DetectorSpec, pixels: np.ndarray) -> tuple[DetectorSpec, np.ndarray]:
    """Of several markers, those whole in the first frame (F*, which must show the whole target) and their pixels
    (F, 4M, 2); else as given (a 3x2 board under a barrel lens missed the very first in 3 seeds of 10)."""
    if not spec.marker_ids or len(spec.marker_ids) < 2:  # one marker, or a kind without markers
        return spec, pixels
    whole = np.all(np.isfinite(pixels[0].reshape(-1, 4, 2)), axis=(1, 2))
    if whole.all() or not whole.any():
        return spec, pixels
    ids = tuple(i for i, seen in zip(spec.marker_ids, whole) if seen)
    return (replace(spec, marker_ids=ids, n_points=4 * len(ids), marker_id=ids[0] if len(ids) == 1 else None),
            pixels[:, np.repeat(whole, 4)])


def _judged(choice: TargetChoice, spec: DetectorSpec, times: np.ndarray, pixels: np.ndarray,
            camera: CameraIntrinsics, max_lost: float) -> Judged:
    """One candidate's verdict from its pixels (F, N, 2) over the followed frames at ``times``."""
    frames = len(times)
    points_seen = np.sum(np.all(np.isfinite(pixels), axis=2), axis=1)
    seen = int(np.count_nonzero(points_seen >= min(pixels.shape[1], MIN_PARTIAL_POINTS)))
    if frames - seen > max_lost * frames:
        return Judged(choice, spec, seen, frames, rejected=f"missing from {frames - seen} of {frames} frames")
    rows = np.unique(np.linspace(0, frames - 1, min(JUDGE_FRAMES, frames)).round().astype(int))
    try:
        fit = fit_desired_trajectory(times[rows], pixels[rows], 0, camera, None, max_lost=1.0, max_gap=float("inf"),
                                     shapes=target_kind(spec.kind).shapes(spec), errors=target_kind(spec.kind).errors)
    except HbvsError as exc:
        not_whole = isinstance(exc, InsufficientDataError) and exc.facts.get("reason") == "not_in_reference"
        return Judged(choice, spec, seen, frames, rejected="not whole in the first frame" if not_whole else str(exc))
    if fit.uncertainty is None:
        return Judged(choice, spec, seen, frames, rejected="found in the first frame only")
    return Judged(choice, spec, seen, frames, theta_sigma_deg=float(np.degrees(rms(fit.uncertainty.theta_sigma[fit.used]))))


def picked(judged: Sequence[Judged], candidates: Candidates, max_lost: float) -> tuple[Judged, str]:
    """The usable candidate of the lowest sigma and the line that says why; InputError when none is usable."""
    usable = sorted((j for j in judged if not j.rejected), key=lambda j: j.theta_sigma_deg)
    frames = judged[0].frames if judged else 0

    def figures(j: Judged) -> str:
        if j.rejected:
            return f"{j.choice.kind} {j.rejected}" + (f" (more than --max-lost {100 * max_lost:.0f} %)" if j.rejected.startswith("missing") else "")
        return f"{j.choice.kind} {j.theta_sigma_deg:.2g} deg (found in {j.seen} of {j.frames} frames)"

    if not usable:
        raise NoTargetThroughout(f"--target auto: no target kind is found over the whole drive ({frames} frames followed): "
                         f"{'; '.join(figures(j) for j in judged)}. Choose one with --target {'|'.join(TARGET_KINDS)}")
    best = usable[0]
    others = "".join(f" vs {figures(j)}" for j in judged if j is not best)
    none_found = f"; no {' and no '.join(candidates.ruled_out)}" if candidates.ruled_out else ""  # the kinds looked for, not found
    reason = (f"{best.choice.reason}; followed over {frames} frames of the whole drive, a short joint estimate on up to {JUDGE_FRAMES} "
              f"of them gives theta_d a sigma of {figures(best).split(' ', 1)[1]}{others}{candidates.aside}{none_found}")
    return best, reason


def spec_of_kind(kind: str, details: dict[str, Any], options: FitOptions, images: list[np.ndarray], camera: CameraIntrinsics,
                 console: Console, world: Any = None, pose: Any = None) -> DetectorSpec:
    """The detector of a target ``kind`` from ``details`` (what ``--target auto`` found), the options, ``world`` or ``images``."""
    squares = parse_board(options.board) if options.board is not None else None
    seen = world.pixels(np.asarray(pose)) if world is not None and pose is not None else None
    request = SpecRequest(images, camera, details, options.marker_dict, world.target.marker_id if world is not None else options.marker_id,
                          squares, seen, info=console.info)
    return target_kind(kind).spec(request)


def parse_board(text: str) -> tuple[int, int]:
    """``--board COLUMNSxROWS`` (squares across and down, at least 3 each); UsageError otherwise."""
    parts = str(text).lower().replace(" ", "").split("x")
    if len(parts) != 2 or not all(p.isdigit() for p in parts) or min(int(p) for p in parts) < 3:
        raise UsageError(f"--board must be COLUMNSxROWS squares, at least 3 each (e.g. 6x4), got {text!r}")
    return int(parts[0]), int(parts[1])
