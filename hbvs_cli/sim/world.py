"""The simulated world: a camera on a unicycle robot and a planar target on a wall.

World frame W: x toward the wall, y left, z up (m). The optical centre, the origin of F
(Sec. II), is at ``camera_height``; no target point may lie at that height (18).
:meth:`World.to_dict` is what ``hbvs teach`` records, so that later stages re-create it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import HbvsError, InvalidValueError, MalformedDataError, PointAtCameraHeightError, RecordingError
from ..core.camera import (
    DEFAULT_CAMERA, CameraIntrinsics, camera_description, camera_from_description, normalize_points,
    normalized_to_pixels,
)
from ..core.fit_model import MAX_TARGET_POINTS
from ..core.frames import PAPER_TO_OPENCV, rotation_z, world_to_robot

TARGET_KINDS = ("dots", "aruco", "texture")


@dataclass(frozen=True)
class Poster:
    """A flat rectangle on the wall carrying the target's picture.

    ``center`` (3,) in W and ``width``, ``height`` in m; ``right`` and ``down`` (3,): unit
    vectors in W along the rows (as seen from the robot) and columns.
    """

    center: NDArray[np.float64]
    width: float
    height: float
    right: NDArray[np.float64] = field(default_factory=lambda: np.array([0.0, -1.0, 0.0]))
    down: NDArray[np.float64] = field(default_factory=lambda: np.array([0.0, 0.0, -1.0]))

    def to_world(self, ab: ArrayLike) -> NDArray[np.float64]:
        """Poster coordinates ``(a, b)`` (m from the top-left corner) to points in W."""
        ab = np.asarray(ab, dtype=float)
        top_left = self.center - 0.5 * self.width * self.right - 0.5 * self.height * self.down
        return top_left + ab[..., :1] * self.right + ab[..., 1:2] * self.down


@dataclass(frozen=True)
class Target:
    """The planar target: its kind, its points and the poster it is drawn on.

    ``kind``: ``"dots"``, ``"aruco"`` or ``"texture"``; ``points_poster`` (N, 2): poster
    coordinates (m); ``dot_radius`` (m, dots), ``marker_id`` (aruco, :data:`ARUCO_DICTIONARY`),
    ``texture`` (``"builtin"`` or an image file name).
    """

    kind: str
    points_poster: NDArray[np.float64]
    poster: Poster
    dot_radius: float = 0.0
    marker_id: int = 0
    texture: str = "builtin"

    @property
    def points_world(self) -> NDArray[np.float64]:
        """Target points in W, shape (N, 3)."""
        return self.poster.to_world(self.points_poster)


#: The ArUco dictionary of simulated markers (OpenCV's DICT_4X4_50).
ARUCO_DICTIONARY = "DICT_4X4_50"
#: The key of each :class:`Poster` field in a world description (``_m``: in m).
_POSTER_KEYS = {"center": "center_m", "width": "width_m", "height": "height_m", "right": "right", "down": "down"}
#: The key and type of each :class:`Target` field that a description may leave out (its default then).
_TARGET_OPTIONAL_KEYS = {"dot_radius": ("dot_radius_m", float), "marker_id": ("marker_id", int), "texture": ("texture", str)}


@dataclass(frozen=True)
class World:
    """Camera, its height (m) and the target (on the wall ``x = wall_x``, the poster centre's x)."""

    camera: CameraIntrinsics
    camera_height: float
    target: Target

    def __post_init__(self) -> None:
        poster = self.target.poster
        if abs(poster.right[0]) > 1e-9 or abs(poster.down[0]) > 1e-9:
            raise MalformedDataError("the poster must lie flat on the wall (its axes may not have an x component)")
        heights = self.target.points_world[:, 2] - self.camera_height
        low = np.flatnonzero(np.abs(heights) < 0.02)
        if low.size:
            raise PointAtCameraHeightError(
                f"target point {int(low[0])} lies at the camera's height ({self.camera_height:.3f} m); "
                "equation (18) needs every point at least 2 cm above or below it"
            )

    @property
    def wall_x(self) -> float:
        """The wall is the plane x = wall_x in W (m)."""
        return float(self.target.poster.center[0])

    def points_in_camera(self, pose: ArrayLike) -> NDArray[np.float64]:
        """Target points in F (paper axes), shape (N, 3) (m)."""
        return world_to_robot(self.target.points_world, pose, self.camera_height)

    def normalized_points(self, pose: ArrayLike) -> NDArray[np.float64]:
        """Normalised image points ``m_i = [1, m_iy, m_iz]`` (9) seen from ``pose``."""
        return normalize_points(self.points_in_camera(pose))

    def pixels(self, pose: ArrayLike) -> NDArray[np.float64]:
        """Ideal pinhole pixels of the target points from ``pose``, shape (N, 2)."""
        with np.errstate(divide="ignore", invalid="ignore"):  # a point in the camera's plane
            return normalized_to_pixels(self.camera, self.points_in_camera(pose))

    def in_view(self, pose: ArrayLike, margin_px: float = 10.0) -> bool:
        """True when every target point is in front of the camera and inside the image."""
        if np.any(self.points_in_camera(pose)[:, 0] <= 0.05):
            return False
        px, size = self.pixels(pose), np.array([self.camera.width, self.camera.height])
        return bool(np.all(px >= margin_px) and np.all(px <= size - 1 - margin_px))

    def reference_geometry(self, reference_pose: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
        """What F* sees: m*_i (N, 3), the unit normal n* in F* toward the plane and d* (m), (7)."""
        reference_pose = np.asarray(reference_pose, dtype=float)
        m_ref = self.normalized_points(reference_pose)
        # The wall's unit normal in W (into the wall), turned into F*.
        normal = rotation_z(reference_pose[2]).T @ np.array([1.0, 0.0, 0.0])
        d_star = float(self.wall_x - reference_pose[0])
        return m_ref, normal, d_star

    def poster_to_image_homography(self, pose: ArrayLike) -> NDArray[np.float64]:
        """``G = K P Rz(phi)^T [right, down, top_left - p_cam]``: poster metres to ideal pixels."""
        pose = np.asarray(pose, dtype=float)
        poster = self.target.poster
        to_robot = rotation_z(pose[2]).T
        origin = poster.to_world(np.zeros(2)) - np.array([pose[0], pose[1], self.camera_height])
        columns = np.column_stack([poster.right, poster.down, origin])
        return self.camera.K @ PAPER_TO_OPENCV @ to_robot @ columns

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready description (the ``world`` record of a teach file)."""
        target = self.target
        return {
            "camera": camera_description(self.camera),
            "camera_height_m": self.camera_height,
            "target": {
                "kind": target.kind,
                "points_poster_m": target.points_poster.tolist(),
                "points_world_m": target.points_world.tolist(),
                "dot_radius_m": target.dot_radius,
                "marker_id": target.marker_id,
                "aruco_dictionary": ARUCO_DICTIONARY,
                "texture": target.texture,
                "poster": {key: np.asarray(getattr(target.poster, name)).tolist() for name, key in _POSTER_KEYS.items()},
            },
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "World":
        """Inverse of :meth:`to_dict`; raises :class:`MalformedDataError` on a malformed description."""
        try:
            camera = camera_from_description(data["camera"])
            t = data["target"]
            p = t["poster"]
            poster = Poster(**{name: float(p[key]) if name in ("width", "height") else _vector(p[key], 3)
                               for name, key in _POSTER_KEYS.items()})
            points = np.asarray(t["points_poster_m"], dtype=float)
            if points.ndim != 2 or points.shape[1] != 2 or points.shape[0] < 3 or not np.all(np.isfinite(points)):
                raise ValueError("points_poster_m must be a list of at least 3 finite (a, b) pairs")
            kind = str(t["kind"])
            if kind not in TARGET_KINDS:
                raise ValueError(f"unknown target kind {kind!r}")
            optional = {name: convert(t[key]) for name, (key, convert) in _TARGET_OPTIONAL_KEYS.items() if key in t}
            target = Target(kind=kind, points_poster=points, poster=poster, **optional)
            return cls(camera=camera, camera_height=float(data["camera_height_m"]), target=target)
        except (KeyError, TypeError, ValueError) as exc:
            raise MalformedDataError(f"malformed world description: {exc}") from None


#: Largest poster side (m) accepted from a file: at 640 px/m, a raster of 6400 px a side.
MAX_POSTER_SIDE_M = 10.0


def world_from_description(data: Any, source: str) -> World:
    """The :class:`World` of a recorded description, checked so that rendering it is safe
    (poster at most :data:`MAX_POSTER_SIDE_M` a side, unit orthogonal axes, finite dot radius,
    at most :data:`MAX_TARGET_POINTS` points); RecordingError otherwise."""
    if isinstance(data, dict) and "targets" in data:
        raise RecordingError(f"{source}: a simulated route of several targets (teach --route) where one target's "
                             "world is expected: hbvs fit splits a route into segments")
    try:
        world = World.from_dict(data)
    except HbvsError as exc:  # World says "malformed world description: ..." itself
        raise RecordingError(f"{source}: {exc}") from None
    except (LookupError, TypeError, ValueError, AttributeError, ArithmeticError) as exc:
        raise RecordingError(f"{source}: malformed world description ({exc})") from None
    target = world.target
    poster = target.poster
    axes = np.array([poster.right, poster.down])
    problems = [
        (not (0.0 < poster.width <= MAX_POSTER_SIDE_M and 0.0 < poster.height <= MAX_POSTER_SIDE_M),
         f"the poster must measure more than 0 and at most {MAX_POSTER_SIDE_M:g} m a side"),
        (not np.allclose(axes @ axes.T, np.eye(2), atol=1e-6), "the poster's axes are not orthogonal unit vectors"),
        (not (math.isfinite(target.dot_radius) and 0.0 <= target.dot_radius <= max(poster.width, poster.height)),
         "the dot radius is not a size on the poster"),
        (target.points_poster.shape[0] > MAX_TARGET_POINTS, f"more than {MAX_TARGET_POINTS} target points"),
    ]
    for failed, reason in problems:
        if failed:
            raise RecordingError(f"{source}: malformed world description ({reason})")
    return world


def _vector(values: Any, size: int) -> NDArray[np.float64]:
    array = np.asarray(values, dtype=float)
    if array.shape != (size,) or not np.all(np.isfinite(array)):
        raise ValueError(f"expected {size} finite numbers, got {values!r}")
    return array


#: Default wall distance from the start of the taught path (m).
DEFAULT_WALL_X = 4.0
#: Default height of the camera's optical centre (m).
DEFAULT_CAMERA_HEIGHT = 0.30


#: Dot centres as fractions of the dot poster's width and height (from its top-left corner),
#: the default scalene triangle first: at least 0.3 m apart and none level with the camera.
DOT_LAYOUT: tuple[tuple[float, float], ...] = (
    (0.06, 0.70), (0.94, 0.55), (0.47, 0.09), (0.82, 0.12), (0.24, 0.28),
    (0.70, 0.80), (0.42, 0.55), (0.10, 0.06), (0.30, 0.88), (0.96, 0.90),
)

def default_target(kind: str = "dots", dots: int = 3, texture: str = "builtin", wall_x: float = DEFAULT_WALL_X) -> Target:
    """The default target of each kind, centred 0.75 m high on the wall in front of the start;
    wide, since theta's noise grows as (distance / width)^2."""
    if kind not in TARGET_KINDS:
        raise InvalidValueError(f"unknown target kind {kind!r}: choose one of {', '.join(TARGET_KINDS)}")
    center = np.array([wall_x, 0.0, 0.75])
    if kind == "dots":
        if not 3 <= dots <= len(DOT_LAYOUT):
            raise InvalidValueError(f"a dot target has 3 to {len(DOT_LAYOUT)} dots, got {dots}")
        poster = Poster(center=center, width=2.0, height=0.9)
        points = np.array(DOT_LAYOUT[:dots]) * [poster.width, poster.height]
        return Target(kind="dots", points_poster=points, poster=poster, dot_radius=0.05)
    if kind == "aruco":
        poster = Poster(center=center, width=0.9, height=0.9)
        side, margin = 0.6, 0.15
        # OpenCV's corner order: top-left, top-right, bottom-right, bottom-left.
        points = np.array([[margin, margin], [margin + side, margin], [margin + side, margin + side], [margin, margin + side]])
        return Target(kind="aruco", points_poster=points, poster=poster, marker_id=7)
    poster = Poster(center=center, width=1.8, height=0.9)
    inset_a, inset_b = 0.10 * poster.width, 0.10 * poster.height
    points = np.array([[inset_a, inset_b], [poster.width - inset_a, inset_b], [poster.width - inset_a, poster.height - inset_b], [inset_a, poster.height - inset_b]])
    return Target(kind="texture", points_poster=points, poster=poster, texture=texture)


def default_world(
    kind: str = "dots",
    camera: CameraIntrinsics = DEFAULT_CAMERA,
    dots: int = 3,
    texture: str = "builtin",
    wall_x: float = DEFAULT_WALL_X,
) -> World:
    """The default world: the default camera 0.30 m above the floor, the wall at x = 4 m."""
    return World(camera=camera, camera_height=DEFAULT_CAMERA_HEIGHT, target=default_target(kind, dots, texture, wall_x))
