"""Dark dots on a light poster: sub-pixel blob centres with identity kept by tracking.

Identity comes from an optimal, distance- and area-gated assignment of candidates to the
predicted positions, so it survives dots crossing; only a first detection sorts the dots
by row ``v`` then column ``u`` (or matches a lost target's last layout).
"""

from __future__ import annotations

import bisect
import math
from collections import Counter
from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np
from numpy.typing import NDArray

from ..errors import UsageError
from .base import (Detection, PointTrack, TargetDetector, as_gray, check_prediction, match_identity, optimal_assignment,
                   padded_box, plain_median)
from .target_kinds import TargetChoice, in_most

#: Cost of a forbidden candidate-to-point pairing in the assignment.
_FORBIDDEN = 1e12
_DILATE_RIM = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
_DILATE_RING = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (9, 9))


#: Dot polarities: ink on paper, or lights on a dark ground.
POLARITIES = ("dark", "light")
#: What the dots stand out in (see :func:`dark_image`); gray is tried first.
CONTRASTS = ("gray", "colour")


#: On first sight, dots may differ in area by this factor from their median (radii 3 to 8 cm
#: on one poster); tracking then follows each dot's own area.
ACQUIRE_AREA_RATIO = 9.0
#: Round blobs this many times smaller than the smallest of the larger ones are specks of
#: noise (:func:`speck_floor`).
SPECK_AREA_GAP = 4.0

def speck_floor(areas: NDArray[np.float64], keep: int = 3) -> float:
    """Area (px) below which round blobs are specks of noise, not dots: the first break of
    :data:`SPECK_AREA_GAP` in the areas sorted from the largest, below at least ``keep`` of
    them (the largest ``keep`` stand whatever their sizes); 0 without such a break."""
    ordered = np.sort(np.asarray(areas, dtype=np.float64))[::-1]
    breaks = np.flatnonzero(ordered[keep - 1:-1] >= SPECK_AREA_GAP * ordered[keep:]) + keep - 1
    return float(ordered[breaks[0]] / SPECK_AREA_GAP) if breaks.size else 0.0


#: Largest dot radius (px) the background estimate leaves out of the background.
MAX_DOT_RADIUS_PX = 80
#: Dark components under this many px are noise, not even counted.
MIN_AREA_PX = 6
#: Largest ratio of a dot's principal axes: 1 for a disc; one seen 50 deg off its normal gives ~1.55.
MAX_ELONGATION = 1.8
#: Below this contrast (gray levels) nothing is detected.
MIN_CONTRAST = 20.0


def dark_image(image: NDArray[np.uint8], polarity: str = "dark", contrast: str = "gray") -> NDArray[np.uint8]:
    """The one-channel frame in which the dots are dark (the negative for light dots, exact).

    ``"gray"``: the luminance. ``"colour"``: a BGR frame's darkest channel per pixel (its
    brightest, negated, for light dots), so a red dot on a grey wall of equal luminance
    shows. Gray is preferred: one JPEG channel carries the subsampled chroma's noise.
    """
    colour = isinstance(image, np.ndarray) and image.ndim == 3 and image.shape[2] in (3, 4) and image.dtype == np.uint8
    if contrast == "colour" and colour:
        blue, green, red = cv2.split(image)[:3]
        if polarity == "light":
            return cv2.bitwise_not(cv2.max(cv2.max(blue, green), red))
        return cv2.min(cv2.min(blue, green), red)
    gray = as_gray(image)
    return cv2.bitwise_not(gray) if polarity == "light" else gray


def flatten_ground(gray: NDArray[np.uint8], max_radius: int = MAX_DOT_RADIUS_PX, extrapolate_edges: bool = False) -> NDArray[np.float32]:
    """``gray`` with its ground's brightness divided out (float32, the ground at 255).

    The ground is a morphological closing wider than the largest dot (``max_radius`` px), at
    quarter resolution, so one threshold serves a bright centre and a vignetted corner.
    Near the edges the closing sees the ground on one side only and comes out too bright;
    ``extrapolate_edges`` first continues it by odd reflection (exact for a linear ramp).
    """
    height, width = gray.shape
    small = cv2.resize(gray, (max(width // 4, 1), max(height // 4, 1)), interpolation=cv2.INTER_AREA)
    size = 2 * (max_radius // 4) + 5
    if max(small.shape) <= size // 2 + 1:
        # The kernel spans the whole window: its closing is its maximum everywhere.
        ground = np.full(gray.shape, max(float(small.max()), 1.0), dtype=np.float32)
    else:
        kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (size, size))
        if extrapolate_edges:  # padded by the kernel's size
            extended = np.pad(small.astype(np.float32), size, mode="reflect", reflect_type="odd")
            closed = cv2.morphologyEx(extended, cv2.MORPH_CLOSE, kernel, borderType=cv2.BORDER_REPLICATE)[size:-size, size:-size]
        else:
            closed = cv2.morphologyEx(small, cv2.MORPH_CLOSE, kernel, borderType=cv2.BORDER_REPLICATE)
        ground = cv2.resize(cv2.max(closed, 1.0), (width, height), interpolation=cv2.INTER_LINEAR).astype(np.float32)
    return cv2.divide(gray.astype(np.float32), ground, scale=255.0)


@dataclass(frozen=True)
class Blobs:
    """Dark connected components of one frame (or window): sub-pixel ``centres`` (M, 2) ``(u, v)``
    in frame pixels (NaN rows where not dot-like), thresholded ``areas`` (M,) px, and (M,) bools:
    ``round`` (dot-like: compact, not elongated, not cut by the window's edge) and
    ``touches_edge`` (reaching the searched window's edge)."""

    centres: NDArray[np.float64]
    areas: NDArray[np.float64]
    round: NDArray[np.bool_]
    touches_edge: NDArray[np.bool_]


def otsu_threshold(gray: NDArray[np.uint8], clip_fraction: float = 0.01) -> int | None:
    """Threshold separating the darkest gray-level class of ``gray`` (Otsu, refined): pixels
    ``<= threshold`` are dark; None when the two classes' means differ by less than
    :data:`MIN_CONTRAST` (nothing stands out).

    The brightest ``clip_fraction`` of pixels is folded into one bin, so a highlight cannot
    become the bright class. While the dark class holds most pixels (a dark wall around a
    small poster) it is split again: dots are a small, dark minority.
    """
    hist = cv2.calcHist([gray], [0], None, [256], [0, 256]).ravel().astype(np.float64)
    total = hist.sum()
    top = int(np.searchsorted(np.cumsum(hist), (1.0 - clip_fraction) * total))
    hist[top] += hist[top + 1 :].sum()
    hist[top + 1 :] = 0.0
    threshold = _otsu_split(hist)
    for _ in range(2):
        if threshold is None or hist[: threshold + 1].sum() <= 0.5 * total:
            break
        inner = _otsu_split(hist[: threshold + 1])
        if inner is None:
            break
        threshold = inner
    return threshold


#: Ground noise (gray levels, 1 sigma, on the flattened scale) above which the window is
#: smoothed before it is thresholded. The simulated camera's default (2 levels) stays below.
NOISY_GROUND = 4.0
#: Noise (gray levels) that the smoothing of a noisy window aims to leave: a Gaussian of
#: sigma s px keeps 1 / (2 sqrt(pi) s) of white noise.
SMOOTHED_NOISE = 5.0
#: Widest smoothing (px): a dot of 2.5 px radius keeps half its contrast.
MAX_SMOOTHING_PX = 2.5
#: The threshold stays this many noise sigmas below the ground.
GROUND_NOISE_MARGIN = 5.0
#: A threshold less than this many levels below the flattened ground (255) is shallow: a
#: whole frame is then flattened again with its ground continued past its edges, whose
#: first estimate is too bright by about as much and gives specks counted as dots.
SHALLOW_THRESHOLD_DEPTH = 40.0


def ground_noise(flat: NDArray[np.float32], floor: float = 0.0) -> float:
    """Robust sigma (gray levels) of the sensor noise on a flattened window.

    The median absolute difference of horizontal neighbours on every fourth row, scaled to
    a Gaussian's sigma (1.4826 / sqrt 2); edges and dots do not move the median. A noise
    surely below ``floor`` is reported as ``floor``: a count of the differences above it
    decides that, cheaper than the median (segmentation only asks whether the noise
    exceeds :data:`NOISY_GROUND`).
    """
    rows = np.asarray(flat, dtype=np.float32)[::4]
    if rows.shape[1] < 2:
        return max(0.0, floor)
    differences = np.abs(rows[:, 1:] - rows[:, :-1]).ravel()
    scale = 1.4826 / math.sqrt(2.0)
    # The upper of the two middle values is at most the level (a margin far wider than
    # float32 rounding below it): so is the median.
    if floor > 0.0 and np.count_nonzero(differences > floor / scale * (1.0 - 1e-5)) <= differences.size - differences.size // 2 - 1:
        return floor
    return float(scale * plain_median(differences))


def _otsu_split(hist: NDArray[np.float64]) -> int | None:
    """Otsu's threshold of a histogram (bins = gray levels from 0), or None without contrast."""
    levels = np.arange(hist.size, dtype=np.float64)
    weight0 = np.cumsum(hist)
    mass0 = np.cumsum(hist * levels)
    weight1 = weight0[-1] - weight0
    with np.errstate(divide="ignore", invalid="ignore"):
        mean0 = mass0 / weight0
        mean1 = (mass0[-1] - mass0) / weight1
        between = weight0 * weight1 * (mean0 - mean1) ** 2
    between[~np.isfinite(between)] = -1.0
    threshold = int(np.argmax(between))
    if between[threshold] <= 0 or mean1[threshold] - mean0[threshold] < MIN_CONTRAST:
        return None
    return threshold


def segmentation_threshold(levels: NDArray[np.uint8], noise: float) -> tuple[NDArray[np.uint8], int | None]:
    """The 8-bit levels of a flattened image (ground at 255) to threshold, smoothed when the
    ground's ``noise`` (gray levels) is above :data:`NOISY_GROUND`, and the threshold: Otsu's, or
    half-way from the ground to the darkest (3x3-averaged) level if that is higher.

    Otsu misses a few 2-3 px dots; the half-way level (where a blurred disc's rim crosses
    its true radius) finds them. A noisy image takes the half-way level, kept
    :data:`GROUND_NOISE_MARGIN` times the noise smoothing leaves below the ground.
    """
    noisy = noise > NOISY_GROUND
    if noisy:
        # Segment a smoothed copy, or every speck becomes a blob; the centres are still
        # measured on the unsmoothed image.
        sigma = min(max(noise / (2.0 * math.sqrt(math.pi) * SMOOTHED_NOISE), 1.0), MAX_SMOOTHING_PX)
        levels = cv2.GaussianBlur(levels, (0, 0), sigma)
        noise /= 2.0 * math.sqrt(math.pi) * sigma
    darkest = float(cv2.blur(levels, (3, 3)).min())
    if 255.0 - darkest < MIN_CONTRAST:
        return levels, None
    halfway = int(0.5 * (255.0 + darkest))
    if noisy:
        # Otsu would split the ground's noise, and a threshold jumping between the two
        # would change the dots' areas (the tracker gates on them) from frame to frame.
        return levels, min(halfway, int(255.0 - GROUND_NOISE_MARGIN * noise))
    otsu = otsu_threshold(levels)
    return levels, halfway if otsu is None else max(otsu, halfway)


def find_dark_blobs(gray: NDArray[np.uint8], window: tuple[int, int, int, int] | None = None) -> Blobs:
    """Dark, dot-like blobs of ``gray`` (H, W) uint8 and their sub-pixel centres, thresholded
    and measured with the ground's brightness divided out (:func:`flatten_ground`: uneven lighting).

    ``window`` (x0, y0, x1, y1, end-exclusive px): searched alone (default: the whole frame);
    a dot is at most a quarter of the window.
    """
    height, width = gray.shape
    x0, y0, x1, y1 = window if window is not None else (0, 0, width, height)
    raw = np.ascontiguousarray(gray[y0:y1, x0:x1])
    empty = Blobs(np.empty((0, 2)), np.empty(0), np.empty(0, dtype=bool), np.empty(0, dtype=bool))
    if raw.size == 0:
        return empty
    for extrapolate_edges in (False, True):
        sub = flatten_ground(raw, extrapolate_edges=extrapolate_edges)
        levels, threshold = segmentation_threshold(np.clip(sub + 0.5, 0, 255).astype(np.uint8), ground_noise(sub, NOISY_GROUND))
        # Faint dots: the ground re-estimated continued past the frame's edges (not in a
        # tracked window, where a few noisy rows would extrapolate it worse).
        if window is not None or threshold is None or 255.0 - threshold >= SHALLOW_THRESHOLD_DEPTH:
            break
    if threshold is None:
        return empty
    return dot_like_blobs(sub, levels, threshold, [(x0, y0, x0 + sub.shape[1], y0 + sub.shape[0])], [0], [0.25 * sub.size])


def dot_like_blobs(flat: NDArray, levels: NDArray[np.uint8], threshold: float, windows: list[tuple[int, int, int, int]],
                   columns: list[int], max_areas: list[float]) -> Blobs:
    """The components of ``levels`` below ``threshold`` at least :data:`MIN_AREA_PX` large, and the
    dot-like ones' centres weighed in ``flat`` (:func:`_blob_centre`). Both hold the frame's
    ``windows`` (x0, y0, x1, y1) side by side, each from its column ``columns[i]`` (a frame, or
    one window of it: column 0). Not dot-like: a component reaching its window's edge, larger
    than ``max_areas[i]`` (px), elongated beyond :data:`MAX_ELONGATION`."""
    _, binary = cv2.threshold(levels, threshold, 255, cv2.THRESH_BINARY_INV)
    # BBDT: of OpenCV's labelling algorithms, the one that is fast on sparse foreground.
    _, labels, stats, _ = cv2.connectedComponentsWithStatsWithAlgorithm(binary, 8, cv2.CV_32S, cv2.CCL_BBDT)
    keep = np.flatnonzero(stats[1:, cv2.CC_STAT_AREA] >= MIN_AREA_PX) + 1
    centres = np.full((keep.size, 2), np.nan)
    areas = stats[keep, cv2.CC_STAT_AREA].astype(np.float64)
    round_ = np.zeros(keep.size, dtype=bool)
    touches = np.zeros(keep.size, dtype=bool)
    for k, label in enumerate(keep.tolist()):
        bx, by, bw, bh, area = stats[label].tolist()
        index = bisect.bisect_right(columns, bx) - 1  # the window whose columns hold the blob
        x0, y0, x1, y1 = windows[index]
        column, window_w, window_h = columns[index], x1 - x0, y1 - y0
        bx -= column
        touches[k] = bx == 0 or by == 0 or bx + bw == window_w or by + bh == window_h
        # Cheap box tests first: a disc fills ~pi/4 of its box.
        if touches[k] or area > max_areas[index] or area < 0.4 * bw * bh or max(bw, bh) > 3 * min(bw, bh):
            continue
        view = np.s_[:window_h, column : column + window_w]
        centre, elongation = _blob_centre(flat[view], labels[view], label, (bx, by, bw, bh))
        if elongation <= MAX_ELONGATION and math.isfinite(centre[0]) and math.isfinite(centre[1]):
            centres[k] = centre + (x0, y0)
            round_[k] = True
    return Blobs(centres, areas, round_, touches)


def _blob_centre(
    sub: NDArray[np.uint8], labels: NDArray[np.int32], label: int, box: tuple[int, int, int, int]
) -> tuple[NDArray[np.float64], float]:
    """Intensity-weighted centroid of one blob and its elongation.

    The weights are ``max(paper - I, 0)`` over the blob grown by 2 px (the anti-aliased
    rim); ``paper`` is the 75th percentile of a ring 2-4 px outside the blob, high enough to
    ignore a neighbouring dark region that reaches into the ring.
    """
    bx, by, bw, bh = box
    grow = 5
    px0, py0 = max(bx - grow, 0), max(by - grow, 0)
    px1, py1 = min(bx + bw + grow, sub.shape[1]), min(by + bh + grow, sub.shape[0])
    mask = np.equal(labels[py0:py1, px0:px1], label).view(np.uint8)  # 0 and 1, without a copy
    moments = cv2.moments(mask, binaryImage=True)
    # Principal second moments (eigenvalues of the 2x2 scatter matrix), in closed form.
    half_sum = 0.5 * (moments["mu20"] + moments["mu02"])
    half_gap = math.hypot(0.5 * (moments["mu20"] - moments["mu02"]), moments["mu11"])
    minor = half_sum - half_gap
    elongation = math.sqrt((half_sum + half_gap) / minor) if minor > 0 else np.inf
    rim = cv2.dilate(mask, _DILATE_RIM)
    ring = cv2.dilate(mask, _DILATE_RING) - rim  # the rim's kernel lies inside the ring's: 0 or 1
    patch = np.asarray(sub[py0:py1, px0:px1], dtype=np.float32)
    ring_values = patch[ring.view(bool)]
    if ring_values.size == 0:
        return np.full(2, np.nan), elongation
    paper = float(np.partition(ring_values, (3 * ring_values.size) // 4)[(3 * ring_values.size) // 4])
    weights = np.maximum(paper - patch, 0.0) * rim
    total = float(weights.sum())
    if total <= 0:
        return np.full(2, np.nan), elongation
    u = float(weights.sum(axis=0) @ np.arange(px0, px1)) / total
    v = float(weights.sum(axis=1) @ np.arange(py0, py1)) / total
    return np.array([u, v]), elongation


#: A candidate farther than this (px) from a dot's predicted position cannot be that dot.
GATE_PX = 20.0
#: Nor one whose area is outside these times the dot's averaged area (two merged dots).
AREA_RATIO = (0.5, 2.0)
#: An unseen dot is predicted through this many frames, then dropped.
MAX_COAST = 10


class DotDetector(TargetDetector):
    """Detect and track ``n_points`` (>= 3) dark dots, keeping their identity (gated by
    :data:`GATE_PX` and :data:`AREA_RATIO`). ``polarity`` and ``contrast``: one of
    :data:`POLARITIES` and of :data:`CONTRASTS` (:func:`dark_image`).
    """

    kind = "dots"

    def __init__(self, n_points: int, *, polarity: str = "dark", contrast: str = "gray") -> None:
        for what, value, choices in (("polarity", polarity, POLARITIES), ("contrast", contrast, CONTRASTS)):
            if value not in choices:
                raise UsageError(f"dot {what} must be one of {', '.join(choices)}, got {value!r}")
        self.polarity = polarity
        self.contrast = contrast
        if int(n_points) < 3:
            raise UsageError(f"a dot target needs at least 3 dots, got {n_points}")
        self.n_points = int(n_points)
        self._track = PointTrack(self.n_points, MAX_COAST)
        self._areas = np.full(self.n_points, np.nan)
        self._layout: NDArray[np.float64] | None = None

    def reset(self) -> None:
        """Forget the track, the dots' areas and their last known layout."""
        self.forget_position()
        self._layout = None

    def forget_position(self) -> None:
        """Forget the track and the dots' areas, keeping their last layout: found again, they keep their names."""
        self._track.reset()
        self._areas[:] = np.nan

    def detect(self, image: NDArray[np.uint8], predicted: NDArray[np.float64] | None = None) -> Detection:
        """Find the dots (:class:`~.base.TargetDetector`): with a prediction (given, or the track's),
        in a window around the predicted dots only; without one, in the whole frame."""
        gray = dark_image(image, self.polarity, self.contrast)
        prediction = check_prediction(predicted, self.n_points, self._track)
        if prediction is None:
            blobs = find_dark_blobs(gray)
            return self._record(blobs, *self._acquire(blobs))
        blobs = find_dark_blobs(gray, self._window(gray.shape, prediction))
        pixels, areas = self._assign(blobs, prediction)
        if not np.all(np.isfinite(pixels)):
            # Some dots were not where predicted: a whole-frame acquisition matched to
            # the prediction's (or the last full) layout brings them back.
            everywhere = find_dark_blobs(gray)
            again, again_areas = self._acquire(everywhere, prediction if np.all(np.isfinite(prediction)) else None)
            if np.all(np.isfinite(again)):
                blobs, pixels, areas = everywhere, again, again_areas
        return self._record(blobs, pixels, areas)

    def _record(self, blobs: Blobs, pixels: NDArray[np.float64], areas: NDArray[np.float64]) -> Detection:
        """Update the track, the dots' areas and their layout with one frame's dots."""
        seen = np.all(np.isfinite(pixels), axis=1)
        self._track.update(pixels)
        # Averaged: a small dot's area jumps with the threshold and would fail the gate.
        known = seen & np.isfinite(self._areas)
        self._areas[known] = 0.7 * self._areas[known] + 0.3 * areas[known]
        self._areas[seen & ~known] = areas[seen & ~known]
        found = bool(np.all(seen))
        if found:
            self._layout = pixels.copy()
        considered = int(blobs.areas.size)  # the components large enough to be looked at
        return Detection(pixels=pixels, found=found, candidates=considered, rejected=considered - int(np.count_nonzero(seen)))

    def _window(self, shape: tuple[int, int], prediction: NDArray[np.float64]) -> tuple[int, int, int, int]:
        """Search window: the predicted dots' box grown by the gate and a dot's size."""
        known = prediction[np.all(np.isfinite(prediction), axis=1)]
        areas = self._areas[np.isfinite(self._areas)]
        radius = float(np.sqrt(areas.max() / np.pi)) if areas.size else 30.0
        margin = GATE_PX + radius + 6.0
        x0, y0, x1, y1 = padded_box(known, margin, shape)
        return x0, y0, max(x1, x0), max(y1, y0)

    def _assign(self, blobs: Blobs, prediction: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Dots from candidates by gated minimum-cost assignment to the predictions."""
        pixels = np.full((self.n_points, 2), np.nan)
        areas = np.full(self.n_points, np.nan)
        candidates = np.flatnonzero(blobs.round)
        rows = np.flatnonzero(np.all(np.isfinite(prediction), axis=1))
        if candidates.size == 0 or rows.size == 0:
            return pixels, areas
        centres = blobs.centres[candidates]
        distance2 = np.sum((prediction[rows, None, :] - centres[None, :, :]) ** 2, axis=-1)
        allowed = distance2 <= GATE_PX**2
        expected = self._areas[rows]
        has_area = np.isfinite(expected)
        ratio = blobs.areas[candidates][None, :] / np.where(has_area, expected, 1.0)[:, None]
        allowed &= ~has_area[:, None] | ((ratio >= AREA_RATIO[0]) & (ratio <= AREA_RATIO[1]))
        cost = np.where(allowed, distance2, _FORBIDDEN)
        chosen_rows, chosen_cols = optimal_assignment(cost)
        crowded = self._crowded(prediction[rows], expected)
        keep = allowed[chosen_rows, chosen_cols] & ~crowded[chosen_rows]
        pixels[rows[chosen_rows[keep]]] = centres[chosen_cols[keep]]
        areas[rows[chosen_rows[keep]]] = blobs.areas[candidates[chosen_cols[keep]]]
        return pixels, areas

    @staticmethod
    def _crowded(prediction: NDArray[np.float64], areas: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Dots predicted to touch another (closer than their radii plus 2 px): their merged
        blob's centroid is neither's, so the track carries them until they part."""
        radius = np.sqrt(np.where(np.isfinite(areas), areas, 0.0) / np.pi)
        distance = np.linalg.norm(prediction[:, None, :] - prediction[None, :, :], axis=-1)
        touching = distance < radius[:, None] + radius[None, :] + 2.0
        np.fill_diagonal(touching, False)
        return np.any(touching, axis=1)

    def _acquire(self, blobs: Blobs, layout: NDArray[np.float64] | None = None) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Dots without any prediction: exactly N dot-like blobs, in canonical order, those of an area
        far from the others' median dropped first; none while not N (a guessed identity would be worse)."""
        pixels = np.full((self.n_points, 2), np.nan)
        areas = np.full(self.n_points, np.nan)
        candidates = np.flatnonzero(blobs.round)
        if candidates.size > self.n_points:
            median = np.median(blobs.areas[candidates])
            ratio = blobs.areas[candidates] / median
            candidates = candidates[(ratio >= 1.0 / ACQUIRE_AREA_RATIO) & (ratio <= ACQUIRE_AREA_RATIO)]
        if candidates.size > self.n_points and layout is None and self._layout is None:
            # On first sight, specks of noise that pass the area ratio (issue 44: 6 px beside
            # dots of 48-60 px, 20 gray levels dark under a shallow threshold) are dropped.
            # Not when found again after a loss: a faint dot far smaller than a distractor
            # would be dropped for it (25-level dots, seed 9: 8 frames lost, n* 39 deg off).
            candidates = candidates[blobs.areas[candidates] >= speck_floor(blobs.areas[candidates], keep=self.n_points)]
        if candidates.size != self.n_points:
            return pixels, areas
        centres = blobs.centres[candidates]
        layout = layout if layout is not None else self._layout
        order = np.lexsort((centres[:, 0], centres[:, 1])) if layout is None else match_identity(centres, layout)
        return centres[order], blobs.areas[candidates][order]


#: Around each dot, clipped pixels within this radius (px) are its core.
CLIPPED_CORE_RADIUS_PX = 12
#: A core of fewer clipped pixels than this is no core (a noise peak at the clip level).
MIN_CLIPPED_CORE_PX = 4
#: The dots are saturated when this fraction of their detections has a clipped core (the
#: LEDs of ``bright_dots``, drawn just below white, reach it in 12 %; with bloom, in 86 %).
SATURATED_FRACTION = 0.5


class SharedPull:
    """The pull (px) that every dot shares in every frame of a drive: the length of the mean
    offset of the dots' clipped cores (pixels at the sensor's limit: 255 for light dots, 0 for
    dark ones) from their measured centres over dots and frames, kept as running sums; 0
    unless the dots are saturated (a clipped core in at least :data:`SATURATED_FRACTION` of
    their detections). Why (bloom pulls every centroid alike, the flat clipped core less; issue
    44's LEDs, seed 7: 0.06-0.10 px against a bias of 0.11-0.13 px): docs/uncertainty.md."""

    def __init__(self, polarity: str = "dark", contrast: str = "gray") -> None:
        self.polarity, self.contrast = polarity, contrast
        self._sum, self._cores, self._detections = np.zeros(2), 0, 0

    def add(self, image: NDArray[np.uint8], pixels: NDArray[np.float64]) -> None:
        offsets = np.full((len(pixels), 2), np.nan)  # NaN rows: no clipped core, or not found
        radius = CLIPPED_CORE_RADIUS_PX
        for k, (u, v) in enumerate(np.asarray(pixels, dtype=float)):
            if not (np.isfinite(u) and np.isfinite(v)):
                continue
            x0, y0 = max(int(round(u)) - radius, 0), max(int(round(v)) - radius, 0)
            patch = dark_image(np.ascontiguousarray(image[y0:int(round(v)) + radius + 1, x0:int(round(u)) + radius + 1]),
                               self.polarity, self.contrast)
            rows, columns = np.nonzero(patch == 0)
            if rows.size >= MIN_CLIPPED_CORE_PX:
                offsets[k] = (columns.mean() + x0 - u, rows.mean() + y0 - v)
        seen = offsets[np.all(np.isfinite(offsets), axis=1)]
        self._sum += seen.sum(axis=0)
        self._cores += len(seen)
        self._detections += int(np.count_nonzero(np.all(np.isfinite(pixels), axis=1)))

    @property
    def pull_px(self) -> float:
        if self._cores == 0 or self._cores < SATURATED_FRACTION * self._detections:
            return 0.0
        return float(np.linalg.norm(self._sum / self._cores))


#: Dots targets have this many dots at most (and 3 at least).
MAX_DOTS = 10


def round_dots(image: NDArray[np.uint8], polarity: str, contrast: str = "gray") -> tuple[NDArray[np.float64], bool]:
    """Centres (N, 2) px of the round blobs of similar size in one frame, and whether they
    make up most of what is compact and interior (a textured picture has many dark shapes
    that are not round; components cut by the frame's edge are not counted)."""
    blobs = find_dark_blobs(dark_image(image, polarity, contrast))
    round_areas, centres = blobs.areas[blobs.round], blobs.centres[blobs.round]
    if round_areas.size < 3:
        return centres, False
    # Specks of noise far smaller than the dots count neither as dots nor against them.
    specks = speck_floor(round_areas)
    round_areas, centres = round_areas[round_areas >= specks], centres[round_areas >= specks]
    median = np.median(round_areas)
    similar = (round_areas >= median / ACQUIRE_AREA_RATIO) & (round_areas <= median * ACQUIRE_AREA_RATIO)
    interior = int(np.count_nonzero(~blobs.touches_edge & (blobs.areas >= max(0.1 * median, specks))))
    return centres[similar], int(similar.sum()) >= max(3, 0.75 * interior)


def find_dots(images: Sequence[NDArray[np.uint8]]) -> TargetChoice | None:
    """The same number of dots (3-10) in most of ``images``, dark ones first, in gray first
    (then in colour, when the frames have it), or None."""
    colour = any(np.ndim(image) == 3 for image in images)
    # In colour, light dots first: a dot that differs from a neutral wall in hue alone is
    # brighter than it in its own channel, and darker in the others only as far as it is saturated.
    order = [("gray", "dark"), ("gray", "light")] + ([("colour", "light"), ("colour", "dark")] if colour else [])
    for contrast, kind in order:
        dots = [round_dots(image, kind, contrast) for image in images]
        centres = [found if dominant and 3 <= len(found) <= MAX_DOTS else found[:0] for found, dominant in dots]
        tally = Counter(len(c) for c in centres if len(c))
        n_dots, frames = tally.most_common(1)[0] if tally else (0, 0)
        if frames and in_most(frames, len(images)):
            before = " (no dark dots)" if kind == "light" else ""
            details = {"polarity": kind, "n_points": n_dots}
            if contrast == "colour":
                channel = "darkest" if kind == "dark" else "brightest"
                before = f" in colour, on their {channel} channel (no dots stand out in gray)"
                details["contrast"] = contrast
            reason = f"{n_dots} {kind} round dots of comparable size in {frames} of the first {len(images)} frames{before}"
            return TargetChoice("dots", reason, details).measured_by(next(c for c in centres if len(c) == n_dots))
    return None
