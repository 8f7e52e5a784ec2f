"""ROS 2 over DDS without ROS: the messages, names and QoS hbvs speaks on a live robot.

ROS 2 topics are DDS topics ``rt/<name>`` of types ``<pkg>::msg::dds_::<Type>_`` in plain
CDR, so the few messages hbvs needs are Cyclone DDS IDL structs with those names
(``tests/test_live_dds.py`` checks them against ``rosbags``' typestore).
"""

# No "from __future__ import annotations": the binding reads the structs' annotations as types.

import os
from dataclasses import dataclass, field
from typing import Any

from ..errors import InputError, UsageError
from .topics import (
    ROS_CAMERA_INFO_SCHEMA, ROS_COMPRESSED_IMAGE_SCHEMA, ROS_IMAGE_SCHEMA, ROS_POSE_STAMPED_SCHEMA, ROS_TWIST_SCHEMA,
    ROS_TWIST_STAMPED_SCHEMA,
)

INSTALL_HINT = "ROS 2 topics need Eclipse Cyclone DDS's Python binding: pip install 'hbvs[ros2]'"

try:
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.idl import IdlStruct
    from cyclonedds.idl.types import array, float64, int32, sequence, uint8, uint32
    from cyclonedds.pub import DataWriter
    from cyclonedds.qos import Policy, Qos
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic
    from cyclonedds.util import duration
except ImportError:
    raise UsageError(INSTALL_HINT) from None


# ----------------------------------------------------------------------------- messages
def dds_type_name(ros_type: str) -> str:
    """The DDS type name of a ROS 2 message type, as the ROS 2 RMWs register it:
    ``geometry_msgs/msg/Twist`` -> ``geometry_msgs::msg::dds_::Twist_``."""
    package, kind, name = ros_type.split("/")
    return f"{package}::{kind}::dds_::{name}_"


@dataclass
class Time(IdlStruct, typename=dds_type_name("builtin_interfaces/msg/Time")):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Header(IdlStruct, typename=dds_type_name("std_msgs/msg/Header")):
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
class Vector3(IdlStruct, typename=dds_type_name("geometry_msgs/msg/Vector3")):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Twist(IdlStruct, typename=dds_type_name(ROS_TWIST_SCHEMA)):
    linear: Vector3 = field(default_factory=Vector3)
    angular: Vector3 = field(default_factory=Vector3)


@dataclass
class TwistStamped(IdlStruct, typename=dds_type_name(ROS_TWIST_STAMPED_SCHEMA)):
    header: Header = field(default_factory=Header)
    twist: Twist = field(default_factory=Twist)


@dataclass
class Point(IdlStruct, typename=dds_type_name("geometry_msgs/msg/Point")):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Quaternion(IdlStruct, typename=dds_type_name("geometry_msgs/msg/Quaternion")):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0
    w: float64 = 1.0


@dataclass
class Pose(IdlStruct, typename=dds_type_name("geometry_msgs/msg/Pose")):
    position: Point = field(default_factory=Point)
    orientation: Quaternion = field(default_factory=Quaternion)


@dataclass
class PoseStamped(IdlStruct, typename=dds_type_name(ROS_POSE_STAMPED_SCHEMA)):
    header: Header = field(default_factory=Header)
    pose: Pose = field(default_factory=Pose)


@dataclass
class Image(IdlStruct, typename=dds_type_name(ROS_IMAGE_SCHEMA)):
    header: Header = field(default_factory=Header)
    height: uint32 = 0
    width: uint32 = 0
    encoding: str = ""
    is_bigendian: uint8 = 0
    step: uint32 = 0
    data: sequence[uint8] = b""  # bytes on the Python side: see _octets_as_bytes


@dataclass
class CompressedImage(IdlStruct, typename=dds_type_name(ROS_COMPRESSED_IMAGE_SCHEMA)):
    header: Header = field(default_factory=Header)
    format: str = ""
    data: sequence[uint8] = b""  # bytes on the Python side: see _octets_as_bytes


@dataclass
class RegionOfInterest(IdlStruct, typename=dds_type_name("sensor_msgs/msg/RegionOfInterest")):
    x_offset: uint32 = 0
    y_offset: uint32 = 0
    height: uint32 = 0
    width: uint32 = 0
    do_rectify: bool = False


@dataclass
class CameraInfo(IdlStruct, typename=dds_type_name(ROS_CAMERA_INFO_SCHEMA)):
    header: Header = field(default_factory=Header)
    height: uint32 = 0
    width: uint32 = 0
    distortion_model: str = ""
    d: sequence[float64] = field(default_factory=list)
    k: array[float64, 9] = field(default_factory=lambda: [0.0] * 9)
    r: array[float64, 9] = field(default_factory=lambda: [0.0] * 9)
    p: array[float64, 12] = field(default_factory=lambda: [0.0] * 12)
    binning_x: uint32 = 0
    binning_y: uint32 = 0
    roi: RegionOfInterest = field(default_factory=RegionOfInterest)


def _octets_as_bytes(message_type: type, name: str) -> None:
    """(De)serialise the ``sequence[uint8]`` field ``name`` as ``bytes`` in one block (the
    binding's list of ints costs 40 ms an image): the member's serialiser is swapped for the
    binding's ``bytes`` one, whose CDR is identical. Raises if the binding's layout differs."""
    from cyclonedds.idl._machinery import BytesMachine, PlainCdrV2SequenceOfPrimitiveMachine, StructMachine

    support = message_type.__idl__
    support.populate()
    for machine in (support.v1_machine, support.v2_machine):
        if not isinstance(machine, StructMachine) or not isinstance(machine.members_machines.get(name), PlainCdrV2SequenceOfPrimitiveMachine):
            raise RuntimeError(f"cyclonedds: unexpected serialiser layout for {message_type.__name__}.{name}")
        machine.members_machines[name] = BytesMachine()


_octets_as_bytes(Image, "data")
_octets_as_bytes(CompressedImage, "data")


#: ROS 2 type name (as rosbags and ``ros2 topic info`` spell it) -> IDL struct.
MESSAGE_TYPES: dict[str, type] = {
    "builtin_interfaces/msg/Time": Time,
    "std_msgs/msg/Header": Header,
    "geometry_msgs/msg/Vector3": Vector3,
    ROS_TWIST_SCHEMA: Twist,
    ROS_TWIST_STAMPED_SCHEMA: TwistStamped,
    "geometry_msgs/msg/Point": Point,
    "geometry_msgs/msg/Quaternion": Quaternion,
    "geometry_msgs/msg/Pose": Pose,
    ROS_POSE_STAMPED_SCHEMA: PoseStamped,
    ROS_IMAGE_SCHEMA: Image,
    ROS_COMPRESSED_IMAGE_SCHEMA: CompressedImage,
    "sensor_msgs/msg/RegionOfInterest": RegionOfInterest,
    ROS_CAMERA_INFO_SCHEMA: CameraInfo,
}

def stamp_of(seconds: float) -> Time:
    """A ROS 2 time from seconds (floor to whole seconds, the rest in ns)."""
    ns = int(round(seconds * 1e9))
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def seconds_of(stamp: Time) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


# ----------------------------------------------------------------------------- names, QoS
def dds_topic_name(ros_name: str) -> str:
    """The DDS topic of a ROS 2 topic: ``/cmd_vel`` -> ``rt/cmd_vel``."""
    name = ros_name.strip()
    if not name.startswith("/"):
        name = "/" + name
    if name == "/" or "//" in name or name.endswith("/") or any(c.isspace() for c in name):
        raise UsageError(f"not a ROS 2 topic name: {ros_name!r}")
    return "rt" + name


def camera_info_topic(image_topic: str) -> str:
    """The sibling ``camera_info`` topic as image_transport names it:
    ``/camera/image_raw`` and ``/camera/image_raw/compressed`` -> ``/camera/camera_info``."""
    parts = image_topic.rstrip("/").split("/")
    if parts and parts[-1] in ("compressed", "theora", "compressedDepth"):
        parts = parts[:-1]
    return "/".join(parts[:-1] + ["camera_info"]) if len(parts) > 1 else "/camera_info"


def command_qos() -> Qos:
    """ROS 2's default QoS: reliable, keep last 10, volatile."""
    return Qos(Policy.Reliability.Reliable(duration(milliseconds=100)), Policy.History.KeepLast(10), Policy.Durability.Volatile)


def sensor_qos() -> Qos:
    """ROS 2's sensor-data QoS: best effort, keep last 5, volatile."""
    return Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(5), Policy.Durability.Volatile)


def domain_id() -> int:
    """``ROS_DOMAIN_ID``, 0 when unset (as ROS 2)."""
    text = os.environ.get("ROS_DOMAIN_ID", "").strip()
    if not text:
        return 0
    try:
        value = int(text)
    except ValueError:
        raise UsageError(f"ROS_DOMAIN_ID must be a number from 0 to 232, got {text!r}") from None
    if not 0 <= value <= 232:
        raise UsageError(f"ROS_DOMAIN_ID must be a number from 0 to 232, got {value}")
    return value


def loopback_config() -> str:
    """A Cyclone DDS configuration (``CYCLONEDDS_URI``, syntax of 0.10 and later) that keeps
    DDS on this machine: ``lo`` only, no multicast, unicast discovery of 127.0.0.1."""

    return (
        '<CycloneDDS xmlns="https://cdds.io/config"><Domain Id="any">'
        "<General><Interfaces><NetworkInterface name=\"lo\"/></Interfaces>"
        "<AllowMulticast>false</AllowMulticast></General>"
        "<Discovery><ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>60</MaxAutoParticipantIndex>"
        '<Peers><Peer address="127.0.0.1"/></Peers></Discovery>'
        "</Domain></CycloneDDS>"
    )


# ----------------------------------------------------------------------------- endpoints
class Ros2Node:
    """One DDS participant on ``ROS_DOMAIN_ID``, with its ROS 2 publishers and subscribers."""

    def __init__(self) -> None:
        try:
            self.participant = DomainParticipant(domain_id())
        except Exception as exc:  # the binding raises DDSException with a return code
            raise InputError(f"DDS: cannot join domain {domain_id()} ({exc}); check CYCLONEDDS_URI") from None
        self._topics: dict[str, Any] = {}

    def _topic(self, ros_name: str, message_type: type) -> Any:
        name = dds_topic_name(ros_name)
        if name in self._topics:
            topic = self._topics[name]
            if topic.data_type is not message_type:
                raise UsageError(f"{ros_name}: used with two message types")
            return topic
        topic = Topic(self.participant, name, message_type)
        self._topics[name] = topic
        return topic

    def publisher(self, ros_name: str, message_type: type, qos: Qos) -> DataWriter:
        return DataWriter(self.participant, self._topic(ros_name, message_type), qos=qos)

    def subscriber(self, ros_name: str, message_type: type, qos: Qos) -> DataReader:
        return DataReader(self.participant, self._topic(ros_name, message_type), qos=qos)
