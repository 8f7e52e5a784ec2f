"""The target-kind registry: one :class:`TargetKind` per detector, registered by the detector's
own module (dots in :mod:`.dot_windows`, :mod:`.aruco`, :mod:`.chessboard`, :mod:`.charuco`,
:mod:`.texture`). ``fit --target``'s choices, the detector ``fit`` and ``repeat`` make, the
uncertainty's numbers (core receives a :class:`~hbvs_cli.core.desired.DetectorErrors`, never a
kind's name) and the target's known shape all come from here (docs/layout.md: "to add a target
kind")."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Protocol

import numpy as np

from ..core.camera import CameraIntrinsics
from ..core.depth import farthest_pair
from ..core.desired import DetectorErrors
from ..core.fit_model import DetectorSpec
from ..core.plane import KnownShape
from ..errors import UsageError


@dataclass(frozen=True)
class SpecRequest:
    """What a kind's :class:`DetectorSpec` is chosen from: the first ``images`` and ``camera``,
    what ``--target auto`` found of it (``details``), the options given (``marker_dict``,
    ``marker_id``, ``board``: a board's squares), a simulated teach's target points as its first
    frame sees them (``seen_pixels`` (N, 2) px, None for real footage; ``marker_id`` is then
    the world's), ``find()``: what a look at the first images finds of the kind
    (:func:`~.autodetect.find_target`, None: nothing), and ``info``, told what a user should know."""

    images: list[np.ndarray]
    camera: CameraIntrinsics
    details: dict[str, Any] = field(default_factory=dict)
    marker_dict: str | None = None
    marker_id: int | None = None
    board: tuple[int, int] | None = None
    seen_pixels: np.ndarray | None = None
    find: Callable[[], Any] = lambda: None
    info: Callable[[str], None] = lambda text: None


class ImageShift(Protocol):
    """A detector's error shared by every point of every frame (dots' bloom), accumulated over
    the drive: :meth:`add` each frame, then :attr:`pull_px` (px)."""

    def add(self, image: np.ndarray, pixels: np.ndarray) -> None: ...

    @property
    def pull_px(self) -> float: ...


def _no_shapes(spec: DetectorSpec) -> list[KnownShape]:
    return []


def _farthest_points(spec: DetectorSpec, m_ref: np.ndarray, normal: np.ndarray) -> tuple[tuple[int, int], float]:
    return farthest_pair(m_ref, normal), 1.0


@dataclass(frozen=True)
class TargetKind:
    """A kind of target and everything hbvs knows of it.

    ``name``: ``--target NAME`` and the fit file's ``target_kind``; ``spec``: its detector's
    description from a :class:`SpecRequest`; ``make(spec, template, seed, windowed)``: the
    detector (``spec.n_points`` known; ``template``: the template image of a kind that
    ``uses_template``, tracked on undistorted images); ``complete(spec, image)``: the spec
    with what only the first image tells (how many dots, which marker); ``errors``: its bias
    and usual precision; ``precision_scale``: theta_d's RMS error (deg) times the points' RMS
    spread (px) times the square root of their number (``--target auto``'s comparison,
    docs/targets.md); ``shapes``: its parts of known shape; ``size_pair(spec, m_ref, normal)``:
    the two points ``--target-size`` is the distance between, and that distance in units of
    the given size (None: its points have no metric size); ``options``: the fit options it
    takes (``marker_dict``, ``marker_id``, ``board``); ``points``: what its points are called;
    ``image_shift``: its shared error's accumulator, or None.
    """

    name: str
    spec: Callable[[SpecRequest], DetectorSpec]
    make: Callable[[DetectorSpec, np.ndarray | None, int, bool], Any]
    errors: DetectorErrors
    precision_scale: float
    complete: Callable[[DetectorSpec, np.ndarray], DetectorSpec] = lambda spec, image: spec
    shapes: Callable[[DetectorSpec], list[KnownShape]] = _no_shapes
    size_pair: Callable[[DetectorSpec, np.ndarray, np.ndarray], tuple[tuple[int, int], float]] | None = _farthest_points
    options: frozenset[str] = frozenset()
    points: str = "corners"
    uses_template: bool = False
    image_shift: Callable[[DetectorSpec], ImageShift] | None = None


#: Every target kind, by name, in the order registered.
TARGET_KINDS: dict[str, TargetKind] = {}


def register_target_kind(kind: TargetKind) -> TargetKind:
    """Add (or replace) a target kind; ``fit --target`` offers it from then on."""
    TARGET_KINDS[kind.name] = kind
    return kind


def target_kind(name: str) -> TargetKind:
    """The registered kind ``name``; UsageError naming the choices otherwise."""
    try:
        return TARGET_KINDS[name]
    except KeyError:
        raise UsageError(f"unknown target kind {name!r}: choose one of {', '.join(TARGET_KINDS)}") from None
