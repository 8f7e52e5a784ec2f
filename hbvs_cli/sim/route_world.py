"""A simulated route longer than one view: several planar targets placed along a taught drive.

Each target keeps its own single-target :class:`~.world.World`, in its own frame W_i (its wall
the plane x = 0, the robot looking along +x at it), placed in the route's frame R by a planar
pose ``(x, y, yaw)``: a point p of W_i is ``Rz(yaw) p + (x, y, 0)`` in R. So everything a single
target knows (its reference geometry (7), its ground truth (4), (14), its exact projection)
serves each segment of a route unchanged, on the robot's pose expressed in W_i (issue 47).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..core.camera import DEFAULT_CAMERA, CameraIntrinsics, camera_description
from ..core.frames import rotation_z, wrap_angle
from ..core.path import CommandProfile
from ..core.route import view_spans
from ..errors import InvalidValueError, MalformedDataError
from .poster import PosterRaster
from .render import RenderSettings, SceneRenderer, load_texture
from .world import DEFAULT_CAMERA_HEIGHT, Target, World, default_target

#: The texture name of the second built-in photograph: the built-in pattern turned by 180 deg,
#: so that two photographs of one route do not look alike.
TURNED_BUILTIN_TEXTURE = "builtin-turned"


@dataclass(frozen=True)
class RouteWorld:
    """A camera at ``camera_height`` (m) and targets along a route: ``worlds[i]`` is target i in
    its own frame W_i, placed in the route frame R at ``placements[i] = (x, y, yaw)`` (m, m, rad);
    ``profile`` and ``start_pose`` (in R) are the taught drive past them (None and zeros for
    a recorded route, :func:`recorded_route`: its drive is the recording's)."""

    name: str
    camera: CameraIntrinsics
    camera_height: float
    placements: NDArray[np.float64]
    worlds: tuple[World, ...]
    profile: CommandProfile | None
    start_pose: NDArray[np.float64]

    def __post_init__(self) -> None:
        placements = np.asarray(self.placements, dtype=float)
        if placements.shape != (len(self.worlds), 3) or not self.worlds or not np.all(np.isfinite(placements)):
            raise MalformedDataError("a route needs one finite placement (x, y, yaw) per target, and at least one target")
        object.__setattr__(self, "placements", placements)

    def local_pose(self, index: int, pose: ArrayLike) -> NDArray[np.float64]:
        """The robot pose(s) (..., 3) of R expressed in target ``index``'s frame W_i."""
        pose = np.asarray(pose, dtype=float)
        x, y, yaw = self.placements[index]
        c, s = np.cos(yaw), np.sin(yaw)
        dx, dy = pose[..., 0] - x, pose[..., 1] - y
        return np.stack([c * dx + s * dy, -s * dx + c * dy, wrap_angle(pose[..., 2] - yaw)], axis=-1)

    def spans(self, pose: ArrayLike, margin_px: float = 10.0) -> NDArray[np.float64]:
        """For each target: the largest distance (px) between two of its image points, 0 when
        it is not wholly in view: how well it is seen."""
        spans = np.zeros(len(self.worlds))
        for index, world in enumerate(self.worlds):
            local = self.local_pose(index, pose)
            if world.in_view(local, margin_px):
                spans[index] = view_spans(world.pixels(local)[None])[0]
        return spans

    def in_view(self, pose: ArrayLike, margin_px: float = 10.0) -> bool:
        """True when at least one target is wholly in view (all its points in front of the camera and in the
        image): what a teach warns about."""
        return any(world.in_view(self.local_pose(i, pose), margin_px) for i, world in enumerate(self.worlds))

    @property
    def route_targets(self) -> tuple[Target, ...]:
        """The targets with their posters expressed in R (what the 3D scene draws)."""
        placed = []
        for (x, y, yaw), world in zip(self.placements, self.worlds):
            rotation, shift = rotation_z(yaw), np.array([x, y, 0.0])
            poster = world.target.poster
            moved = replace(poster, center=rotation @ poster.center + shift, right=rotation @ poster.right,
                            down=rotation @ poster.down)
            placed.append(replace(world.target, poster=moved))
        return tuple(placed)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready description (the ``world`` record of a teach file): the camera as a single
        target's, and each target's own description with its placement (yaw in rad)."""
        return {
            "route": self.name,
            "camera": camera_description(self.camera),
            "camera_height_m": self.camera_height,
            "targets": [{"placement": placement.tolist(), "target": world.to_dict()["target"]}
                        for placement, world in zip(self.placements, self.worlds)],
        }


def route_targets_from_description(data: Any) -> tuple[NDArray[np.float64], tuple[World, ...]]:
    """The placements (K, 3) and target worlds of a recorded route description (:meth:`RouteWorld.to_dict`);
    MalformedDataError for a malformed one."""
    try:
        entries = list(data["targets"])
        placements = np.array([[float(v) for v in entry["placement"]] for entry in entries])
        worlds = tuple(World.from_dict({"camera": data["camera"], "camera_height_m": data["camera_height_m"],
                                        "target": entry["target"]}) for entry in entries)
    except (KeyError, TypeError, ValueError) as exc:
        raise MalformedDataError(f"malformed route description: {exc}") from None
    if placements.shape != (len(worlds), 3) or not worlds:
        raise MalformedDataError("malformed route description: each target needs a placement (x, y, yaw)")
    return placements, worlds


def recorded_route(data: Any, camera: CameraIntrinsics) -> RouteWorld:
    """The route of a teach file's ``world`` record (:meth:`RouteWorld.to_dict`), seen by ``camera``."""
    placements, worlds = route_targets_from_description(data)
    return RouteWorld(str(data.get("route", "")), camera, worlds[0].camera_height, placements, worlds, None, np.zeros(3))


#: A target is seen well enough to be followed when two of its image points are this far apart (px).
MIN_SPAN_PX = 70.0
#: Speed of the corridor's taught drive (m/s).
CORRIDOR_SPEED = 0.25
#: Its legs (m), each but the last followed by a left turn of CORRIDOR_TURN_DEG on a radius of
#: CORRIDOR_TURN_RADIUS (m): 23 m in all, turning 75 deg.
CORRIDOR_LEGS = (4.0, 5.0, 5.0, 5.0)
CORRIDOR_TURN_DEG = 25.0
CORRIDOR_TURN_RADIUS = 3.0
#: Its targets, one per leg: kind, texture, scale of the default target of that kind, height (m)
#: of the poster's centre, and its place: metres beyond the end of its leg and to the left of
#: its line (negative: to the right, outside the coming turn), facing back along the leg.
CORRIDOR_TARGETS: tuple[tuple[str, str, float, float, float, float], ...] = (
    ("dots", "builtin", 1.0, 0.75, 3.0, -1.2),
    ("aruco", "builtin", 2.0, 1.00, 3.0, -1.2),
    ("texture", "builtin", 1.3, 0.90, 3.0, -1.2),
    ("texture", TURNED_BUILTIN_TEXTURE, 1.3, 0.90, 3.0, 0.0),
)


def corridor_route(camera: CameraIntrinsics = DEFAULT_CAMERA) -> RouteWorld:
    """The corridor: four straight legs joined by three left turns (23 m at 0.25 m/s, 92 s), a
    target at the end of each leg (a dot target, a marker board and two photographs), each
    seen frontally from its leg. Followed as :func:`~hbvs_cli.core.route.split_route` does
    (each seen at least :data:`MIN_SPAN_PX`, the largest next), consecutive targets are seen
    together for 11.5, 24 and 21 s; none is nearer than 1 m to the path."""
    turn_rate = CORRIDOR_SPEED / CORRIDOR_TURN_RADIUS
    turn_s = np.radians(CORRIDOR_TURN_DEG) / turn_rate
    durations = np.ravel([[leg / CORRIDOR_SPEED, turn_s] for leg in CORRIDOR_LEGS])[:-1]
    w = np.ravel([[0.0, turn_rate] for _ in CORRIDOR_LEGS])[:-1]
    starts = np.concatenate([[0.0], np.cumsum(durations)[:-1]])
    profile = CommandProfile(t=starts, v=np.full(w.size, CORRIDOR_SPEED), w=w, t_end=float(durations.sum()))
    leg_ends = profile.segment_start_poses(np.zeros(3))[1::2]
    placements, worlds = [], []
    for (kind, texture, scale, height, ahead, left), (x, y, heading) in zip(CORRIDOR_TARGETS, leg_ends):
        c, s = np.cos(heading), np.sin(heading)
        placements.append([x + ahead * c - left * s, y + ahead * s + left * c, heading])
        target = _scaled(default_target(kind, dots=4, wall_x=0.0), scale, height)
        worlds.append(World(camera=camera, camera_height=DEFAULT_CAMERA_HEIGHT, target=replace(target, texture=texture)))
    return RouteWorld("corridor", camera, DEFAULT_CAMERA_HEIGHT, np.array(placements), tuple(worlds), profile, np.zeros(3))


def _scaled(target: Target, scale: float, height: float) -> Target:
    """``target`` (its poster centred at W_i's origin) scaled by ``scale``, its centre ``height`` m up."""
    poster = target.poster
    grown = replace(poster, center=np.array([0.0, 0.0, height]), width=poster.width * scale, height=poster.height * scale)
    return replace(target, points_poster=target.points_poster * scale, dot_radius=target.dot_radius * scale, poster=grown)


#: The simulated routes of ``teach --sim --route NAME``.
ROUTES: dict[str, Callable[[CameraIntrinsics], RouteWorld]] = {"corridor": corridor_route}


def simulated_route(name: str, camera: CameraIntrinsics = DEFAULT_CAMERA) -> RouteWorld:
    """The route called ``name`` (:data:`ROUTES`) seen by ``camera``; InvalidValueError for an unknown name."""
    if name not in ROUTES:
        raise InvalidValueError(f"unknown route {name!r}: choose one of {', '.join(ROUTES)}")
    return ROUTES[name](camera)


class RouteRenderer(SceneRenderer):
    """Frames of a route: every target's poster painted into one frame (the farther first), then
    the one sensor of :class:`SceneRenderer` (exposure, noise). Whole frames only."""

    def __init__(self, route: RouteWorld, settings: RenderSettings) -> None:
        rasters = [PosterRaster.from_target(world.target, texture=_route_texture(world)) for world in route.worlds]
        super().__init__(route.worlds[0], rasters[0], settings)
        self.route = route
        self.parts = [SceneRenderer(world, raster, settings) for world, raster in zip(route.worlds, rasters)]

    def render_scene(self, pose: ArrayLike) -> NDArray[np.uint8]:
        """The noiseless, unexposed scene: each poster as its own renderer draws it on the wall,
        the nearer over the farther wherever it differs from the bare wall (a poster pixel of
        exactly the wall's gray lets the farther poster's pixel show through)."""
        frame = self._wall.copy()
        pose = np.asarray(pose, dtype=float)
        distances = np.linalg.norm(self.route.placements[:, :2] - pose[:2], axis=1)
        for index in np.argsort(-distances, kind="stable"):
            alone = self.parts[index].render_scene(self.route.local_pose(int(index), pose))
            np.copyto(frame, alone, where=alone != self._background)
        return frame


def _route_texture(world: World) -> NDArray[np.uint8] | None:
    """The picture of a route's target: the turned built-in photograph, else as a single target's."""
    if world.target.kind == "texture" and world.target.texture == TURNED_BUILTIN_TEXTURE:
        return np.ascontiguousarray(PosterRaster.from_target(replace(world.target, texture="builtin")).image[::-1, ::-1])
    return load_texture(world)


def make_route_renderer(route: RouteWorld, noise: float, blur: float, exposure: float, grain: float = 0.0) -> RouteRenderer:
    """The renderer of a route with the sensor of :func:`~.render.make_renderer`."""
    return RouteRenderer(route, RenderSettings(noise_std=noise, blur_sigma=blur, exposure_gain=exposure, noise_grain=grain))
