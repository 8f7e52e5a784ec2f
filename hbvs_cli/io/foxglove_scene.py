"""What Foxglove's 3D panel needs: frame transforms, the target, the taught path. Frames (also the ROS 2
export's): ``world`` (x toward the wall, z up, m); ``base_link`` (the robot on the floor, x forward, z up);
``camera_optical`` (at the camera's height, z forward, x right, y down, as ``CameraInfo`` assumes)."""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from .messages import CAMERA_FRAME as OPTICAL_FRAME
from .messages import WORLD_FRAME, color, pose_at, quaternion, stamp, vector3
from .topics import FRAME_TRANSFORM_SCHEMA, SCENE_TOPIC, SCENE_UPDATE_SCHEMA, TRANSFORM_TOPIC

BASE_FRAME = "base_link"

#: Rotation of ``camera_optical`` in ``base_link`` (x, y, z, w): the optical axes in the
#: robot's frame are x_opt = -y, y_opt = -z, z_opt = +x.
OPTICAL_FROM_BASE_QUATERNION = (-0.5, 0.5, -0.5, 0.5)


def frame_transform(ns: int, parent: str, child: str, translation: Sequence[float], rotation: Sequence[float]) -> Any:
    """A ``foxglove.FrameTransform``: ``child``'s pose in ``parent`` (m; unit quaternion x, y, z, w)."""
    from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform

    return FrameTransform(
        timestamp=stamp(ns), parent_frame_id=parent, child_frame_id=child,
        translation=vector3(translation), rotation=quaternion(rotation),
    )


def _entity(ns: int, entity_id: str, **primitives: list[Any]) -> Any:
    from google.protobuf.duration_pb2 import Duration
    from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity

    return SceneEntity(timestamp=stamp(ns), frame_id=WORLD_FRAME, id=entity_id, lifetime=Duration(), frame_locked=False, **primitives)


def target_entity(ns: int, target: Any, entity_id: str = "target") -> Any:
    """A target of a simulated world: its points as spheres, its poster as a thin box."""
    from foxglove_schemas_protobuf.CubePrimitive_pb2 import CubePrimitive
    from foxglove_schemas_protobuf.SpherePrimitive_pb2 import SpherePrimitive
    from scipy.spatial.transform import Rotation

    poster = target.poster
    diameter = max(2.0 * float(target.dot_radius), 0.03)
    spheres = [
        SpherePrimitive(pose=pose_at(point), size=vector3((diameter, diameter, diameter)), color=color(0.1, 0.9, 0.2, 1.0))
        for point in np.asarray(target.points_world, dtype=float)
    ]
    # The poster's box: its x along the wall normal, y along "right", z along "up".
    right = np.asarray(poster.right, dtype=float)
    up = -np.asarray(poster.down, dtype=float)
    rotation = Rotation.from_matrix(np.column_stack([np.cross(right, up), right, up])).as_quat()
    size = vector3((0.01, float(poster.width), float(poster.height)))
    cube = CubePrimitive(pose=pose_at(poster.center, rotation), size=size, color=color(0.9, 0.9, 0.9, 0.6))
    return _entity(ns, entity_id, spheres=spheres, cubes=[cube])


def path_entity(ns: int, poses: np.ndarray, height: float = 0.0) -> Any:
    """The taught path, a line through the planar poses (K, 3) at ``height`` (m)."""
    from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
    from foxglove_schemas_protobuf.Point3_pb2 import Point3

    points = [Point3(x=float(x), y=float(y), z=float(height)) for x, y in np.asarray(poses, dtype=float)[:, :2]]
    line = LinePrimitive(
        type=LinePrimitive.LINE_STRIP, pose=pose_at((0.0, 0.0, 0.0)), thickness=0.02, scale_invariant=False,
        points=points, color=color(1.0, 0.3, 0.1, 1.0),
    )
    return _entity(ns, "taught_path", lines=[line])


class SceneWriter:
    """Writes the 3D topics of one hbvs file: :meth:`start` once, then :meth:`pose` at every true pose."""

    def __init__(self, writer: Any) -> None:
        self.writer = writer
        self.started = False

    def start(self, ns: int, camera_height: float, world: Any = None, taught_poses: np.ndarray | None = None) -> None:
        """``base_link -> camera_optical`` (the camera ``camera_height`` m above the wheel axis) and the
        scene (a ``foxglove.SceneUpdate``: the target when ``world`` is given, the taught path), at ``ns``."""
        from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

        camera = frame_transform(ns, BASE_FRAME, OPTICAL_FRAME, (0.0, 0.0, camera_height), OPTICAL_FROM_BASE_QUATERNION)
        self.writer.write(TRANSFORM_TOPIC, FRAME_TRANSFORM_SCHEMA, ns, camera)
        entities = []
        if world is not None:
            # A route (sim/route.py) has several targets, placed in its frame; a world has one.
            targets = getattr(world, "route_targets", None) or (world.target,)
            entities.extend(target_entity(ns, target, "target" if i == 0 else f"target_{i}")
                            for i, target in enumerate(targets))
        if taught_poses is not None and len(taught_poses) > 1:
            entities.append(path_entity(ns, taught_poses))
        if entities:
            self.writer.write(SCENE_TOPIC, SCENE_UPDATE_SCHEMA, ns, SceneUpdate(entities=entities))
        self.started = True

    def pose(self, ns: int, pose: Sequence[float]) -> None:
        """``world -> base_link`` of the planar pose (x, y, phi) (m, m, rad) at ``ns``."""
        from ..core.frames import yaw_to_quaternion

        x, y, phi = (float(v) for v in pose)
        robot = frame_transform(ns, WORLD_FRAME, BASE_FRAME, (x, y, 0.0), yaw_to_quaternion(phi))
        self.writer.write(TRANSFORM_TOPIC, FRAME_TRANSFORM_SCHEMA, ns, robot)


#: Where the clock of a simulated teach or run starts (ns since 1970, UTC): 2003-10-27, the
#: opening day of IROS 2003; fixed, so that the same seed gives byte-identical files.
SIMULATION_EPOCH_NS = 1_067_212_800 * 1_000_000_000
