"""The camera of ``repeat --sim``: one measurement per control period, with the faults asked
for. Pixel noise is added to the detected points too: a real detector's comes mostly from
what a renderer does not model (docs/results.md, "Under measurement noise")."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np

from ..core.camera import distort_pixels, normalized_to_pixels
from ..core.estimation import Observation, ObservationStatus, PlanarPoseEstimator, dropped
from ..core.fit_model import FitModel
from ..core.frames import world_to_robot
from .render import SceneRenderer, Window
from .scene import Scene, point_identity, renderer_for


@dataclass(frozen=True)
class CameraSettings:
    """What the simulated camera measures and which faults it suffers.

    ``pixel_noise``: px (1 sigma), added after tracking; ``seed``: of the sensor noise (with 1
    appended, of the faults); ``occlusions``: ``[start, end)`` (s) when the target is covered;
    ``drop_rate``, ``outlier_rate``: fractions of frames dropped, or with a spurious blob or a
    wrong point; ``exposure_step``: ``(t, gain)`` from ``t`` (s) on; ``record_images``: render
    images for the run file even with ``points`` perception.
    """

    perception: str
    pixel_noise: float = 0.0
    seed: int = 0
    occlusions: tuple[tuple[float, float], ...] = ()
    drop_rate: float = 0.0
    outlier_rate: float = 0.0
    exposure_step: tuple[float, float] | None = None
    record_images: bool = False


class PointDetector(Protocol):
    """What the camera runs on a rendered frame: the fit's detector, made by the stage
    (:func:`hbvs_cli.perception.tracked.detector_from_model` with ``windowed=True``, whose
    :class:`~hbvs_cli.perception.tracked.TrackedDetector` says what each method returns)."""

    def detect(self, image: np.ndarray) -> np.ndarray: ...

    def search_windows(self) -> list[Window] | None: ...

    def detect_in_windows(self, image: np.ndarray, windows: list[Window]) -> np.ndarray | None: ...


class SimulatedCamera:
    """The repeat's camera: ``perception="images"`` renders the scene and runs the fit's
    ``detector`` on it, ``"points"`` projects the target points; faults as :class:`CameraSettings`."""

    def __init__(
        self, scene: Scene, model: FitModel, settings: CameraSettings, estimator: PlanarPoseEstimator, detector: PointDetector | None,
    ) -> None:
        self.scene = scene
        self.model = model
        self.settings = settings
        self.estimator = estimator
        # The world's target points in the fit's order (as its detector first saw them).
        self._identity = [int(i) for i in point_identity(scene.world.pixels(scene.reference_pose), model.reference_pixels)]
        self._points_world = [tuple(float(v) for v in point) for point in scene.world.target.points_world]
        self._camera_height = float(scene.world.camera_height)
        self.noise_rng = np.random.default_rng(settings.seed)
        self.fault_rng = np.random.default_rng([settings.seed, 1])
        self.image_rng = np.random.default_rng([settings.seed, 2])
        self.last_image: np.ndarray | None = None
        self.detector = detector  # None with points perception
        images = settings.perception == "images"
        self.renderer: SceneRenderer | None = renderer_for(scene, model) if images or settings.record_images else None

    def _occluded(self, t: float) -> bool:
        return any(start <= t < end for start, end in self.settings.occlusions)

    def observe(self, pose: np.ndarray, t: float) -> Observation:
        if self.settings.drop_rate > 0 and self.fault_rng.random() < self.settings.drop_rate:
            return dropped()
        outlier = self.settings.outlier_rate > 0 and self.fault_rng.random() < self.settings.outlier_rate
        points = self.settings.perception == "points"
        if points:
            pixels = None if self._occluded(t) else self._project(pose)
            if pixels is None:
                return Observation(None, status=ObservationStatus.OCCLUDED)
            pixels = distort_pixels(self.scene.world.camera, pixels)
        else:
            pixels = self._measured_pixels(pose, t, outlier)
        if self.settings.pixel_noise > 0:
            pixels = pixels + self.noise_rng.normal(0.0, self.settings.pixel_noise, pixels.shape)
        if outlier and points:
            # A wrong detection: one point displaced by 5 to 20 px (images: a spurious blob drawn in).
            index = int(self.fault_rng.integers(pixels.shape[0]))
            angle = self.fault_rng.uniform(0.0, 2.0 * math.pi)
            pixels[index] += self.fault_rng.uniform(5.0, 20.0) * np.array([math.cos(angle), math.sin(angle)])
        return self.estimator.from_pixels(pixels)

    def _measured_pixels(self, pose: np.ndarray, t: float, outlier: bool) -> np.ndarray:
        """The fit's detector's pixels (N, 2) in this frame's render, kept as :attr:`last_image`."""
        step = self.settings.exposure_step  # (t, gain): the gain from t (s) on
        gain = step[1] if step is not None and t >= step[0] else None
        blob = self._spurious_blob(pose) if outlier else None
        # Tracked dots are looked for in small windows, all that is rendered; failing that, the whole frame.
        windows = self.detector.search_windows()
        pixels = None
        if windows is not None:
            image = self._frame(self.renderer.render_windows(pose, self.noise_rng, windows, exposure_gain=gain), pose, t, blob)
            pixels = self.detector.detect_in_windows(image, windows)
        if pixels is None:
            image = self._frame(self.renderer.render(pose, self.noise_rng, exposure_gain=gain), pose, t, blob)
            pixels = self.detector.detect(image)
        elif self.settings.record_images:
            # The windows measured, in a whole frame whose other pixels have a noise stream of their own.
            whole = self._frame(self.renderer.render(pose, self.image_rng, exposure_gain=gain), pose, t, blob)
            for x0, y0, x1, y1 in windows:
                whole[y0:y1, x0:x1] = image[y0:y1, x0:x1]
            image = whole
        self.last_image = image
        return pixels

    def _frame(self, image: np.ndarray, pose: np.ndarray, t: float, blob: tuple[tuple[int, int], int, int] | None) -> np.ndarray:
        """``image`` with this frame's faults drawn in: the occluder, the spurious blob."""
        if self._occluded(t):
            self._cover_target(image, pose)
        if blob is not None:
            centre, radius, value = blob
            cv2.circle(image, centre, radius, value, -1, cv2.LINE_AA, 4)
        return image

    def _project(self, pose: np.ndarray) -> np.ndarray | None:
        """Pixels of the target points (in the fit's identity order) seen from ``pose``, or
        None when one is behind the camera or outside the image: the numbers of
        :func:`~hbvs_cli.core.frames.world_to_robot` and (9), (11), in plain floats (faster
        for a few points than numpy's per-call cost)."""
        camera = self.scene.world.camera
        x, y, phi = (float(v) for v in pose)
        c, s = np.cos(phi), np.sin(phi)
        height = self._camera_height
        in_camera = []
        for px, py, pz in self._points_world:
            dx, dy = px - x, py - y
            forward = c * dx + s * dy
            if forward <= 0.05:
                return None
            in_camera.append((forward, -s * dx + c * dy, pz - height))
        pixels = np.empty((len(self._identity), 2))
        width, rows = camera.width - 1, camera.height - 1
        for row, index in enumerate(self._identity):
            forward, left, up = in_camera[index]
            u = camera.cx - camera.fx * left / forward
            v = camera.cy - camera.fy * up / forward
            if u < 0 or v < 0 or u > width or v > rows:
                return None
            pixels[row, 0], pixels[row, 1] = u, v
        return pixels

    def _cover_target(self, image: np.ndarray, pose: np.ndarray) -> None:
        """An occluder (a person walking by) in front of the whole poster, and 4 px around it."""
        world = self.scene.world
        poster = world.target.poster
        corners = poster.to_world(np.array([[0, 0], [poster.width, 0], [poster.width, poster.height], [0, poster.height]]))
        with np.errstate(divide="ignore", invalid="ignore"):
            px = normalized_to_pixels(world.camera, world_to_robot(corners, pose, world.camera_height))
        u0, v0 = np.maximum(np.floor(px.min(axis=0) - 4.0).astype(int), 0)
        u1, v1 = np.minimum(np.ceil(px.max(axis=0) + 4.0).astype(int), (world.camera.width, world.camera.height))
        if u1 > u0 and v1 > v0:
            image[v0:v1, u0:u1] = 90

    def _spurious_blob(self, pose: np.ndarray) -> tuple[tuple[int, int], int, int]:
        """A dark blob (for dots: a fake dot) or a bright one near the target: its centre and
        radius (1/16 px, as ``cv2.circle`` takes them with 4 fractional bits) and gray level."""
        world = self.scene.world
        px = world.pixels(pose)
        spread = max(float(np.ptp(px[:, 0])), float(np.ptp(px[:, 1])), 20.0)
        centre = px.mean(axis=0) + self.fault_rng.uniform(-0.8, 0.8, 2) * spread
        distance = float(world_to_robot(world.target.points_world.mean(axis=0)[None, :], pose, world.camera_height)[0, 0])
        radius = max(2.0, world.camera.fx * max(world.target.dot_radius, 0.03) / max(distance, 0.1))
        value = 30 if world.target.kind == "dots" else 250
        return (int(round(centre[0] * 16)), int(round(centre[1] * 16))), int(round(radius * 16)), value

    def image_of(self, pose: np.ndarray) -> np.ndarray:
        """The camera image of this step (``--record-images``): the one just measured, or a
        noiseless-seeded render at ``pose`` when perception did not render one."""
        if self.last_image is None:  # (only perception on images keeps one)
            return self.renderer.render(pose, np.random.default_rng(0))
        return self.last_image
