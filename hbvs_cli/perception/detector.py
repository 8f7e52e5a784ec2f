"""Choosing a detector: :func:`make_detector` for a target kind, :func:`guess_target_kind` for a frame."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .aruco import marker_ids_in_view
from .base import TargetDetector, as_gray
from .dots import find_dark_blobs
from ..core.fit_model import DetectorSpec
from .target_kinds import target_kind


def make_detector(
    kind: str,
    *,
    n_points: int,
    reference_image: NDArray[np.uint8] | None = None,
    reference_pixels: ArrayLike | None = None,
    seed: int = 0,
    windowed: bool = False,
    **options: Any,
) -> TargetDetector:
    """A detector of ``n_points`` points for a registered ``kind`` (:mod:`.target_kinds`).

    ``options``: the :class:`~hbvs_cli.core.fit_model.DetectorSpec` fields the kind takes
    (``marker_id``, ``marker_dict``, ``marker_ids``, ``polarity``, ``contrast``, ``board``);
    ``reference_image`` and the target's ``reference_pixels`` (N, 2) in it: a template kind's
    (texture; ``seed``: its robust sampling); ``windowed``: dots each in its own window.
    UsageError for an unknown kind or inconsistent arguments.
    """
    pixels = None if reference_pixels is None else np.asarray(reference_pixels, dtype=float)
    return target_kind(kind).make(DetectorSpec(kind, n_points=n_points, template_pixels=pixels, **options), reference_image, seed, windowed)


def guess_target_kind(image: NDArray[np.uint8]) -> str:
    """Which kind of target a frame shows: ``"aruco"`` if a marker is detected; ``"dots"`` if 3
    or more similar dark round blobs make up most of the dark structure; else ``"texture"``."""
    gray = as_gray(image)
    if marker_ids_in_view(gray):
        return "aruco"
    blobs = find_dark_blobs(gray)
    round_blobs = blobs.areas[blobs.round]
    if round_blobs.size >= 3:
        median = np.median(round_blobs)
        similar = int(np.count_nonzero((round_blobs > median / 3) & (round_blobs < median * 3)))
        # Components cut by the frame's edge (typically the wall) are not counted.
        interior = int(np.count_nonzero(~blobs.touches_edge))
        if similar >= 3 and similar >= 0.75 * interior:
            return "dots"
    return "texture"
