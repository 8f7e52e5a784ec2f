"""The simulated world of ``repeat --sim``: the scene, its true depth and the taught pose.

A simulated teach's fit carries its world and path; for real footage a world is built at an
assumed ``--depth D``: a wall D m from F* papered with the reference image.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..core.assignment import optimal_assignment
from ..core.camera import pixels_to_normalized, undistort_pixels
from ..core.frames import rotation_z
from ..core.desired import taught_frame_interval
from ..core.fit_model import FitModel, SensorSettings
from ..core.path import CommandProfile
from ..core.trajectory import SplineTrajectory
from .world import Poster, Target, World, world_from_description
from ..errors import UsageError
from .poster import PosterRaster, build_pyramid
from .render import RenderSettings, SceneRenderer, make_renderer


@dataclass
class Scene:
    """A world to simulate, its true depth d*, and the taught pose at any taught time
    (``poster_image``: the picture on the wall when it is not the target's own drawing)."""

    world: World
    d_true: float
    reference_pose: np.ndarray
    taught_profile: CommandProfile | None = None
    taught_start: np.ndarray | None = None
    taught_t0: float = 0.0
    spline: SplineTrajectory | None = None
    poster_image: np.ndarray | None = None
    run_start: float = 0.0
    run_speed: float = 1.0
    #: Where each of ``taught_profile``'s segments starts (:meth:`~hbvs_cli.core.path.CommandProfile.segment_start_poses`).
    taught_segment_starts: np.ndarray | None = None

    def taught_pose(self, t: ArrayLike) -> np.ndarray:
        """The taught robot pose at taught times ``t`` (s), in W, shape (..., 3)."""
        t = np.asarray(t, dtype=float)
        if self.taught_profile is not None:
            return self.taught_profile.poses_at(t - self.taught_t0, self.taught_start, self.taught_segment_starts)
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


def knows_its_world(model: FitModel) -> bool:
    """True for a fit of a simulated teach (its world recorded), False for real footage,
    whose world :func:`simulation_world` builds from the reference image."""
    return model.world_description is not None and model.taught_path is not None


def simulation_world(model: FitModel, reference_image: NDArray | None, depth: float | None, speed: float = 1.0,
                     source: str = "the fit file") -> Scene:
    """The scene of ``repeat --sim`` for a fit model; the reference image is needed only when
    the model does not know its world. RecordingError (naming ``source``) for a malformed one."""
    start = model.trajectory.t_start
    if knows_its_world(model):
        if depth is not None:
            raise UsageError("--depth is for a teach from real footage; this fit came from a simulated teach and knows its world")
        world = world_from_description(model.world_description, source)
        path = model.taught_path
        _, _, d_true = world.reference_geometry(path.reference_pose)
        interval = taught_frame_interval(path.t)
        profile = CommandProfile(t=path.t - path.t[0], v=path.v, w=path.w, t_end=float(path.t[-1] - path.t[0] + interval))
        return Scene(
            world=world, d_true=d_true, reference_pose=path.reference_pose,
            taught_profile=profile, taught_start=path.start_pose, taught_t0=float(path.t[0]),
            run_start=start, run_speed=speed, taught_segment_starts=profile.segment_start_poses(path.start_pose),
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
    world, poster_image, reference_pose = world_from_reference(model, reference_image, depth)
    return Scene(
        world=world, d_true=float(depth), reference_pose=reference_pose,
        spline=model.trajectory, poster_image=poster_image, run_start=start, run_speed=speed,
    )


#: Height of the camera of a world built from real footage (only relative heights matter).
BUILT_CAMERA_HEIGHT = 1.0


def world_from_reference(model: FitModel, image: np.ndarray, depth: float) -> tuple[World, np.ndarray, np.ndarray]:
    """A world whose vertical wall, ``depth`` m ahead of F* (at the origin), is papered with
    the reference image as F* saw it, the target points where F* saw them; the poster's
    picture; and the pose of F*."""
    normal = np.asarray(model.normal, dtype=float)
    horizontal = np.array([normal[0], normal[1], 0.0])
    if np.linalg.norm(horizontal) < 0.5:
        raise UsageError("the fitted target plane is nearly horizontal; a wall cannot be built for it")
    # Turn F* so that the wall's normal is the world's +x: F* sits at the origin with yaw
    # psi, so a direction v in F* is Rz(psi) v in the world.
    psi = -math.atan2(horizontal[1], horizontal[0])
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


def point_identity(seen: NDArray[np.float64], reference_pixels: NDArray[np.float64]) -> NDArray[np.intp]:
    """The permutation of the points ``seen`` (N, 2) px from F* into the order of a fit's
    ``reference_pixels`` (N, 2) px: each matched to the nearest, all at once."""
    cost = np.linalg.norm(np.asarray(reference_pixels)[:, None, :] - seen[None, :, :], axis=-1)
    rows, columns = optimal_assignment(cost)
    order = np.empty(len(rows), dtype=int)
    order[rows] = columns
    return order


def renderer_for(scene: Scene, model: FitModel) -> SceneRenderer:
    """The camera of the scene, with the teach's sensor (noise, its grain, blur, exposure) as the fit recorded it."""
    sensor = model.render or SensorSettings()
    if scene.poster_image is None:
        return make_renderer(scene.world, sensor.noise, sensor.blur, sensor.exposure, sensor.noise_grain)
    poster = scene.world.target.poster
    raster = PosterRaster(kind=scene.world.target.kind, ppm=scene.poster_image.shape[1] / poster.width,
                          levels=build_pyramid(scene.poster_image), width=poster.width, height=poster.height)
    return SceneRenderer(scene.world, raster, RenderSettings(noise_std=sensor.noise, noise_grain=sensor.noise_grain))
