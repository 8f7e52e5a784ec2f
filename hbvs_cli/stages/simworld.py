"""The simulated world of ``repeat --sim``, and its camera with faults.

After a simulated teach the fit file carries the world and the taught path, so the repeat
sees exactly the world that was taught, and the taught pose at any time is known exactly.
After a teach from real footage there is no world: one consistent with the reference image
is built instead, at an assumed depth ``--depth D`` (a vertical wall D metres from F*,
papered with the reference image, the target points where the reference image shows them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from numpy.typing import ArrayLike

import numpy as np

from ..core.camera import distort_pixels, pixels_to_normalized
from ..core.estimation import STATUS_OCCLUDED, Observation, dropped
from ..core.frames import rotation_z
from ..core.path import CommandProfile
from ..core.world import Poster, Target, World
from ..errors import UsageError
from ..io.topics import ANNOTATIONS_TOPIC, IMAGE_TOPIC, TOPICS


@dataclass
class Scene:
    """A world to simulate, its true depth d*, and the taught pose at any taught time.

    Attributes
    ----------
    world : World
    d_true : float
        True distance from F* to the target plane (m).
    reference_pose : ndarray, shape (3,)
    has_ground_truth : bool
        True when the taught poses are the simulated teach's own (not reconstructed).
    poster_image : ndarray or None
        The picture on the wall when it is not the target's own drawing (real footage).
    """

    world: World
    d_true: float
    reference_pose: np.ndarray
    has_ground_truth: bool
    taught_profile: CommandProfile | None = None
    taught_start: np.ndarray | None = None
    taught_t0: float = 0.0
    spline: Any = None
    poster_image: np.ndarray | None = None
    run_start: float = 0.0
    run_speed: float = 1.0
    _segment_starts: np.ndarray | None = None

    def taught_pose(self, t: ArrayLike) -> np.ndarray:
        """The taught robot pose at taught times ``t`` (s), in W, shape (..., 3)."""
        t = np.asarray(t, dtype=float)
        if self.taught_profile is not None:
            if self._segment_starts is None:
                self._segment_starts = self.taught_profile.segment_start_poses(self.taught_start)
            return self.taught_profile.poses_at(t - self.taught_t0, self.taught_start, self._segment_starts)
        # Real footage: the fit's trajectory at the assumed depth, (3) and (14) inverted.
        desired = self.spline.evaluate(t)
        phi = self.reference_pose[2] - np.asarray(desired.theta_d)
        x1 = self.d_true * np.asarray(desired.x_hd1)
        x2 = self.d_true * np.asarray(desired.x_hd2)
        c, s = np.cos(phi), np.sin(phi)
        return np.stack([self.reference_pose[0] - (c * x1 - s * x2), self.reference_pose[1] - (s * x1 + c * x2), phi], axis=-1)

    def taught_pose_at_run_time(self, tau: ArrayLike) -> np.ndarray:
        """The taught pose at repeat time ``tau`` (s): the trajectory may be time-scaled."""
        return self.taught_pose(self.run_start + self.run_speed * np.asarray(tau, dtype=float))


def simulation_world(model: Any, reference_image: bytes | None, depth: float | None, speed: float = 1.0) -> Scene:
    """The scene of ``repeat --sim`` for a fit model (see the module docstring)."""
    start = model.trajectory.t_start
    if model.world is not None and model.taught_path is not None:
        path = model.taught_path
        _, _, d_true = model.world.reference_geometry(path.reference_pose)
        interval = float(np.median(np.diff(path.t))) if path.t.size > 1 else 1.0 / 30.0
        profile = CommandProfile(t=path.t - path.t[0], v=path.v, w=path.w, t_end=float(path.t[-1] - path.t[0] + interval))
        if depth is not None:
            raise UsageError("--depth is for a teach from real footage; this fit came from a simulated teach and knows its world")
        return Scene(
            world=model.world, d_true=d_true, reference_pose=path.reference_pose, has_ground_truth=True,
            taught_profile=profile, taught_start=path.start_pose, taught_t0=float(path.t[0]),
            run_start=start, run_speed=speed,
        )
    if depth is None:
        raise UsageError(
            "this fit came from real footage, so there is no simulated world: give --depth D, the assumed distance (m) "
            "from the reference camera to the target, to build one"
        )
    if not (math.isfinite(depth) and depth > 0):
        raise UsageError(f"--depth must be a positive distance in metres, got {depth}")
    if reference_image is None:
        raise UsageError("the fit file has no reference image to build a world from")
    from ..io.images import decode_image

    image = decode_image(reference_image, "the fit's reference image")
    world, poster_image, reference_pose = world_from_reference(model, image, depth)
    return Scene(
        world=world, d_true=float(depth), reference_pose=reference_pose, has_ground_truth=False,
        spline=model.trajectory, poster_image=poster_image, run_start=start, run_speed=speed,
    )


#: Height given to the camera of a world built from real footage (any value works: only
#: heights relative to the camera matter).
BUILT_CAMERA_HEIGHT = 1.0


def world_from_reference(model: Any, image: np.ndarray, depth: float) -> tuple[World, np.ndarray, np.ndarray]:
    """A vertical wall ``depth`` metres ahead of F* (at the world origin), papered with the
    reference image as F* saw it, and the target points where F* saw them.

    Returns the world, the poster's picture and the pose of F* in it.
    """
    import cv2

    from ..core.camera import undistort_pixels

    normal = np.asarray(model.normal, dtype=float)
    horizontal = np.array([normal[0], normal[1], 0.0])
    if np.linalg.norm(horizontal) < 0.5:
        raise UsageError("the fitted target plane is nearly horizontal; a wall cannot be built for it")
    # Turn F* so that the wall's normal is the world's +x: F* sits at the origin with yaw
    # psi, so a direction v in F* is Rz(psi) v in the world.
    psi = -math.atan2(horizontal[1], horizontal[0])
    n_world = rotation_z(psi) @ (horizontal / np.linalg.norm(horizontal))
    assert abs(n_world[1]) < 1e-9
    camera = model.camera

    def to_wall(pixels: np.ndarray) -> np.ndarray:
        """World points on the wall x = depth seen at these reference pixels."""
        m = pixels_to_normalized(camera, undistort_pixels(camera, np.asarray(pixels, dtype=float)))
        rays = (rotation_z(psi) @ m.T).T
        if np.any(rays[:, 0] <= 1e-3):
            raise UsageError("part of the reference image looks away from the wall; cannot build a world")
        points = rays * (depth / rays[:, :1])
        points[:, 2] += BUILT_CAMERA_HEIGHT
        return points

    h, w = image.shape[:2]
    corners = to_wall(np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]]))
    y_left, y_right = corners[:, 1].max(), corners[:, 1].min()
    z_top, z_bottom = corners[:, 2].max(), corners[:, 2].min()
    width, height = y_left - y_right, z_top - z_bottom
    poster = Poster(center=np.array([depth, 0.5 * (y_left + y_right), 0.5 * (z_top + z_bottom)]), width=width, height=height)
    points_world = to_wall(model.reference_pixels)
    points_poster = np.stack([y_left - points_world[:, 1], z_top - points_world[:, 2]], axis=-1)
    target = Target(kind=model.target_kind, points_poster=points_poster, poster=poster, texture="reference image")
    world = World(camera=camera, camera_height=BUILT_CAMERA_HEIGHT, target=target)
    # Paint the poster: every poster pixel looks up the reference image pixel that sees it.
    ppm = min(640.0, 4000.0 / max(width, height))
    size = (int(round(width * ppm)), int(round(height * ppm)))
    reference_pose = np.array([0.0, 0.0, psi])
    poster_to_image = world.poster_to_image_homography(reference_pose)
    metres_from_pixels = np.array([[1.0 / ppm, 0.0, 0.5 / ppm], [0.0, 1.0 / ppm, 0.5 / ppm], [0.0, 0.0, 1.0]])
    painted = cv2.warpPerspective(
        image, poster_to_image @ metres_from_pixels, size, flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
        borderMode=cv2.BORDER_CONSTANT, borderValue=128,
    )
    return world, painted, reference_pose


class SimulatedCamera:
    """The repeat's camera: a measurement per frame, with the faults asked for.

    ``perception="images"`` renders the scene and runs the fit's detector on it;
    ``perception="points"`` projects the target points and adds pixel noise. Faults:
    occlusion intervals (the target is covered), dropped frames, outliers (a spurious dot
    or a wrong point), a sudden exposure change.
    """

    def __init__(self, scene: Scene, model: Any, settings: Any, options: Any, template_image: bytes | None) -> None:
        from .detection import detector_from_model, estimator_from_model
        from .options import parse_interval

        self.scene = scene
        self.model = model
        self.settings = settings
        self.perception = settings.perception
        self.estimator = estimator_from_model(model)
        self.identity = world_point_identity(scene, model)
        self._points = scene.world.target.points_world[self.identity]
        self._camera_height = scene.world.camera_height
        self.noise_rng = np.random.default_rng(options.seed)
        self.fault_rng = np.random.default_rng([options.seed, 1])
        self.occlusions = [parse_interval(text, "--occlude") for text in options.occlude]
        self.drop_rate = options.drop_rate
        self.outlier_rate = options.outlier_rate
        self.exposure_step = _parse_exposure_step(options.exposure_step)
        self.last_image: np.ndarray | None = None
        self.renderer = None
        self.detector = None
        if self.perception == "images" or options.record_images:
            self.renderer = _renderer_for(scene, model)
        if self.perception == "images":
            self.detector = detector_from_model(model, template_image, seed=options.seed)

    def _occluded(self, t: float) -> bool:
        return any(start <= t < end for start, end in self.occlusions)

    def observe(self, pose: np.ndarray, t: float) -> Observation:
        if self.drop_rate > 0 and self.fault_rng.random() < self.drop_rate:
            return dropped()
        outlier = self.outlier_rate > 0 and self.fault_rng.random() < self.outlier_rate
        if self.perception == "points":
            return self._observe_points(pose, t, outlier)
        return self._observe_image(pose, t, outlier)

    def _observe_points(self, pose: np.ndarray, t: float, outlier: bool) -> Observation:
        world = self.scene.world
        if self._occluded(t):
            return Observation(None, status=STATUS_OCCLUDED)
        pixels = self._project(pose)
        if pixels is None:
            return Observation(None, status=STATUS_OCCLUDED)
        pixels = distort_pixels(world.camera, pixels)
        if self.settings.pixel_noise > 0:
            pixels = pixels + self.noise_rng.normal(0.0, self.settings.pixel_noise, pixels.shape)
        if outlier:
            # A wrong detection: one point displaced by 5 to 20 px.
            index = int(self.fault_rng.integers(pixels.shape[0]))
            angle = self.fault_rng.uniform(0.0, 2.0 * math.pi)
            pixels[index] += self.fault_rng.uniform(5.0, 20.0) * np.array([math.cos(angle), math.sin(angle)])
        return self.estimator.from_pixels(pixels)

    def _observe_image(self, pose: np.ndarray, t: float, outlier: bool) -> Observation:
        gain = self.settings_exposure(t)
        image = self.renderer.render(pose, self.noise_rng, exposure_gain=gain)
        if self._occluded(t):
            self._cover_target(image, pose)
        if outlier:
            self._add_spurious_blob(image, pose)
        self.last_image = image
        pixels = self.detector.detect(image)
        return self.estimator.from_pixels(pixels)

    def _project(self, pose: np.ndarray) -> np.ndarray | None:
        """Pixels of the target points (in the fit's identity order) seen from ``pose``, or
        None when one is behind the camera or outside the image: the points perception's
        projection, done with precomputed arrays because it runs every control period."""
        camera = self.scene.world.camera
        c, s = math.cos(pose[2]), math.sin(pose[2])
        d = self._points - (pose[0], pose[1], self._camera_height)
        depth = c * d[:, 0] + s * d[:, 1]
        if depth.min() <= 0.05:
            return None
        u = camera.cx - camera.fx * (-s * d[:, 0] + c * d[:, 1]) / depth
        v = camera.cy - camera.fy * d[:, 2] / depth
        if u.min() < 0 or v.min() < 0 or u.max() > camera.width - 1 or v.max() > camera.height - 1:
            return None
        return np.stack([u, v], axis=-1)

    def settings_exposure(self, t: float) -> float | None:
        if self.exposure_step is None:
            return None
        at, gain = self.exposure_step
        return gain if t >= at else None

    def _target_box(self, pose: np.ndarray, pad: float) -> tuple[int, int, int, int]:
        world = self.scene.world
        corners = world.target.poster.to_world(np.array([[0, 0], [world.target.poster.width, 0],
                                                         [world.target.poster.width, world.target.poster.height],
                                                         [0, world.target.poster.height]]))
        m_bar = np.array([_to_camera(world, pose, c) for c in corners])
        px = np.stack([world.camera.cx - world.camera.fx * m_bar[:, 1] / m_bar[:, 0],
                       world.camera.cy - world.camera.fy * m_bar[:, 2] / m_bar[:, 0]], axis=-1)
        u0, v0 = np.floor(px.min(axis=0) - pad).astype(int)
        u1, v1 = np.ceil(px.max(axis=0) + pad).astype(int)
        return max(u0, 0), max(v0, 0), min(u1, world.camera.width), min(v1, world.camera.height)

    def _cover_target(self, image: np.ndarray, pose: np.ndarray) -> None:
        """An occluder (a person walking by) in front of the whole poster."""
        u0, v0, u1, v1 = self._target_box(pose, pad=4.0)
        if u1 > u0 and v1 > v0:
            image[v0:v1, u0:u1] = 90

    def _add_spurious_blob(self, image: np.ndarray, pose: np.ndarray) -> None:
        """A dark blob (for dots: a fake dot) or a bright one near the target."""
        import cv2

        world = self.scene.world
        px = world.pixels(pose)
        spread = max(float(np.ptp(px[:, 0])), float(np.ptp(px[:, 1])), 20.0)
        centre = px.mean(axis=0) + self.fault_rng.uniform(-0.8, 0.8, 2) * spread
        distance = float(np.mean(_to_camera(world, pose, world.target.points_world.mean(axis=0))[0:1]))
        radius = max(2.0, world.camera.fx * max(world.target.dot_radius, 0.03) / max(distance, 0.1))
        value = 30 if world.target.kind == "dots" else 250
        cv2.circle(image, (int(round(centre[0] * 16)), int(round(centre[1] * 16))), int(round(radius * 16)), value, -1, cv2.LINE_AA, 4)

    def write_image(self, writer: Any, ns: int, record: Any, desired_px: np.ndarray) -> None:
        """Store this step's camera image with detected and desired points (``--record-images``)."""
        from ..io.images import bytes_to_store, write_compressed_image
        from ..io.mcap import time_message
        from ..io.messages import CAMERA_FRAME, annotations_message

        image = self.last_image
        if image is None or self.perception != "images":
            image = self.renderer.render(record.pose, np.random.default_rng(0))
        stamp = time_message(ns)
        topics = TOPICS["run"]
        write_compressed_image(writer, IMAGE_TOPIC, ns, *bytes_to_store(image), CAMERA_FRAME)
        label = f"t = {record.t:.2f} s" + ("  target lost" if record.lost else "")
        writer.write(ANNOTATIONS_TOPIC, topics[ANNOTATIONS_TOPIC], ns, annotations_message(stamp, record.observation.pixels, desired_px, label))


def world_point_identity(scene: Scene, model: Any) -> np.ndarray:
    """Order of the world's target points that matches the fit's point identity.

    The fit numbers the points as its detector first saw them; the world lists them in its
    own order. Matching where F* sees each world point to the fit's reference pixels
    gives the permutation once.
    """
    from scipy.optimize import linear_sum_assignment

    seen = scene.world.pixels(scene.reference_pose)
    cost = np.linalg.norm(np.asarray(model.reference_pixels)[:, None, :] - seen[None, :, :], axis=-1)
    rows, columns = linear_sum_assignment(cost)
    order = np.empty(len(rows), dtype=int)
    order[rows] = columns
    return order


def _to_camera(world: World, pose: np.ndarray, point: np.ndarray) -> np.ndarray:
    from ..core.frames import world_to_robot

    return world_to_robot(np.asarray(point, dtype=float)[None, :], pose, world.camera_height)[0]


def _parse_exposure_step(text: str | None) -> tuple[float, float] | None:
    from .options import parse_time_and_factor

    return None if text is None else parse_time_and_factor(text, "--exposure-step")


def _renderer_for(scene: Scene, model: Any) -> Any:
    from .teach import make_renderer

    # The same sensor as the teach (noise, blur, exposure), as the fit recorded it.
    render = model.render or {}
    noise = float(render.get("noise", 2.0))
    if scene.poster_image is None:
        return make_renderer(scene.world, noise, float(render.get("blur", 0.0)), float(render.get("exposure", 1.0)))
    from ..perception.poster import PosterRaster, build_pyramid
    from ..perception.render import RenderSettings, SceneRenderer

    poster = scene.world.target.poster
    raster = PosterRaster(kind=scene.world.target.kind, ppm=scene.poster_image.shape[1] / poster.width,
                          levels=build_pyramid(scene.poster_image), width=poster.width, height=poster.height)
    return SceneRenderer(scene.world, raster, RenderSettings(noise_std=noise))
