"""Dots followed in one small window each: the tracked detection of the closed loop.

A dot within :data:`WINDOW_GATE_PX` of its prediction lies whole in a small square around it:
those squares alone (merged where they overlap) find the same dots as the box around all of
them, reading (and needing rendered) a few percent of the pixels.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from ..core.desired import DetectorErrors
from ..core.fit_model import DetectorSpec
from ..errors import InputError
from .base import Detection, padded_box
from .dots import (NOISY_GROUND, Blobs, DotDetector, SharedPull, dark_image, dot_like_blobs, find_dark_blobs,
                   find_dots, flatten_ground, ground_noise, segmentation_threshold)
from .target_kinds import SpecRequest, TargetKind, register_target_kind

#: A pixel window ``(x0, y0, x1, y1)``, end-exclusive.
Window = tuple[int, int, int, int]

#: Radius (px) assumed for a dot whose area is not known yet (as the single window does).
UNKNOWN_RADIUS_PX = 30.0
#: Pixels between a dot's rim and its window's edge: the 5 px its centroid reads, and one more.
RIM_MARGIN_PX = 6.0
#: A tracked dot's window reaches this far (px) beyond its prediction (less than the detector's
#: gate); a dot that moved farther touches the edge and the whole frame is searched.
WINDOW_GATE_PX = 8.0


def merged_windows(windows: list[Window]) -> list[Window]:
    """Windows with every overlapping pair replaced by their bounding box, until none overlap."""
    merged = list(windows)
    while True:
        overlapping = ((i, j) for i, a in enumerate(merged) for j, b in enumerate(merged[i + 1:], i + 1)
                       if a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3])
        i, j = next(overlapping, (None, None))
        if i is None:
            return merged
        a, b = merged[i], merged.pop(j)
        merged[i] = (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3]))


#: Ground level of the flattened image (:func:`~.dots.flatten_ground`), which also fills the
#: columns that keep the windows apart in :func:`find_blobs_in_windows`.
GROUND_LEVEL = 255.0


class WindowMosaic:
    """A reusable buffer of flattened windows side by side, one column of ground between
    neighbours (no blob joins two windows) and ground below the shorter ones."""

    def __init__(self) -> None:
        self._buffer = np.empty((0, 0), dtype=np.float32)

    def layout(self, windows: list[Window]) -> tuple[NDArray[np.float32], list[int]]:
        """The mosaic for ``windows`` (filled with the ground) and each window's first column."""
        height = max(y1 - y0 for _, y0, _, y1 in windows)
        *columns, width = itertools.accumulate((x1 - x0 + 1 for x0, _, x1, _ in windows), initial=0)
        width -= 1
        if self._buffer.shape[0] < height or self._buffer.shape[1] < width:
            self._buffer = np.empty((max(height, self._buffer.shape[0]), max(width, self._buffer.shape[1])), dtype=np.float32)
        mosaic = self._buffer[:height, :width]
        mosaic.fill(GROUND_LEVEL)
        return mosaic, columns


def find_blobs_in_windows(gray: NDArray[np.uint8], windows: list[Window], mosaic: WindowMosaic) -> Blobs:
    """Dark, dot-like blobs in the non-overlapping ``windows`` of ``gray`` (H, W) uint8, as
    :func:`~.dots.find_dark_blobs` finds them in a flattened window.

    Each window's ground is divided out on its own; then one noise estimate (the windows'
    mean), one threshold and one labelling in ``mosaic`` serve them all."""
    empty = Blobs(np.empty((0, 2)), np.empty(0), np.empty(0, dtype=bool), np.empty(0, dtype=bool))
    windows = [w for w in windows if w[2] > w[0] and w[3] > w[1]]
    if not windows:
        return empty
    flat, columns = mosaic.layout(windows)
    views = [flat[: y1 - y0, column : column + x1 - x0] for (x0, y0, x1, y1), column in zip(windows, columns)]
    for view, (x0, y0, x1, y1) in zip(views, windows):
        view[...] = flatten_ground(np.ascontiguousarray(gray[y0:y1, x0:x1]))
    # The windows' mean noise decides whether to smooth (and by how much). ground_noise with
    # NOISY_GROUND as its floor skips the median of a window surely below it: when every
    # window is, so is the mean; else those windows' own values enter the mean too.
    noises = [ground_noise(view, NOISY_GROUND) for view in views]
    if any(noise > NOISY_GROUND for noise in noises):
        noises = [noise if noise > NOISY_GROUND else ground_noise(view) for noise, view in zip(noises, views)]
    noise = sum(noises) / len(noises)
    levels, threshold = segmentation_threshold(np.clip(flat + 0.5, 0, 255).astype(np.uint8), noise)
    if threshold is None:
        return empty
    areas = [(x1 - x0) * (y1 - y0) for x0, y0, x1, y1 in windows]  # a dot fills less than its window
    return dot_like_blobs(flat, levels, threshold, windows, columns, areas)


class WindowedDotDetector(DotDetector):
    """A :class:`~.dots.DotDetector` that, while every dot is tracked, first searches the
    windows of :meth:`search_windows`."""

    def __init__(self, n_points: int, **options) -> None:
        super().__init__(n_points, **options)
        self._mosaic = WindowMosaic()

    def search_windows(self, shape: tuple[int, int]) -> list[Window] | None:
        """The windows the next tracked detection reads, in an image of ``shape`` (H, W),
        or None when a dot has no prediction (the next frame is searched whole)."""
        prediction = self._track.predict()
        if prediction is None or not np.all(np.isfinite(prediction)):
            return None
        radii = np.sqrt(self._areas / math.pi)
        windows = []
        for point, radius in zip(prediction[:, None], radii.tolist()):
            margin = WINDOW_GATE_PX + (radius if math.isfinite(radius) else UNKNOWN_RADIUS_PX) + RIM_MARGIN_PX
            x0, y0, x1, y1 = padded_box(point, margin, shape)
            if x0 >= x1 or y0 >= y1:
                return None
            windows.append((x0, y0, x1, y1))
        return merged_windows(windows)

    def detect_in_windows(self, image: NDArray[np.uint8], windows: list[Window]) -> Detection | None:
        """The tracked dots found in ``windows`` of ``image`` (the only pixels read), or None,
        with the track left as it was, unless every dot is found there."""
        prediction = self._track.predict()
        if prediction is None or not np.all(np.isfinite(prediction)):
            return None
        gray = dark_image(image, self.polarity, self.contrast)
        blobs = find_blobs_in_windows(gray, windows, self._mosaic)
        pixels, areas = self._assign(blobs, prediction)
        if not np.all(np.isfinite(pixels)):
            return None
        return self._record(blobs, pixels, areas)

    def detect(self, image: NDArray[np.uint8], predicted: NDArray[np.float64] | None = None) -> Detection:
        """Find the dots; see :class:`~.base.TargetDetector`. Without a given prediction,
        the tracked dots' own windows first."""
        windows = self.search_windows(image.shape[:2]) if predicted is None else None
        detection = None if windows is None else self.detect_in_windows(image, windows)
        return super().detect(image, predicted) if detection is None else detection


def _dots_spec(request: SpecRequest) -> DetectorSpec:
    """As many dots as a simulated target has, else as the first frames show them (None:
    counted in the first image)."""
    details = request.details
    if request.seen_pixels is None and not details:
        found = find_dots(request.images)
        details = found.details if found is not None else {}
    n_points = request.seen_pixels.shape[0] if request.seen_pixels is not None else details.get("n_points")
    return DetectorSpec(kind="dots", n_points=n_points, polarity=details.get("polarity"), contrast=details.get("contrast"))


def _counted(spec: DetectorSpec, image: np.ndarray) -> DetectorSpec:
    """The spec with its number of round dots, counted in the first image when not known."""
    if spec.n_points is not None:
        return spec
    blobs = find_dark_blobs(dark_image(image, spec.polarity or "dark", spec.contrast or "gray"))
    count = int(np.count_nonzero(blobs.round))  # a round blob has a finite centre
    if count < 3:
        raise InputError(f"found {count} {spec.polarity or 'dark'} dots in the first image; a dots target needs at least 3 (or choose --target)")
    return replace(spec, n_points=count)


# Round dots: no edge bias; theta_d 0.1 deg and x_hd1 2e-3 (the perception bounds); the
# saturated ones' shared pull (bloom) is measured over the drive.
register_target_kind(TargetKind(
    name="dots", spec=_dots_spec, complete=_counted,
    make=lambda spec, template, seed, windowed: (WindowedDotDetector if windowed else DotDetector)(
        int(spec.n_points), polarity=spec.polarity or "dark", contrast=spec.contrast or "gray"),
    errors=DetectorErrors("dots", expected_precision=(0.1, 2e-3)),
    precision_scale=10.3, image_shift=lambda spec: SharedPull(spec.polarity or "dark", spec.contrast or "gray"),
))
