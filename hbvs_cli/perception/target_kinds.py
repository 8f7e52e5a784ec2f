"""The target-kind registry: a :class:`TargetKind` per detector, registered by the detector's
own module as it is imported (dots by :mod:`.dot_windows`). ``fit --target``'s choices, the
detectors of fit and repeat, the uncertainty's numbers (core receives a
:class:`~hbvs_cli.core.desired.DetectorErrors`, never a kind's name) and the target's known
shape come from here (docs/layout.md, "to add a target kind")."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from ..core.camera import CameraIntrinsics
from ..core.depth import farthest_pair
from ..core.desired import DetectorErrors
from ..core.fit_model import DetectorSpec
from ..core.plane import KnownShape
from ..errors import InputError, UsageError


@dataclass(frozen=True)
class SpecRequest:
    """What a kind's :class:`DetectorSpec` is chosen from: the first ``images``, what ``--target
    auto`` found of it (``details``), the options (``board``: a board's squares), a simulated
    target's points as its first frame sees them (``seen_pixels`` (N, 2) px, None for footage;
    ``marker_id`` is then the world's), ``find()``: what the first images show of the kind
    (:func:`~.autodetect.find_target`), and ``info``, told what a user should know."""

    images: list[np.ndarray]
    camera: CameraIntrinsics
    details: dict[str, Any] = field(default_factory=dict)
    marker_dict: str | None = None
    marker_id: int | None = None
    board: tuple[int, int] | None = None
    seen_pixels: np.ndarray | None = None
    find: Callable[[], Any] = lambda: None
    info: Callable[[str], None] = lambda text: None

    def found(self, what: str, advice: str, told: str = "") -> dict[str, Any]:
        """The ``details`` of what :attr:`find` finds, its reason told after ``told`` when given; InputError
        (no ``what`` found consistently in the first frames, and ``advice``) when it finds nothing."""
        found = self.find()
        if found is None:
            raise InputError(f"no {what} found consistently in the first {len(self.images)} frames ({advice})")
        if told:
            self.info(f"{told}: {found.reason}")
        return found.details


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

