"""The target-kind registry: a :class:`TargetKind` per detector, registered by the detector's
own module as it is imported (dots by :mod:`.dot_windows`). ``fit --target``'s choices, the
detectors of fit and repeat, the uncertainty's numbers (core receives a
:class:`~hbvs_cli.core.desired.DetectorErrors`, never a kind's name) and the target's known
shape come from here (docs/layout.md, "to add a target kind")."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Callable

import cv2
import numpy as np
from numpy.typing import NDArray

from ..core.camera import CameraIntrinsics
from ..core.depth import farthest_pair
from ..core.desired import DetectorErrors
from ..core.fit_model import DetectorSpec
from ..core.plane import KnownShape
from ..errors import InputError, UsageError


@dataclass(frozen=True)
class TargetChoice:
    """What ``--target auto`` picked: the ``kind``, one sentence for stderr (``reason``), the
    detector's ``details`` (``polarity``, ``n_points``, ``contrast``; ``marker_dict``,
    ``marker_ids``; ``board``), and the points seen: how many (texture: median matched
    features per frame), their RMS ``spread_px`` about their centroid and their convex hull's
    ``area_px`` (px^2)."""

    kind: str
    reason: str
    details: dict[str, Any] = field(default_factory=dict)
    n_points: int = 0
    spread_px: float = float("nan")
    area_px: float = 0.0
    #: The points seen (K, 2) px (texture: its matched features), for the own-print test.
    points: NDArray[np.float64] | None = field(default=None, repr=False, compare=False)

    @property
    def predicted_deg(self) -> float:
        """theta_d's predicted RMS error (deg): the kind's ``precision_scale`` over spread_px * sqrt(n_points)."""
        spread = self.spread_px * np.sqrt(self.n_points)
        return target_kind(self.kind).precision_scale / spread if spread > 0 else float("inf")

    def measured_by(self, points: NDArray[np.float64] | None) -> TargetChoice:
        """This choice with ``n_points``, ``spread_px`` and ``area_px`` of ``points`` (N, 2) px (NaN rows unseen)."""
        if points is None:
            return self
        seen = points[np.all(np.isfinite(points), axis=1)]
        spread = float(np.sqrt(np.mean(np.sum((seen - seen.mean(axis=0)) ** 2, axis=1))))
        return replace(self, n_points=len(seen), spread_px=spread, area_px=float(cv2.contourArea(cv2.convexHull(seen.astype(np.float32)))),
                       points=seen)


def in_most(count: int, frames: int) -> bool:
    """Whether ``count`` of ``frames`` is most of them (and two, of two or more): found consistently."""
    return count >= max(1, (frames + 1) // 2) and count >= min(frames, 2)


@dataclass(frozen=True)
class SpecRequest:
    """What a kind's :class:`DetectorSpec` is chosen from: the first ``images``, what ``--target
    auto`` found of it (``details``), the options (``board``: a board's squares), a simulated
    target's points as its first frame sees them (``seen_pixels`` (N, 2) px, None for footage;
    ``marker_id`` is then the world's), and ``info``, told what a user should know."""

    images: list[np.ndarray]
    camera: CameraIntrinsics
    details: dict[str, Any] = field(default_factory=dict)
    marker_dict: str | None = None
    marker_id: int | None = None
    board: tuple[int, int] | None = None
    seen_pixels: np.ndarray | None = None
    info: Callable[[str], None] = lambda text: None

    def found(self, choice: TargetChoice | None, what: str, advice: str, told: str = "") -> dict[str, Any]:
        """The ``details`` of what the kind's finder found in :attr:`images` (``choice``), its reason told after
        ``told`` when given; InputError (no ``what`` found consistently in the first frames, and ``advice``) for None."""
        if choice is None:
            raise InputError(f"no {what} found consistently in the first {len(self.images)} frames ({advice})")
        if told:
            self.info(f"{told}: {choice.reason}")
        return choice.details


@dataclass(frozen=True)
class TargetKind:
    """A kind of target (its fields: docs/layout.md, "A target kind"): ``name`` is a fit file's ``target_kind``;
    ``make(spec, template, seed, windowed)`` the detector; ``precision_scale``: theta_d's RMS error (deg) times
    its points' RMS spread (px) times the root of their number (``--target auto``, docs/targets.md);
    ``size_pair(spec, m_ref, normal)``: the points ``--target-size`` separates, in units of it (None: no metric
    size); ``uses_template``: tracked undistorted; ``image_shift(spec)``: an accumulator (``add(image, pixels)``,
    ``pull_px``) of an error all its points share, or None."""

    name: str
    spec: Callable[[SpecRequest], DetectorSpec]
    make: Callable[[DetectorSpec, np.ndarray | None, int, bool], Any]
    errors: DetectorErrors
    precision_scale: float
    complete: Callable[[DetectorSpec, np.ndarray], DetectorSpec] = lambda spec, image: spec
    shapes: Callable[[DetectorSpec], list[KnownShape]] = lambda spec: []
    size_pair: Callable[[DetectorSpec, np.ndarray, np.ndarray], tuple[tuple[int, int], float]] | None = (
        lambda spec, m_ref, normal: (farthest_pair(m_ref, normal), 1.0))
    options: frozenset[str] = frozenset()
    uses_template: bool = False
    image_shift: Callable[[DetectorSpec], Any] | None = None


#: Every target kind by name, in the order registered.
TARGET_KINDS: dict[str, TargetKind] = {}


def register_target_kind(kind: TargetKind) -> None:
    """Add (or replace) a target kind: ``fit --target`` offers it from then on."""
    TARGET_KINDS[kind.name] = kind


def target_kind(name: str) -> TargetKind:
    """The registered kind ``name``; UsageError naming the choices otherwise."""
    if name not in TARGET_KINDS:
        raise UsageError(f"unknown target kind {name!r}: choose one of {', '.join(TARGET_KINDS)}")
    return TARGET_KINDS[name]

