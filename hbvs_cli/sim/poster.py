"""The target's picture as a raster: the poster a renderer warps into the camera.

Poster coordinates ``(a, b)`` are metres from the top-left corner, ``a`` right, ``b`` down.
``cv2.pyrDown`` would shift each pyramid level by a quarter pixel (:meth:`PosterRaster.level_to_poster`
says where a level's pixels are), so :func:`build_pyramid` uses an even kernel instead.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from ..core.grayscale import as_gray
from .world import Target
from ..errors import InputError, UsageError

#: Gray levels of the poster's paper and of the ink (dots, marker cells).
PAPER_WHITE = 230
INK_BLACK = 20
#: Default level-0 resolution (px/m): every default poster a whole multiple of 2^6 pixels.
DEFAULT_PPM = 640.0
#: The pyramid stops once a level's longer side would drop below this (px).
MIN_LEVEL_SIZE = 8
#: Seed of the built-in texture: the pattern is part of the simulated world and must never change.
BUILTIN_TEXTURE_SEED = 20031027

_PYRAMID_KERNEL = np.array([1.0, 3.0, 3.0, 1.0], dtype=np.float32) / 8.0


@dataclass(frozen=True)
class PosterRaster:
    """A grayscale picture of a target's poster and its anti-aliasing pyramid.

    ``ppm``: level-0 raster px per metre of poster; ``levels[l]``: uint8 image of shape
    ``(ceil(H0 / 2^l), ceil(W0 / 2^l))``, ``(H0, W0) = round((height, width) ppm)`` (m).
    """

    kind: str
    ppm: float
    levels: tuple[NDArray[np.uint8], ...]
    width: float
    height: float

    @classmethod
    def from_target(cls, target: Target, texture: NDArray | None = None) -> "PosterRaster":
        """Draw the poster of ``target`` at :data:`DEFAULT_PPM`; ``texture`` (kind "texture" only): a
        loaded image stretched over it (None: the built-in pattern). InputError for an unusable
        texture, UsageError for a degenerate poster."""
        poster, ppm = target.poster, DEFAULT_PPM
        size = (int(round(poster.height * ppm)), int(round(poster.width * ppm)))
        if min(size) < 2:
            raise UsageError(f"a {poster.width} m x {poster.height} m poster at {ppm} px/m is too small to draw")
        if target.kind == "dots":
            base = _draw_dots(size, target.points_poster * ppm - 0.5, target.dot_radius * ppm)
        elif target.kind == "aruco":
            base = _draw_aruco(size, target.points_poster * ppm - 0.5, target.marker_id)
        elif target.kind == "texture":
            base = _builtin_texture(size) if texture is None else _fit_texture(texture, size)
        else:
            raise UsageError(f"unknown target kind {target.kind!r}")
        return cls(kind=target.kind, ppm=float(ppm), levels=build_pyramid(base), width=float(poster.width), height=float(poster.height))

    @property
    def image(self) -> NDArray[np.uint8]:
        """The level-0 picture, shape (H0, W0)."""
        return self.levels[0]

    def level_to_poster(self, level: int) -> NDArray[np.float64]:
        """Homography (3x3) from level-``level`` pixels to poster metres: ``(i + 0.5) 2^level / ppm``."""
        step = 2.0**level / self.ppm
        return np.array([[step, 0.0, 0.5 * step], [0.0, step, 0.5 * step], [0.0, 0.0, 1.0]])

    def level_for_scale(self, px_per_metre: float) -> int:
        """The level closest to the poster's magnification ``px_per_metre`` (camera px/m):
        one level pixel spans 0.7-1.4 camera pixels, enough for bilinear sampling not to alias."""
        if not np.isfinite(px_per_metre) or px_per_metre <= 0:
            return len(self.levels) - 1
        level = int(np.floor(np.log2(self.ppm / px_per_metre) + 0.5))
        return int(np.clip(level, 0, len(self.levels) - 1))


def build_pyramid(image: NDArray[np.uint8], min_size: int = MIN_LEVEL_SIZE) -> tuple[NDArray[np.uint8], ...]:
    """Halve ``image`` (H, W) uint8 with the centred ``[1, 3, 3, 1] / 8`` filter until the
    longer side would fall below ``min_size`` px; ``levels[0]`` is ``image``."""
    levels = [np.ascontiguousarray(image)]
    while max(levels[-1].shape) // 2 >= min_size:
        previous = levels[-1]
        # anchor=(1, 1): output j averages inputs j-1 .. j+2, i.e. it is centred on j + 0.5;
        # keeping the even outputs puts level-(l+1) pixel i on level-l coordinate 2i + 0.5.
        smooth = cv2.sepFilter2D(
            previous, -1, _PYRAMID_KERNEL, _PYRAMID_KERNEL, anchor=(1, 1), borderType=cv2.BORDER_REFLECT
        )
        levels.append(np.ascontiguousarray(smooth[::2, ::2]))
    return tuple(levels)


def _draw_dots(size: tuple[int, int], centres: NDArray[np.float64], radius: float) -> NDArray[np.uint8]:
    """Black discs on white paper, ``centres`` (N, 2) and ``radius`` in level-0 px, with
    radially symmetric anti-aliasing (coverage ``clip(radius - d + 0.5, 0, 1)``), so that the
    ink's centroid stays on the sub-pixel centre (``cv2.circle``'s does not)."""
    if radius <= 0:
        raise UsageError("a dot target needs a positive dot radius")
    height, width = size
    coverage = np.zeros(size, dtype=np.float64)
    reach = radius + 1.0
    for cx, cy in centres:
        x0, x1 = max(int(np.floor(cx - reach)), 0), min(int(np.ceil(cx + reach)) + 1, width)
        y0, y1 = max(int(np.floor(cy - reach)), 0), min(int(np.ceil(cy + reach)) + 1, height)
        if x0 >= x1 or y0 >= y1:
            continue
        xs = np.arange(x0, x1, dtype=np.float64) - cx
        ys = np.arange(y0, y1, dtype=np.float64)[:, None] - cy
        disc = np.clip(radius - np.hypot(xs, ys) + 0.5, 0.0, 1.0)
        np.maximum(coverage[y0:y1, x0:x1], disc, out=coverage[y0:y1, x0:x1])
    picture = PAPER_WHITE - (PAPER_WHITE - INK_BLACK) * coverage
    return np.round(picture).astype(np.uint8)


def _draw_aruco(size: tuple[int, int], corners: NDArray[np.float64], marker_id: int) -> NDArray[np.uint8]:
    """The DICT_4X4_50 marker ``marker_id`` with its outer corners on ``corners`` (4, 2,
    level-0 px, OpenCV order), warped there by 4 x 4 supersampling."""
    if corners.shape != (4, 2):
        raise UsageError(f"an ArUco target has 4 points (its corners), got {corners.shape[0]}")
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    if not 0 <= marker_id < 50:
        raise UsageError(f"ArUco id {marker_id} is not in DICT_4X4_50 (0-49)")
    factor = 4
    side = float(np.max(np.linalg.norm(corners - np.roll(corners, 1, axis=0), axis=1)))
    cells = 6
    marker_px = cells * max(1, int(np.ceil(factor * side / cells)))
    marker = cv2.aruco.generateImageMarker(dictionary, int(marker_id), marker_px, borderBits=1)
    # Marker image: outer corners at -0.5 and marker_px - 0.5 (pixel edges).
    edge = marker_px - 0.5
    source = np.array([[-0.5, -0.5], [edge, -0.5], [edge, edge], [-0.5, edge]], dtype=np.float64)
    # Supersampled raster: fine pixel X covers level-0 [X / f - 0.5, (X + 1) / f - 0.5], so its
    # centre is level-0 (X + 0.5) / f - 0.5, i.e. X = f (x + 0.5) - 0.5.
    fine = factor * (corners + 0.5) - 0.5
    x0, y0 = map(int, np.maximum(np.floor(corners.min(axis=0)) - 1, 0))
    x1, y1 = map(int, np.minimum(np.ceil(corners.max(axis=0)) + 2, size[::-1]))
    picture = np.full(size, PAPER_WHITE, dtype=np.uint8)
    if x0 >= x1 or y0 >= y1:
        return picture
    shift = np.array([[1.0, 0.0, -factor * x0], [0.0, 1.0, -factor * y0], [0.0, 0.0, 1.0]])
    to_fine = shift @ cv2.getPerspectiveTransform(source.astype(np.float32), fine.astype(np.float32))
    ink = np.where(marker > 127, PAPER_WHITE, INK_BLACK).astype(np.uint8)
    patch = cv2.warpPerspective(
        ink, to_fine, (factor * (x1 - x0), factor * (y1 - y0)),
        flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=PAPER_WHITE,
    )
    # INTER_AREA by an integer factor is a plain box average: level-0 pixel i is the mean of
    # fine pixels f i .. f i + f - 1, consistent with the mapping above.
    picture[y0:y1, x0:x1] = cv2.resize(patch, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)
    return picture


def _fit_texture(texture: NDArray, size: tuple[int, int]) -> NDArray[np.uint8]:
    """A caller-supplied image converted to gray uint8 and stretched to ``size`` (H, W)."""
    image = as_gray(texture, "the texture image")
    if min(image.shape) < 8:
        raise InputError(f"the texture image is too small ({image.shape[1]}x{image.shape[0]} px)")
    height, width = size
    shrinking = width < image.shape[1] or height < image.shape[0]
    interpolation = cv2.INTER_AREA if shrinking else cv2.INTER_CUBIC
    return cv2.resize(np.ascontiguousarray(image), (width, height), interpolation=interpolation)


def _builtin_texture(size: tuple[int, int]) -> NDArray[np.uint8]:
    """A deterministic, corner-rich gray pattern for the ``texture`` target: shapes 1/60 to
    1/4 of the longer side (corners at every distance of the default path), drawn at 2x."""
    rng = np.random.default_rng(BUILTIN_TEXTURE_SEED)
    height, width = size
    scale = 2
    canvas = np.full((height * scale, width * scale), 128, dtype=np.uint8)
    longer = max(height, width) * scale
    shift = 4  # cv2 drawing with 4 fractional bits
    one = 1 << shift

    def gray() -> int:
        return int(rng.integers(0, 256))

    def point() -> tuple[int, int]:
        return int(rng.uniform(0, width * scale) * one), int(rng.uniform(0, height * scale) * one)

    def length(low: float, high: float) -> float:
        return float(rng.uniform(low, high)) * longer

    # Large blocks first, then denser and smaller structure on top.
    for _ in range(30):
        x, y = point()
        w, h = int(length(0.06, 0.25) * one), int(length(0.06, 0.25) * one)
        cv2.rectangle(canvas, (x, y), (x + w, y + h), gray(), -1, cv2.LINE_AA, shift)
    for _ in range(140):
        centre = np.array(point(), dtype=np.float64)
        k = int(rng.integers(3, 7))
        angles = np.sort(rng.uniform(0, 2 * np.pi, k))
        radii = np.array([length(0.015, 0.07) for _ in range(k)]) * one
        poly = np.stack([centre[0] + radii * np.cos(angles), centre[1] + radii * np.sin(angles)], axis=1)
        cv2.fillPoly(canvas, [poly.astype(np.int32)], gray(), cv2.LINE_AA, shift)
    for _ in range(40):
        cv2.line(canvas, point(), point(), gray(), max(1, int(length(0.004, 0.012))), cv2.LINE_AA, shift)
    for _ in range(10):
        x, y = point()
        cell = length(0.015, 0.04)
        n = int(rng.integers(3, 7))
        dark, light = int(rng.integers(0, 100)), int(rng.integers(160, 256))
        for i in range(n):
            for j in range(n):
                x_ij, y_ij = x + int(i * cell * one), y + int(j * cell * one)
                corner = (x_ij + int(cell * one), y_ij + int(cell * one))
                cv2.rectangle(canvas, (x_ij, y_ij), corner, dark if (i + j) % 2 else light, -1, cv2.LINE_AA, shift)
    for _ in range(25):
        radius = int(length(0.015, 0.06) * one)
        cv2.circle(canvas, point(), radius, gray(), max(1, int(length(0.004, 0.01))), cv2.LINE_AA, shift)
    return cv2.resize(canvas, (width, height), interpolation=cv2.INTER_AREA)
