"""Dots followed in one small window each: the tracked detection of the closed loop.

:class:`~.dots.DotDetector` follows its dots in one window, the box around all of them
grown by the gate, which for a target spread over the frame is most of it. A dot that
moved at most ``gate_px`` from its prediction lies, whole, in a square of half-side
``gate_px + radius + 6`` px around that prediction; searching those squares alone (merged
where they overlap, so that no blob is counted twice) finds the same dots, by the same
thresholding, centroids and gated assignment, reading a few percent of the pixels.

A renderer that knows the windows can render just them
(:meth:`hbvs_cli.sim.render.SceneRenderer.render_windows`); a frame where some dot is not
in its window falls back to the whole frame (:meth:`WindowedDotDetector.detect`), as the
single-window detector does.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from .base import Detection
from .dots import Blobs, DotDetector, dark_image, find_dark_blobs

#: A pixel window ``(x0, y0, x1, y1)``, end-exclusive.
Window = tuple[int, int, int, int]

#: Radius (px) assumed for a dot whose area is not known yet (as the single window does).
UNKNOWN_RADIUS_PX = 30.0
#: Pixels kept between a dot's rim and its window's edge: the 5 px its centroid reads around
#: the blob, and one more.
RIM_MARGIN_PX = 6.0


def merged_windows(windows: list[Window]) -> list[Window]:
    """Windows with every overlapping pair replaced by their bounding box, until none overlap."""
    merged = list(windows)
    changed = True
    while changed:
        changed = False
        for i in range(len(merged)):
            for j in range(i + 1, len(merged)):
                a, b = merged[i], merged[j]
                if a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]:
                    merged[i] = (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3]))
                    del merged[j]
                    changed = True
                    break
            if changed:
                break
    return merged


def joined(parts: list[Blobs]) -> Blobs:
    """The candidates of several windows as one :class:`~.dots.Blobs`."""
    if len(parts) == 1:
        return parts[0]
    return Blobs(
        np.concatenate([p.centres for p in parts]).reshape(-1, 2),
        np.concatenate([p.areas for p in parts]),
        np.concatenate([p.round for p in parts]),
        np.concatenate([p.touches_edge for p in parts]),
    )


class WindowedDotDetector(DotDetector):
    """A :class:`~.dots.DotDetector` that follows each dot in its own window.

    Takes the same parameters. While every dot is tracked, :meth:`detect` first searches
    the windows of :meth:`search_windows`; only when some dot is not found there does it
    search as :class:`~.dots.DotDetector` does (the dots' common box, then the whole
    frame).
    """

    def search_windows(self, shape: tuple[int, int]) -> list[Window] | None:
        """The windows the next tracked detection reads, in an image of ``shape`` (H, W),
        or None when a dot has no prediction (the next frame is searched whole)."""
        prediction = self._track.predict()
        if prediction is None or not np.all(np.isfinite(prediction)):
            return None
        height, width = shape
        radii = np.sqrt(self._areas / math.pi)
        windows = []
        for (u, v), radius in zip(prediction.tolist(), radii.tolist()):
            margin = self.gate_px + (radius if math.isfinite(radius) else UNKNOWN_RADIUS_PX) + RIM_MARGIN_PX
            x0, y0 = max(math.floor(u - margin), 0), max(math.floor(v - margin), 0)
            x1, y1 = min(math.ceil(u + margin) + 1, width), min(math.ceil(v + margin) + 1, height)
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
        # The window bounds a candidate's size; the area gate of the assignment does the rest.
        parts = [
            find_dark_blobs(gray, window, self.min_area, float((window[2] - window[0]) * (window[3] - window[1])),
                            self.max_elongation, self.min_contrast, True)
            for window in windows
        ]
        blobs = joined(parts)
        pixels, areas = self._assign(blobs, prediction)
        if not np.all(np.isfinite(pixels)):
            return None
        return self._record(blobs, pixels, areas)

    def detect(self, image: NDArray[np.uint8], predicted: NDArray[np.float64] | None = None) -> Detection:
        """Find the dots; see :class:`~.base.TargetDetector`. Without a given prediction,
        the tracked dots' own windows first."""
        if predicted is None:
            windows = self.search_windows(image.shape[:2])
            if windows is not None:
                detection = self.detect_in_windows(image, windows)
                if detection is not None:
                    return detection
        return super().detect(image, predicted)
