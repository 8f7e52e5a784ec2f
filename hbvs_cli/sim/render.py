"""Synthetic camera frames: the poster warped into the camera, with exposure, blur and noise.

The image model, in order: the poster's picture (the :class:`~.poster.PosterRaster` level of
about camera-pixel sized pixels, against aliasing) on a uniform wall; the lens distortion;
Gaussian blur; the sensor, ``gain * irradiance + offset`` plus Gaussian noise (white, or
correlated over ``noise_grain`` px), rounded to 8 bits. A target point is rendered at
``World.pixels(pose)`` (OpenCV pixels), distorted by :func:`~hbvs_cli.core.camera.distort_pixels`.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..core.camera import CameraIntrinsics, distort_pixels
from .world import World
from ..errors import InputError, UsageError
from .poster import PosterRaster

#: Poster corners closer to the camera plane than this (m) take the exact (slow) path that
#: masks rays meeting the wall behind the camera.
_NEAR_DEPTH = 1e-3
#: Camera pixels around the poster's projected outline rendered with it (the bilinear fringe).
_ROI_PAD = 2
#: A pixel window ``(x0, y0, x1, y1)``, end-exclusive.
Window = tuple[int, int, int, int]
#: Largest correlation length of the sensor noise (px): beyond it the "noise" is shading.
MAX_NOISE_GRAIN_PX = 20.0


@dataclass(frozen=True)
class RenderSettings:
    """Photometric settings of the simulated camera: the sensor noise's standard deviation
    (gray levels) and correlation length (the sigma, camera px, of the Gaussian that smooths
    it; 0 for white noise), the optical blur's sigma (camera px), the exposure's gain and
    offset (gray levels), and the wall's gray level before exposure (0-255)."""

    noise_std: float = 2.0
    blur_sigma: float = 0.0
    exposure_gain: float = 1.0
    exposure_offset: float = 0.0
    background: float = 150.0
    noise_grain: float = 0.0

    def __post_init__(self) -> None:
        values = (self.noise_std, self.blur_sigma, self.exposure_gain, self.exposure_offset, self.background, self.noise_grain)
        if not all(np.isfinite(v) for v in values):
            raise UsageError("render settings must be finite numbers")
        for value, name in ((self.noise_std, "noise standard deviation"), (self.blur_sigma, "blur sigma"),
                            (self.exposure_gain, "exposure gain")):
            if value < 0:
                raise UsageError(f"the {name} must be >= 0, got {value}")
        if not 0 <= self.noise_grain <= MAX_NOISE_GRAIN_PX:
            raise UsageError(f"the noise grain must be within 0-{MAX_NOISE_GRAIN_PX:g} px, got {self.noise_grain}")
        if not 0 <= self.background <= 255:
            raise UsageError(f"the wall's gray level must be within 0-255, got {self.background}")


@lru_cache(maxsize=1)
def _gaussian_table() -> NDArray[np.float32]:
    """Standard normal quantiles at the 65536 mid-bin probabilities, rescaled to unit variance:
    indexed by uniform 16-bit integers, Gaussian samples (tails to 4.3 sigma) faster than
    ``Generator.standard_normal``."""
    from scipy.special import ndtri

    table = ndtri((np.arange(65536, dtype=np.float64) + 0.5) / 65536.0)
    return (table / table.std()).astype(np.float32)


class SceneRenderer:
    """Render camera frames of a :class:`World` from robot poses; ``raster`` is drawn from
    ``world.target`` when omitted."""

    def __init__(self, world: World, raster: PosterRaster | None = None, settings: RenderSettings | None = None) -> None:
        self.world = world
        self.raster = raster if raster is not None else PosterRaster.from_target(world.target)
        self.settings = settings if settings is not None else RenderSettings()
        if self.raster.kind != world.target.kind:
            raise UsageError(f"the poster raster is for a {self.raster.kind!r} target, the world has {world.target.kind!r}")
        camera = world.camera
        self._size = (int(camera.height), int(camera.width))
        self._background = int(round(self.settings.background))
        self._wall = np.full(self._size, self._background, dtype=np.uint8)
        self._noise = np.zeros(self._size, dtype=np.float32)
        self._grain_kernel = _grain_kernel(self.settings.noise_grain) if self.settings.noise_grain > 0 else None
        self._ideal_map = _inverse_distortion_map(camera) if camera.has_distortion else None
        self._outlines: dict[int, NDArray[np.float64]] = {}

    def render(self, pose: ArrayLike, rng: np.random.Generator, exposure_gain: float | None = None) -> NDArray[np.uint8]:
        """One camera frame (height, width), uint8, seen from ``pose`` (x, y, phi) (m, m, rad),
        its noise from ``rng`` (nothing drawn without noise); ``exposure_gain`` overrides
        the settings' for this frame (an auto-exposure step)."""
        gain = self._gain(exposure_gain)
        scene = self.render_scene(pose)
        whole = (0, 0, self._size[1], self._size[0])
        noise = self._noise_in(rng, [whole])[0] if self.settings.noise_std > 0 else self._noise
        # One pass: gain * scene + noise_std * noise + offset, rounded and saturated to uint8.
        return cv2.addWeighted(
            noise, float(self.settings.noise_std), scene, gain, float(self.settings.exposure_offset), dtype=cv2.CV_8U
        )

    def render_scene(self, pose: ArrayLike) -> NDArray[np.uint8]:
        """The noiseless, unexposed scene (poster on the wall, lens, blur), shape (height, width), uint8."""
        view = self._view(pose)
        frame = self._wall.copy()
        # The patch reaches the blur's reach beyond the poster: blurring it equals blurring the frame.
        window = self._poster_box(view, _ROI_PAD + int(np.ceil(3.0 * self.settings.blur_sigma)))
        if window is not None:
            x0, y0, x1, y1 = window
            frame[y0:y1, x0:x1] = self._sampled(view, window)
        return frame

    def render_windows(
        self, pose: ArrayLike, rng: np.random.Generator, windows: Sequence[Window], exposure_gain: float | None = None
    ) -> NDArray[np.uint8]:
        """A camera frame rendered only inside ``windows`` (end-exclusive ``(x0, y0, x1, y1)``,
        not overlapping) as :meth:`render` would (the noise drawn for their pixels alone); the
        rest is the exposed wall without noise, not to be measured."""
        gain = self._gain(exposure_gain)
        settings = self.settings
        wall = float(np.clip(np.rint(gain * self._background + settings.exposure_offset), 0, 255))
        frame = np.full(self._size, wall, dtype=np.uint8)
        regions = [r for r in (_clipped(w, self._size) for w in windows) if r[0] < r[2] and r[1] < r[3]]
        if not regions:
            return frame
        view = self._view(pose)
        poster_box = self._poster_box(view)
        zeros = [self._noise[y0:y1, x0:x1] for x0, y0, x1, y1 in regions]
        noises = self._noise_in(rng, regions) if settings.noise_std > 0 else zeros
        for (x0, y0, x1, y1), noise in zip(regions, noises):
            scene = self._scene_in(view, poster_box, (x0, y0, x1, y1))
            cv2.addWeighted(noise, float(settings.noise_std), scene, gain, float(settings.exposure_offset),
                            dst=frame[y0:y1, x0:x1], dtype=cv2.CV_8U)
        return frame

    def _gain(self, exposure_gain: float | None) -> float:
        gain = self.settings.exposure_gain if exposure_gain is None else float(exposure_gain)
        if not np.isfinite(gain) or gain < 0:
            raise UsageError(f"the exposure gain must be a finite number >= 0, got {exposure_gain}")
        return gain

    def _view(self, pose: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.uint8], NDArray[np.float64], NDArray[np.float64]]:
        """What a frame from ``pose`` samples: the poster-to-image and level-to-image
        homographies, the level's picture, its outline (poster m) and the outline's depths."""
        pose = np.asarray(pose, dtype=float)
        if pose.shape != (3,) or not np.all(np.isfinite(pose)):
            raise UsageError(f"a pose is three finite numbers (x, y, phi), got {pose!r}")
        poster_to_image = self.world.poster_to_image_homography(pose)
        level = self.level_for(poster_to_image)
        level_to_image = poster_to_image @ self.raster.level_to_poster(level)
        outline = self._outline(level)
        depth = np.column_stack([outline, np.ones(len(outline))]) @ poster_to_image[2]
        return poster_to_image, level_to_image, self.raster.levels[level], outline, depth

    def _poster_box(self, view: tuple, pad: int = _ROI_PAD) -> Window | None:
        """The window the poster can cover in a frame of ``view``, ``pad`` px around it included
        (the whole image when unsure), or None when it covers none."""
        poster_to_image, _, _, outline, depth = view
        if np.all(depth <= _NEAR_DEPTH):
            return None
        if np.any(depth <= _NEAR_DEPTH):
            return (0, 0, self._size[1], self._size[0])
        ideal = _apply(poster_to_image, outline)
        if self._ideal_map is None:
            return _bounding_window(ideal, pad, self._size)
        width_height = np.array(self._size[::-1], dtype=float)
        if np.all((ideal >= -0.25 * width_height) & (ideal <= 1.25 * width_height)):  # the image grown by a quarter
            return _bounding_window(distort_pixels(self.world.camera, ideal), pad, self._size)
        # Far outside the image the lens polynomial can fold back: sample every pixel.
        return (0, 0, self._size[1], self._size[0])

    def _sampled(self, view: tuple, window: Window) -> NDArray[np.uint8]:
        """The noiseless, unexposed scene of ``view`` in ``window``, blurred (border replicated)."""
        _, level_to_image, picture, _, depth = view
        if np.any(depth <= _NEAR_DEPTH):
            patch = self._sample_masked(picture, level_to_image, window)
        elif self._ideal_map is None:
            patch = self._warp(picture, level_to_image, window)
        else:
            patch = self._remap(picture, level_to_image, window)
        if self.settings.blur_sigma > 0:
            patch = cv2.GaussianBlur(patch, (0, 0), self.settings.blur_sigma, borderType=cv2.BORDER_REPLICATE)
        return patch

    def _scene_in(self, view: tuple, poster_box: Window | None, window: Window) -> NDArray[np.uint8]:
        """The noiseless, unexposed scene inside ``window`` (within the image), equal to
        that window of :meth:`render_scene`'s frame up to the rounding of the sampling."""
        x0, y0, x1, y1 = window
        # Blurring a window needs the scene the kernel's reach around it.
        pad = int(np.ceil(3.0 * self.settings.blur_sigma))
        grown = _clipped((x0 - pad, y0 - pad, x1 + pad, y1 + pad), self._size)
        gx0, gy0, gx1, gy1 = grown
        # No pixel of the poster's box in the grown window (both end-exclusive): the wall alone.
        if poster_box is None or not (poster_box[0] < gx1 and gx0 < poster_box[2] and poster_box[1] < gy1 and gy0 < poster_box[3]):
            return self._wall[y0:y1, x0:x1]
        return self._sampled(view, grown)[y0 - gy0 : y1 - gy0, x0 - gx0 : x1 - gx0]

    def _noise_in(self, rng: np.random.Generator, windows: list[Window]) -> list[NDArray[np.float32]]:
        """Unit-variance sensor noise (float32) for each window, correlated by the grain:
        drawn over the window grown by the kernel's reach, in one draw from ``rng``."""
        reach = 0 if self._grain_kernel is None else len(self._grain_kernel) // 2
        grown = [_clipped((x0 - reach, y0 - reach, x1 + reach, y1 + reach), self._size) for x0, y0, x1, y1 in windows]
        sizes = [(gy1 - gy0) * (gx1 - gx0) for gx0, gy0, gx1, gy1 in grown]
        uniform = np.frombuffer(rng.bytes(2 * sum(sizes)), dtype=np.uint16)
        white = _gaussian_table().take(uniform)
        noises = []
        offset = 0
        for (x0, y0, x1, y1), (gx0, gy0, gx1, gy1), size in zip(windows, grown, sizes):
            noise = white[offset : offset + size].reshape(gy1 - gy0, gx1 - gx0)
            offset += size
            if self._grain_kernel is not None:
                noise = cv2.sepFilter2D(noise, -1, self._grain_kernel, self._grain_kernel, borderType=cv2.BORDER_REFLECT)
            noises.append(noise[y0 - gy0 : y1 - gy0, x0 - gx0 : x1 - gx0])
        return noises

    def level_for(self, poster_to_image: NDArray[np.float64]) -> int:
        """Pyramid level for a poster-to-image homography, from the magnification (camera px
        per poster metre) ``sqrt(|det J|)`` of its Jacobian at the target's centroid."""
        centre = np.mean(self.world.target.points_poster, axis=0)
        h = np.append(centre, 1.0) @ poster_to_image.T
        if h[2] <= _NEAR_DEPTH:
            return 0
        pixel = h[:2] / h[2]
        jacobian = (poster_to_image[:2, :2] - np.outer(pixel, poster_to_image[2, :2])) / h[2]
        return self.raster.level_for_scale(float(np.sqrt(abs(np.linalg.det(jacobian)))))

    def _outline(self, level: int) -> NDArray[np.float64]:
        """Points along the edge of the level's picture, in poster metres, shape (4 K, 2),
        made once per level: several a side, as lens distortion bows straight edges."""
        if level in self._outlines:
            return self._outlines[level]
        height, width = self.raster.levels[level].shape
        to_poster = self.raster.level_to_poster(level)
        # The picture's outer edges are half a level pixel beyond the first and last centres.
        a1 = to_poster[0, 0] * width
        b1 = to_poster[1, 1] * height
        t = np.linspace(0.0, 1.0, 9 if self._ideal_map is not None else 2)
        top = np.column_stack([t * a1, np.zeros_like(t)])
        right = np.column_stack([np.full_like(t, a1), t * b1])
        bottom = np.column_stack([(1 - t) * a1, np.full_like(t, b1)])
        left = np.column_stack([np.zeros_like(t), (1 - t) * b1])
        outline = self._outlines[level] = np.concatenate([top, right, bottom, left])
        return outline

    def _warp(self, picture: NDArray[np.uint8], level_to_image: NDArray[np.float64], window: Window) -> NDArray[np.uint8]:
        x0, y0, x1, y1 = window
        to_window = np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]]) @ level_to_image
        return cv2.warpPerspective(
            picture, to_window, (x1 - x0, y1 - y0),
            flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=self._background,
        )

    def _remap(self, picture: NDArray[np.uint8], level_to_image: NDArray[np.float64], window: Window) -> NDArray[np.uint8]:
        x0, y0, x1, y1 = window
        ideal = np.ascontiguousarray(self._ideal_map[y0:y1, x0:x1]).reshape(-1, 1, 2)
        source = cv2.perspectiveTransform(ideal, np.linalg.inv(level_to_image)).reshape(y1 - y0, x1 - x0, 2)
        return cv2.remap(
            picture, source, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=self._background
        )

    def _sample_masked(self, picture: NDArray[np.uint8], level_to_image: NDArray[np.float64], window: Window) -> NDArray[np.uint8]:
        """Sampling that blanks rays meeting the wall behind the camera (the third component of
        ``inv(H) [p, 1]``, ``1 / depth`` of the wall point, not positive)."""
        x0, y0, x1, y1 = window
        if self._ideal_map is None:
            u, v = np.meshgrid(np.arange(x0, x1, dtype=np.float64), np.arange(y0, y1, dtype=np.float64))
        else:
            u = self._ideal_map[y0:y1, x0:x1, 0].astype(np.float64)
            v = self._ideal_map[y0:y1, x0:x1, 1].astype(np.float64)
        inverse = np.linalg.inv(level_to_image)
        w = inverse[2, 0] * u + inverse[2, 1] * v + inverse[2, 2]
        ahead = w > 0
        safe = np.where(ahead, w, 1.0)
        # Off-picture coordinates for rays behind the camera: the border value (the wall).
        map_x, map_y = (np.where(ahead, (a * u + b * v + c) / safe, -10.0).astype(np.float32) for a, b, c in inverse[:2])
        return cv2.remap(picture, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=self._background)


def _apply(homography: NDArray[np.float64], points: NDArray[np.float64]) -> NDArray[np.float64]:
    h = np.column_stack([points, np.ones(len(points))]) @ homography.T
    return h[:, :2] / h[:, 2:]


def _clipped(window: Window, size: tuple[int, int]) -> Window:
    """``window`` clipped to an image of ``size`` (height, width)."""
    height, width = size
    x0, y0, x1, y1 = window
    return max(int(x0), 0), max(int(y0), 0), min(int(x1), width), min(int(y1), height)


def _bounding_window(points: NDArray[np.float64], pad: int, size: tuple[int, int]) -> Window | None:
    """The :data:`Window` around ``points``, clipped to the image; None when nothing of it is in the image."""
    low, high = np.floor(points.min(axis=0)) - pad, np.ceil(points.max(axis=0)) + pad + 1
    x0, y0, x1, y1 = _clipped((low[0], low[1], high[0], high[1]), size)
    return (x0, y0, x1, y1) if x0 < x1 and y0 < y1 else None


def _inverse_distortion_map(camera: CameraIntrinsics) -> NDArray[np.float32]:
    """For every real (distorted) pixel, the ideal pinhole pixel it sees, shape (H, W, 2): the
    inverse of :func:`distort_pixels`, ``cv2.undistortPoints`` iterated to convergence."""
    u, v = np.meshgrid(np.arange(camera.width, dtype=np.float64), np.arange(camera.height, dtype=np.float64))
    real = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
    coefficients = np.asarray(camera.distortion, dtype=np.float64)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
    undistort = cv2.fisheye.undistortPoints if camera.distortion_model == "equidistant" else cv2.undistortPoints  # a fisheye lens
    ideal = undistort(real, camera.K, coefficients, P=camera.K, criteria=criteria)
    return ideal.reshape(camera.height, camera.width, 2).astype(np.float32)


def load_texture(world: World) -> NDArray[np.uint8] | None:
    """The poster image of a texture target (None for the built-in pattern)."""
    if world.target.kind != "texture" or world.target.texture == "builtin":
        return None
    path = Path(world.target.texture)
    if not path.is_file():
        raise InputError(f"{path}: texture image not found")
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise InputError(f"{path}: not an image OpenCV can read")
    return image


def make_renderer(world: World, noise: float, blur: float, exposure: float, grain: float = 0.0) -> SceneRenderer:
    """The scene renderer of a world (shared by teach and repeat so both see alike)."""
    raster = PosterRaster.from_target(world.target, texture=load_texture(world))
    return SceneRenderer(world, raster, RenderSettings(noise_std=noise, blur_sigma=blur, exposure_gain=exposure, noise_grain=grain))


def _grain_kernel(grain: float) -> NDArray[np.float32]:
    """The 1D Gaussian (sigma ``grain`` px, 4 sigma each side) that correlates the noise,
    scaled so that unit-variance white noise keeps unit variance after both passes."""
    radius = max(int(np.ceil(4.0 * grain)), 1)
    kernel = cv2.getGaussianKernel(2 * radius + 1, grain, cv2.CV_64F).ravel()
    return (kernel / np.sqrt(np.sum(kernel**2))).astype(np.float32)
