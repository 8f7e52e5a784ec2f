"""What every target detector shares: the :class:`Detection` it returns, the
:class:`TargetDetector` protocol, the :class:`PointTrack` it predicts with, and the point
identity (:func:`match_identity`). Pixels are OpenCV's, measured (distorted).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import UsageError
from ..core.assignment import optimal_assignment  # noqa: F401 - re-exported: the detectors take it from here
from ..core.grayscale import as_gray  # noqa: F401 - re-exported: the detectors take it from here


@dataclass(frozen=True)
class Detection:
    """The target points found in one frame: ``pixels`` (N, 2) ``(u, v)`` in the target's order,
    NaN rows where not found; ``found``: all N found and accepted; ``candidates`` considered
    and ``rejected`` as outliers."""

    pixels: NDArray[np.float64]
    found: bool
    candidates: int
    rejected: int


@runtime_checkable
class TargetDetector(Protocol):
    """What the pipeline needs from a detector of any target kind. The detectors subclass it for
    :meth:`reset`, which forgets their ``_track`` (a :class:`PointTrack`)."""

    kind: str
    n_points: int

    def reset(self) -> None:
        """Forget the tracking state (the next frame is searched as if it were the first)."""
        self._track.reset()

    def detect(self, image: NDArray[np.uint8], predicted: NDArray[np.float64] | None = None) -> Detection:
        """Find the target points in a gray or BGR uint8 ``image``; ``predicted`` (N, 2, NaN
        rows unknown) is where they are expected, else the detector's own track says."""


class PointTrack:
    """Constant-velocity prediction (px per frame) of N image points from their past measurements:
    a point unseen for more than ``max_coast`` frames is dropped, the track inactive once every point is.
    ``streak``: the frames in a row with every point seen (the velocity of each is known from 2 on)."""

    def __init__(self, n_points: int, max_coast: int = 10) -> None:
        self.n_points = int(n_points)
        self.max_coast = int(max_coast)
        self.reset()

    def reset(self) -> None:
        """Forget everything."""
        self._last = np.full((self.n_points, 2), np.nan)
        self._velocity = np.zeros((self.n_points, 2))
        self._since = np.zeros(self.n_points, dtype=np.int64)
        self.streak = 0

    @property
    def active(self) -> bool:
        """True while at least one point is tracked."""
        return bool(np.any(self._alive()))

    def _alive(self) -> NDArray[np.bool_]:
        return np.all(np.isfinite(self._last), axis=1) & (self._since <= self.max_coast)

    def predict(self) -> NDArray[np.float64] | None:
        """Expected positions in the next frame, shape (N, 2) (NaN rows for dropped points),
        or None when the track is inactive."""
        alive = self._alive()
        every = alive.all()
        if not every and not alive.any():
            return None
        predicted = self._last + self._velocity * (self._since + 1)[:, None]
        if not every:
            predicted[~alive] = np.nan
        return predicted

    def update(self, measured: NDArray[np.float64]) -> None:
        """Record one frame's measurements, shape (N, 2) (NaN rows for points not seen)."""
        seen = np.all(np.isfinite(measured), axis=1)
        self._since += 1
        known = seen & np.all(np.isfinite(self._last), axis=1) & (self._since <= self.max_coast + 1)
        if known.all():  # every point seen again in time: the same updates, without the masks
            self._velocity = (measured - self._last) / self._since[:, None]
            self._last = np.array(measured, dtype=np.float64)
            self._since[:] = 0
            self.streak += 1
            return
        self._velocity[known] = (measured[known] - self._last[known]) / self._since[known][:, None]
        self._velocity[seen & ~known] = 0.0
        self._last[seen] = measured[seen]
        self._since[seen] = 0
        self.streak = self.streak + 1 if seen.all() else 0
        if not self.active:
            self.reset()


def check_prediction(predicted: ArrayLike | None, n_points: int, track: PointTrack | None = None) -> NDArray[np.float64] | None:
    """``predicted`` as an (N, 2) float array (NaN rows allowed), or, when it has no finite row,
    ``track``'s prediction (None without a track); UsageError for the wrong shape or infinities."""
    if predicted is not None:
        array = np.asarray(predicted, dtype=np.float64)
        if array.shape != (n_points, 2):
            raise UsageError(f"a prediction needs shape ({n_points}, 2), got {array.shape}")
        if np.any(np.isinf(array)):
            raise UsageError("a prediction may contain NaN rows but no infinities")
        if np.any(np.all(np.isfinite(array), axis=1)):
            return array
    return None if track is None else track.predict()


def search_window(shape: tuple[int, int], prediction: NDArray[np.float64], grow: float, min_size: int,
                  per_axis: bool = False) -> tuple[int, int, int, int] | None:
    """The predicted target's box (x0, y0, x1, y1) grown by ``grow`` times its size (its
    larger side, or each side with ``per_axis``) plus 16 px, clipped to the frame; None when
    fewer than two points are predicted or it is narrower than ``min_size`` px."""
    known = prediction[np.all(np.isfinite(prediction), axis=1)]
    if len(known) < 2:
        return None
    extent = np.ptp(known, axis=0)
    margin = grow * (extent if per_axis else np.full(2, np.max(extent))) + 16.0
    x0, y0, x1, y1 = padded_box(known, margin, shape)
    if x1 - x0 < min_size or y1 - y0 < min_size:
        return None
    return x0, y0, x1, y1


def padded_box(points: NDArray[np.float64], margin: ArrayLike, shape: tuple[int, ...]) -> tuple[int, int, int, int]:
    """The box (x0, y0, x1, y1, end-exclusive px) of ``points`` (N, 2) grown by ``margin`` px (one, or
    one per axis), clipped to an image of ``shape`` (H, W): x1 <= x0 (or y1 <= y0) when they lie beyond it."""
    x0, y0 = np.maximum(np.floor(points.min(axis=0) - margin), 0).astype(int).tolist()
    x1, y1 = np.minimum(np.ceil(points.max(axis=0) + margin) + 1, (shape[1], shape[0])).astype(int).tolist()
    return x0, y0, x1, y1


def signed_polygon_area(points: ArrayLike) -> float:
    """Signed area of a polygon (shoelace), shape (N, 2): positive when its vertices run
    counter-clockwise in x-right, y-up axes (clockwise on an image)."""
    points = np.asarray(points, dtype=np.float64)
    x, y = points[:, 0], points[:, 1]
    x_next, y_next = np.concatenate((x[1:], x[:1])), np.concatenate((y[1:], y[:1]))  # np.roll at a tenth of its cost
    return 0.5 * float(np.dot(x, y_next) - np.dot(x_next, y))


def match_identity(detected: ArrayLike, reference: ArrayLike) -> NDArray[np.intp]:
    """The permutation that puts detected points (N, 2) in reference order (``detected[permutation]``):
    the minimum total squared distance assignment once both sets are centred and scaled to unit
    RMS radius, so that a target seen nearer, farther or shifted still matches."""
    detected = np.asarray(detected, dtype=np.float64)
    reference = np.asarray(reference, dtype=np.float64)
    if detected.shape != reference.shape or detected.ndim != 2 or detected.shape[1] != 2:
        raise UsageError(f"cannot match {detected.shape} points against {reference.shape} reference points")
    if not (np.all(np.isfinite(detected)) and np.all(np.isfinite(reference))):
        raise UsageError("points to match must be finite")
    detected, reference = _normalized(detected), _normalized(reference)
    cost = np.sum((reference[:, None, :] - detected[None, :, :]) ** 2, axis=-1)
    rows, cols = optimal_assignment(cost)
    permutation = np.empty(len(reference), dtype=np.intp)
    permutation[rows] = cols
    return permutation


def _normalized(points: NDArray[np.float64]) -> NDArray[np.float64]:
    centred = points - points.mean(axis=0)
    spread = np.sqrt(np.mean(np.sum(centred**2, axis=1)))
    return centred / spread if spread > 0 else centred


def row_lengths(vectors: NDArray[np.float64]) -> NDArray[np.float64]:
    """The lengths of (K, 2) vectors (``np.linalg.norm(vectors, axis=1)`` without its overhead)."""
    return np.sqrt((vectors * vectors).sum(axis=1))


def plain_median(values: NDArray[np.floating]) -> np.floating:
    """``np.median`` of a 1-d array, in its dtype, without the generic wrapper (it runs on every frame)."""
    half = values.size // 2
    if values.size % 2:
        return np.partition(values, half)[half]
    low, high = np.partition(values, (half - 1, half))[half - 1 : half + 1]
    return (low + high) / 2
