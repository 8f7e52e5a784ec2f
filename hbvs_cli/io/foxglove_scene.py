"""What Foxglove's 3D panel needs: frame transforms, the target, the taught path.

Frames (the same in the Foxglove files and in the ROS 2 export, :mod:`.ros_export`):

* ``world``: the simulator's world frame, x toward the wall, z up (m).
* ``base_link``: the robot on the floor, x forward, z up; ``world -> base_link`` is the
  robot's planar pose, published at every pose (``foxglove.FrameTransform`` on ``/tf``).
* ``camera_optical``: the camera at its height above ``base_link``, in the optical
  convention that Foxglove's ``CameraCalibration`` and ROS's ``CameraInfo`` assume: z
  forward (the robot's x), x right (the robot's -y), y down (the robot's -z). Images,
  annotations and the calibration are in this frame. ``base_link -> camera_optical`` is
  published once, at the first pose.

The target (its points as spheres, the poster as a thin box) and the taught path (a line)
are one ``foxglove.SceneUpdate`` on ``/scene``, in ``world``, written when the world and
the path are known (a simulated teach, a simulated run).
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from .messages import CAMERA_FRAME as OPTICAL_FRAME
from .messages import WORLD_FRAME
from .topics import FRAME_TRANSFORM_SCHEMA, SCENE_TOPIC, SCENE_UPDATE_SCHEMA, TRANSFORM_TOPIC

BASE_FRAME = "base_link"

#: Rotation of ``camera_optical`` in ``base_link`` (x, y, z, w): its columns are the optical
#: axes in the robot's frame, x_opt = -y, y_opt = -z, z_opt = +x.
OPTICAL_FROM_BASE_MATRIX = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
OPTICAL_FROM_BASE_QUATERNION = (-0.5, 0.5, -0.5, 0.5)

_TARGET_COLOR = {"r": 0.1, "g": 0.9, "b": 0.2, "a": 1.0}
_POSTER_COLOR = {"r": 0.9, "g": 0.9, "b": 0.9, "a": 0.6}
_PATH_COLOR = {"r": 1.0, "g": 0.3, "b": 0.1, "a": 1.0}
_IDENTITY_POSE = {"position": {"x": 0.0, "y": 0.0, "z": 0.0}, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}
_FOREVER = {"sec": 0, "nsec": 0}


def _vector(values: Sequence[float]) -> dict[str, float]:
    x, y, z = (float(v) for v in values)
    return {"x": x, "y": y, "z": z}


def _quaternion(values: Sequence[float]) -> dict[str, float]:
    x, y, z, w = (float(v) for v in values)
    return {"x": x, "y": y, "z": z, "w": w}


def frame_transform(timestamp: dict[str, int], parent: str, child: str, translation: Sequence[float], rotation: Sequence[float]) -> dict[str, Any]:
    """A ``foxglove.FrameTransform``: ``child``'s pose in ``parent`` (m; unit quaternion x, y, z, w)."""
    return {
        "timestamp": timestamp, "parent_frame_id": parent, "child_frame_id": child,
        "translation": _vector(translation), "rotation": _quaternion(rotation),
    }


def robot_transform(timestamp: dict[str, int], pose: Sequence[float]) -> dict[str, Any]:
    """``world -> base_link`` of a planar pose (x, y, phi) (m, m, rad)."""
    from ..core.frames import yaw_to_quaternion

    x, y, phi = (float(v) for v in pose)
    return frame_transform(timestamp, WORLD_FRAME, BASE_FRAME, (x, y, 0.0), yaw_to_quaternion(phi))


def camera_transform(timestamp: dict[str, int], camera_height: float) -> dict[str, Any]:
    """``base_link -> camera_optical``: the camera ``camera_height`` (m) above the wheel axis."""
    return frame_transform(timestamp, BASE_FRAME, OPTICAL_FRAME, (0.0, 0.0, camera_height), OPTICAL_FROM_BASE_QUATERNION)


def _entity(timestamp: dict[str, int], entity_id: str, **primitives: list[dict[str, Any]]) -> dict[str, Any]:
    entity: dict[str, Any] = {
        "timestamp": timestamp, "frame_id": WORLD_FRAME, "id": entity_id, "lifetime": _FOREVER, "frame_locked": False,
        "metadata": [], "arrows": [], "cubes": [], "spheres": [], "cylinders": [], "lines": [], "triangles": [],
        "texts": [], "models": [],
    }
    entity.update(primitives)
    return entity


def target_entity(timestamp: dict[str, int], world: Any) -> dict[str, Any]:
    """The target of a simulated world: its points as spheres, its poster as a thin box."""
    target = world.target
    poster = target.poster
    diameter = max(2.0 * float(target.dot_radius), 0.03)
    spheres = [
        {"pose": {"position": _vector(point), "orientation": _IDENTITY_POSE["orientation"]},
         "size": _vector((diameter, diameter, diameter)), "color": _TARGET_COLOR}
        for point in np.asarray(target.points_world, dtype=float)
    ]
    # The poster's box: its x along the wall normal, y along "right", z along "up".
    right = np.asarray(poster.right, dtype=float)
    up = -np.asarray(poster.down, dtype=float)
    normal = np.cross(right, up)
    from scipy.spatial.transform import Rotation

    rotation = Rotation.from_matrix(np.column_stack([normal, right, up])).as_quat()
    cube = {
        "pose": {"position": _vector(poster.center), "orientation": _quaternion(rotation)},
        "size": _vector((0.01, float(poster.width), float(poster.height))), "color": _POSTER_COLOR,
    }
    return _entity(timestamp, "target", spheres=spheres, cubes=[cube])


def path_entity(timestamp: dict[str, int], poses: np.ndarray, height: float = 0.0) -> dict[str, Any]:
    """The taught path, a line through the planar poses (K, 3) at ``height`` (m)."""
    points = [_vector((x, y, height)) for x, y in np.asarray(poses, dtype=float)[:, :2]]
    line = {
        "type": 0, "pose": _IDENTITY_POSE, "thickness": 0.02, "scale_invariant": False, "points": points,
        "color": _PATH_COLOR, "colors": [], "indices": [],
    }
    return _entity(timestamp, "taught_path", lines=[line])


def scene_update(timestamp: dict[str, int], world: Any = None, taught_poses: np.ndarray | None = None) -> dict[str, Any]:
    """A ``foxglove.SceneUpdate`` with the target (when ``world`` is given) and the taught path."""
    entities = []
    if world is not None:
        entities.append(target_entity(timestamp, world))
    if taught_poses is not None and len(taught_poses) > 1:
        entities.append(path_entity(timestamp, taught_poses))
    return {"deletions": [], "entities": entities}


class SceneWriter:
    """Writes the 3D topics of one hbvs file through an :class:`~hbvs_cli.io.mcap.McapWriter`.

    :meth:`start` once (the camera on the robot, the target, the taught path), then
    :meth:`pose` at every true pose. Call sites stay a line each.
    """

    def __init__(self, writer: Any) -> None:
        self.writer = writer
        self.started = False

    def start(self, ns: int, camera_height: float, world: Any = None, taught_poses: np.ndarray | None = None) -> None:
        """``base_link -> camera_optical`` and the scene (target, taught path), at ``ns``."""
        from .mcap import time_message

        stamp = time_message(ns)
        self.writer.write(TRANSFORM_TOPIC, FRAME_TRANSFORM_SCHEMA, ns, camera_transform(stamp, camera_height))
        scene = scene_update(stamp, world, taught_poses)
        if scene["entities"]:
            self.writer.write(SCENE_TOPIC, SCENE_UPDATE_SCHEMA, ns, scene)
        self.started = True

    def pose(self, ns: int, pose: Sequence[float]) -> None:
        """``world -> base_link`` of the planar pose (x, y, phi) at ``ns``."""
        from .mcap import time_message

        self.writer.write(TRANSFORM_TOPIC, FRAME_TRANSFORM_SCHEMA, ns, robot_transform(time_message(ns), pose))


#: Where the clock of a simulated teach or run starts (ns since 1970, UTC): 2003-10-27
#: 00:00:00, the opening day of IROS 2003, where Chen et al. presented the method. A fixed
#: epoch gives Foxglove and ROS tools a real date instead of 1 January 1970 while the same
#: inputs and seed still give byte-identical files. A replayed run keeps the stamps of the
#: recording it replays, so that the two line up.
SIMULATION_EPOCH_NS = 1_067_212_800 * 1_000_000_000
