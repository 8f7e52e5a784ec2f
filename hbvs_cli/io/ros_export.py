"""``hbvs export``: a teach, fit or run file as a ROS 2 bag (MCAP storage, CDR) written with ``rosbags``
(topics in docs/ros2.md), moved into place when complete; only a bag hbvs wrote is ever replaced. Poses
keep the camera's height as z, so that ``evo_ape`` on the two pose topics gives what ``hbvs report`` gives."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..core.frames import yaw_to_quaternion
from ..core.path import CommandProfile
from ..errors import OutputError, RecordingError, TruncatedInputError, UsageError
from .fit_file import model_from_message
from .foxglove_scene import BASE_FRAME, OPTICAL_FRAME, OPTICAL_FROM_BASE_QUATERNION, WORLD_FRAME
from .images import read_compressed_image
from .mcap import McapStream, read_metadata, seconds_to_ns
from .messages import velocity_from_message
from .output_target import atomic_folder, directory_lock, remove_stale_partials
from .topics import (
    CALIBRATION_TOPIC, COMMAND_TOPIC, DESIRED_POSE_TOPIC, IMAGE_TOPIC, MODEL_TOPIC, REFERENCE_IMAGE_TOPIC,
    ROS_CAMERA_INFO_SCHEMA, ROS_CAMERA_INFO_TOPIC, ROS_CMD_VEL_TOPIC, ROS_COMPRESSED_IMAGE_SCHEMA, ROS_DESIRED_POSE_TOPIC,
    ROS_IMAGE_TOPIC, ROS_PATH_SCHEMA, ROS_POSE_STAMPED_SCHEMA, ROS_REFERENCE_IMAGE_TOPIC, ROS_TAUGHT_PATH_TOPIC,
    ROS_TF_SCHEMA, ROS_TF_STATIC_TOPIC, ROS_TF_TOPIC, ROS_TRUE_POSE_TOPIC, ROS_TWIST_SCHEMA, TEACH_COMMAND_TOPIC, TOPICS,
    TRUE_POSE_TOPIC,
)

#: rosbag2 metadata version written (read by Iron and later; rosbags reads every version).
BAG_VERSION = 8
BAG_METADATA = "metadata.yaml"
#: The ``custom_data`` entry that marks a bag hbvs wrote (the only kind export replaces).
HBVS_MARK = ("hbvs_export", "1")


@dataclass
class ExportSummary:
    """What was written: the bag folder, the file kind, and messages per bag topic."""

    output: Path
    kind: str
    counts: dict[str, int] = field(default_factory=dict)
    truncated: bool = False


def check_bag_target(spec: str, inputs: tuple[str, ...] = ()) -> Path:
    """The folder ``hbvs export -o`` will write, checked before anything is read: :class:`UsageError` for
    ``-``, anything but a bag hbvs wrote, or an input inside it."""
    if spec == "-":
        raise UsageError("a ROS 2 bag is a folder and cannot go to stdout; give a folder name with -o")
    final = Path(os.path.realpath(spec))
    if not final.parent.is_dir():
        raise OutputError(f"{spec}: the folder {final.parent} does not exist")
    for source in inputs:
        if source != "-" and Path(os.path.realpath(source)).is_relative_to(final):
            raise UsageError(f"{source}: is inside the bag {spec} that the export would replace; copy it elsewhere first")
    if final.exists() or final.is_symlink():
        if not final.is_dir():
            raise UsageError(f"{spec}: exists and is not a ROS 2 bag folder; give a new folder name")
        if any(final.iterdir()) and not written_by_hbvs(final):
            raise UsageError(f"{spec}: is a folder that is not a ROS 2 bag written by hbvs export; it is kept, give a new folder name")
    return final


def written_by_hbvs(folder: Path) -> bool:
    """True when ``folder`` holds hbvs's mark in its ``metadata.yaml`` and no file but the ones
    it lists (so that replacing it deletes nothing else)."""
    from .sources.bag_storage import bag_information

    try:
        information = bag_information(folder, str(folder)) if (folder / BAG_METADATA).is_file() else {}
    except Exception:  # noqa: BLE001 - unreadable, too large, malformed or an alias bomb: not ours
        return False
    custom = information.get("custom_data")
    files = information.get("relative_file_paths")
    if not (isinstance(custom, dict) and str(custom.get(HBVS_MARK[0])) == HBVS_MARK[1] and isinstance(files, list)):
        return False
    listed = {BAG_METADATA, *(str(f) for f in files)}
    return all(entry.name in listed and entry.is_file() and not entry.is_symlink() for entry in folder.iterdir())


class _Bag:
    """A rosbags writer with one connection per topic, opened on first use, and counts; builds the
    ROS 2 messages with the same type store."""

    def __init__(self, writer: Any, typestore: Any) -> None:
        self.writer = writer
        self.typestore = typestore
        self.types = typestore.types
        self.connections: dict[str, Any] = {}
        self.counts: dict[str, int] = {}

    def write(self, topic: str, msgtype: str, ns: int, message: Any) -> None:
        if topic not in self.connections:
            self.connections[topic] = self.writer.add_connection(topic, msgtype, typestore=self.typestore)
        self.writer.write(self.connections[topic], int(ns), bytes(self.typestore.serialize_cdr(message, msgtype)))
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def header(self, ns: int, frame_id: str) -> Any:
        sec, nanosec = divmod(max(int(ns), 0), 1_000_000_000)
        stamp = self.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)
        return self.types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)

    def vector(self, x: float, y: float, z: float) -> Any:
        return self.types["geometry_msgs/msg/Vector3"](x=float(x), y=float(y), z=float(z))

    def quaternion(self, q: Any) -> Any:
        x, y, z, w = (float(v) for v in q)
        return self.types["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w)

    def twist(self, v: float, w: float) -> Any:
        return self.types[ROS_TWIST_SCHEMA](linear=self.vector(v, 0.0, 0.0), angular=self.vector(0.0, 0.0, w))

    def pose_stamped(self, ns: int, position: Any, orientation: Any) -> Any:
        x, y, z = (float(v) for v in position)
        pose = self.types["geometry_msgs/msg/Pose"](
            position=self.types["geometry_msgs/msg/Point"](x=x, y=y, z=z), orientation=self.quaternion(orientation),
        )
        return self.types[ROS_POSE_STAMPED_SCHEMA](header=self.header(ns, WORLD_FRAME), pose=pose)

    def path(self, poses: list[Any]) -> Any:
        return self.types[ROS_PATH_SCHEMA](header=self.header(_stamp_ns(poses[-1].header.stamp), WORLD_FRAME), poses=poses)

    def tf(self, ns: int, parent: str, child: str, translation: Any, rotation: Any) -> Any:
        """A ``TFMessage`` of the one transform of ``child`` in ``parent``."""
        transform = self.types["geometry_msgs/msg/Transform"](translation=self.vector(*translation), rotation=self.quaternion(rotation))
        stamped = self.types["geometry_msgs/msg/TransformStamped"](header=self.header(ns, parent), child_frame_id=child, transform=transform)
        return self.types[ROS_TF_SCHEMA](transforms=[stamped])

    def compressed_image(self, ns: int, data: bytes, image_format: str) -> Any:
        return self.types[ROS_COMPRESSED_IMAGE_SCHEMA](
            header=self.header(ns, OPTICAL_FRAME), format=image_format, data=np.frombuffer(data, dtype=np.uint8),
        )

    def camera_info(self, ns: int, calibration: Any) -> Any:
        roi = self.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        return self.types[ROS_CAMERA_INFO_SCHEMA](
            header=self.header(ns, OPTICAL_FRAME), height=int(calibration.height), width=int(calibration.width),
            distortion_model=str(calibration.distortion_model), d=np.array(calibration.D, dtype=np.float64),
            k=np.array(calibration.K, dtype=np.float64), r=np.array(calibration.R, dtype=np.float64),
            p=np.array(calibration.P, dtype=np.float64), binning_x=0, binning_y=0, roi=roi,
        )


def _pose_fields(message: Any, source: str) -> tuple[list[float], list[float]]:
    """Position and orientation of a ``foxglove.PoseInFrame``, as recorded (3D)."""
    position = [float(getattr(message.pose.position, k)) for k in ("x", "y", "z")]
    orientation = [float(getattr(message.pose.orientation, k)) for k in ("x", "y", "z", "w")]
    if not np.all(np.isfinite(position + orientation)):
        raise RecordingError(f"{source}: a pose message holds NaN or infinity")
    return position, orientation


def export_ros2_bag(source: str, output: str, allow_truncated: bool = False) -> ExportSummary:
    """Write the teach, fit or run file ``source`` (a path or ``-``) as the ROS 2 bag folder ``output``
    (:func:`check_bag_target` first); a truncated ``source`` replaces a bag only with ``allow_truncated``."""
    final = check_bag_target(output, (source,))
    with directory_lock(final.parent):
        # What an export killed by SIGKILL left (its process is dead); nobody else's.
        remove_stale_partials(final.parent.glob(f"{final.name}.*.partial"))
    # Imported here, not at the top: rosbags takes a while to import, and only export needs it.
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    stream = McapStream(source)
    kind: str | None = None
    camera_calibration: Any = None
    path_topic = {"teach": TRUE_POSE_TOPIC, "run": DESIRED_POSE_TOPIC}
    path_poses: list[Any] = []
    def before_swap(work: Path) -> None:
        check_bag_target(output)  # again: another export (or someone) may have put a folder there
        if stream.truncated and final.exists() and not allow_truncated:
            raise TruncatedInputError(
                f"{stream.name} ended before its end record (the writer upstream stopped?), so its bag did not "
                f"replace the existing {final}; pass --allow-truncated to replace it"
            )
        if final.exists() or final.is_symlink():
            os.replace(final, work / "replaced")

    with atomic_folder(final, "bag", before_swap) as bag_path:
        writer = Writer(bag_path, version=BAG_VERSION, storage_plugin=StoragePlugin.MCAP)
        writer.set_custom_data(*HBVS_MARK)
        writer.open()
        bag = _Bag(writer, get_typestore(Stores.ROS2_HUMBLE))
        try:
            for message in stream:
                kind = kind or _file_kind(stream)
                expected = TOPICS[kind].get(message.topic)
                if expected is None:
                    continue
                if message.schema_name != expected:
                    raise RecordingError(f"{stream.name}: {message.topic} holds {message.schema_name[:60]!r}, expected {expected}")
                ns = message.log_time
                if message.topic in (COMMAND_TOPIC, TEACH_COMMAND_TOPIC):
                    v, w = velocity_from_message(message.json(stream.name), stream.name)
                    bag.write(ROS_CMD_VEL_TOPIC, ROS_TWIST_SCHEMA, ns, bag.twist(v, w))
                elif message.topic in (TRUE_POSE_TOPIC, DESIRED_POSE_TOPIC):
                    position, orientation = _pose_fields(message.foxglove(stream.name), stream.name)
                    pose = bag.pose_stamped(ns, position, orientation)
                    topic = ROS_TRUE_POSE_TOPIC if message.topic == TRUE_POSE_TOPIC else ROS_DESIRED_POSE_TOPIC
                    bag.write(topic, ROS_POSE_STAMPED_SCHEMA, ns, pose)
                    if path_topic.get(kind) == message.topic:
                        path_poses.append(pose)
                    if message.topic == TRUE_POSE_TOPIC:
                        if ROS_TF_STATIC_TOPIC not in bag.counts:  # the camera's height: the first true pose's z
                            bag.write(ROS_TF_STATIC_TOPIC, ROS_TF_SCHEMA, ns, bag.tf(
                                ns, BASE_FRAME, OPTICAL_FRAME, (0.0, 0.0, position[2]), OPTICAL_FROM_BASE_QUATERNION))
                        bag.write(ROS_TF_TOPIC, ROS_TF_SCHEMA, ns, bag.tf(
                            ns, WORLD_FRAME, BASE_FRAME, (position[0], position[1], 0.0), orientation))
                elif message.topic == CALIBRATION_TOPIC:
                    camera_calibration = message.foxglove(stream.name)
                elif message.topic in (IMAGE_TOPIC, REFERENCE_IMAGE_TOPIC):
                    image = read_compressed_image(message.data, stream.name)
                    topic = ROS_IMAGE_TOPIC if message.topic == IMAGE_TOPIC else ROS_REFERENCE_IMAGE_TOPIC
                    bag.write(topic, ROS_COMPRESSED_IMAGE_SCHEMA, ns, bag.compressed_image(ns, image.data, image.format))
                    if message.topic == IMAGE_TOPIC and camera_calibration is not None:
                        bag.write(ROS_CAMERA_INFO_TOPIC, ROS_CAMERA_INFO_SCHEMA, ns, bag.camera_info(ns, camera_calibration))
                elif message.topic == MODEL_TOPIC:
                    path_poses = _fit_taught_path(message.json(stream.name), stream.name, bag)
            kind = kind or _file_kind(stream)
            if path_poses:
                path = bag.path(path_poses)
                bag.write(ROS_TAUGHT_PATH_TOPIC, ROS_PATH_SCHEMA, _stamp_ns(path.header.stamp), path)
        finally:
            writer.close()
        if not bag.counts:
            raise RecordingError(f"{stream.name}: nothing to export (no commands, poses or images in this {kind} file)")
    return ExportSummary(output=final, kind=kind, counts=bag.counts, truncated=stream.truncated)


def _stamp_ns(stamp: Any) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _file_kind(stream: McapStream) -> str:
    kind = read_metadata(stream, "hbvs").get("file_kind")
    if kind not in TOPICS:
        raise RecordingError(f"{stream.name}: not an hbvs teach, fit or run file (no hbvs metadata naming its kind)")
    return str(kind)


def _fit_taught_path(model_message: dict[str, Any], source: str, bag: _Bag) -> list[Any]:
    """The taught path of a fit file: poses at the taught frames, integrated from the taught commands."""
    model = model_from_message(model_message, source)
    taught = model.taught_path
    if taught is None:
        return []
    step = float(np.median(np.diff(taught.t)))
    profile = CommandProfile(t=taught.t, v=taught.v, w=taught.w, t_end=float(taught.t[-1] + step))
    poses = profile.poses_at(taught.t - taught.t[0], taught.start_pose)
    height = float(model.world_description["camera_height_m"]) if model.world_description is not None else 0.0
    quaternions = yaw_to_quaternion(poses[:, 2])
    return [bag.pose_stamped(seconds_to_ns(t), (x, y, height), q) for t, (x, y, _), q in zip(taught.t, poses, quaternions)]
