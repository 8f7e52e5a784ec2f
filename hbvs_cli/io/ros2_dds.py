"""ROS 2 over DDS without ROS: the messages, names and QoS hbvs speaks on a live robot. ROS 2 topics
are DDS topics ``rt/<name>`` of types ``<pkg>::msg::dds_::<Type>_`` in plain CDR, so the messages are
Cyclone DDS IDL structs of those names, made from ``rosbags``' message definitions."""

import os
import types
from dataclasses import dataclass, field
from typing import Any

from ..errors import InputError, UsageError
from .dds_discovery import dds_settings
from .ros2_names import full_topic_name
from .topics import (
    ROS_CAMERA_INFO_SCHEMA, ROS_COMPRESSED_IMAGE_SCHEMA, ROS_IMAGE_SCHEMA, ROS_POSE_STAMPED_SCHEMA, ROS_TWIST_STAMPED_SCHEMA,
)

INSTALL_HINT = "ROS 2 topics need Eclipse Cyclone DDS's Python binding: pip install 'hbvs[ros2]'"

try:
    from cyclonedds.domain import Domain, DomainParticipant
    from cyclonedds.idl import IdlStruct
    from cyclonedds.idl.types import array, float64, int32, sequence, uint8, uint32
    from cyclonedds.pub import DataWriter
    from cyclonedds.qos import Policy, Qos
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic
    from cyclonedds.util import duration
except ImportError:
    raise UsageError(INSTALL_HINT) from None


def _idl_structs(ros_types: tuple[str, ...]) -> dict[str, type]:
    """IDL structs of ROS 2 message types (and the types they nest) from rosbags' Humble definitions,
    fields defaulting to zero, "" and their own default; ``uint8[]`` is ``bytes``."""
    from rosbags.interfaces import Nodetype
    from rosbags.typesys import Stores, get_typestore

    definitions = get_typestore(Stores.ROS2_HUMBLE).fielddefs
    base = {"float64": (float64, 0.0), "int32": (int32, 0), "uint32": (uint32, 0), "uint8": (uint8, 0),
            "bool": (bool, False), "string": (str, "")}
    made: dict[str, type] = {}

    def typed(node: tuple[Any, Any]) -> tuple[Any, Any]:
        kind, detail = node
        if kind == Nodetype.BASE:
            return base[detail[0]][0], field(default=base[detail[0]][1])
        if kind == Nodetype.NAME:
            return make(detail), field(default_factory=make(detail))
        element, zero = detail[0][1][0], base[detail[0][1][0]][1]
        if kind == Nodetype.ARRAY:
            return array[base[element][0], detail[1]], field(default_factory=lambda: [zero] * detail[1])
        if element == "uint8":
            return sequence[uint8], field(default=b"")
        return sequence[base[element][0]], field(default_factory=list)

    def make(ros_type: str) -> type:
        if ros_type not in made:
            members = {name: typed(node) for name, node in definitions[ros_type][1]}
            body = {"__module__": __name__, "__annotations__": {k: v[0] for k, v in members.items()}}
            body.update({k: v[1] for k, v in members.items()})
            # The type name the ROS 2 RMWs register: geometry_msgs/msg/Twist -> geometry_msgs::msg::dds_::Twist_.
            package, kind, name = ros_type.split("/")
            cls = types.new_class(name, (IdlStruct,), {"typename": f"{package}::{kind}::dds_::{name}_"},
                                  lambda namespace: namespace.update(body))
            made[ros_type] = dataclass(cls)
            for name, node in definitions[ros_type][1]:
                if node == (Nodetype.SEQUENCE, ((Nodetype.BASE, ("uint8", 0)), 0)):
                    _octets_as_bytes(made[ros_type], name)
        return made[ros_type]

    for ros_type in ros_types:
        make(ros_type)
    return made


def _octets_as_bytes(message_type: type, name: str) -> None:
    """(De)serialise the ``sequence[uint8]`` field ``name`` with the binding's ``bytes`` serialiser (same
    CDR, one block instead of a list of ints); raises if the binding's layout differs."""
    from cyclonedds.idl._machinery import BytesMachine, PlainCdrV2SequenceOfPrimitiveMachine, StructMachine

    support = message_type.__idl__
    support.populate()
    for machine in (support.v1_machine, support.v2_machine):
        if not isinstance(machine, StructMachine) or not isinstance(machine.members_machines.get(name), PlainCdrV2SequenceOfPrimitiveMachine):
            raise RuntimeError(f"cyclonedds: unexpected serialiser layout for {message_type.__name__}.{name}")
        machine.members_machines[name] = BytesMachine()


#: ROS 2 type name (as rosbags and ``ros2 topic info`` spell it) -> IDL struct.
MESSAGE_TYPES: dict[str, type] = _idl_structs((
    ROS_TWIST_STAMPED_SCHEMA, ROS_POSE_STAMPED_SCHEMA, ROS_IMAGE_SCHEMA, ROS_COMPRESSED_IMAGE_SCHEMA, ROS_CAMERA_INFO_SCHEMA,
))
# Bound to module names (dds.Twist, dds.Image...), as the rest of hbvs uses them.
_BY_NAME = {cls.__name__: cls for cls in MESSAGE_TYPES.values()}
Time, Header, Vector3, Point, Quaternion, Pose, PoseStamped = (_BY_NAME[n] for n in ("Time", "Header", "Vector3", "Point", "Quaternion", "Pose", "PoseStamped"))
Twist, TwistStamped, Image, CompressedImage, RegionOfInterest, CameraInfo = (
    _BY_NAME[n] for n in ("Twist", "TwistStamped", "Image", "CompressedImage", "RegionOfInterest", "CameraInfo")
)


def stamp_of(seconds: float) -> Time:
    """A ROS 2 time from seconds (floor to whole seconds, the rest in ns)."""
    ns = int(round(seconds * 1e9))
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def seconds_of(stamp: Time) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


def dds_topic_name(ros_name: str) -> str:
    """The DDS topic of a ROS 2 topic: ``/cmd_vel`` (or ``cmd_vel``) -> ``rt/cmd_vel``; a name ROS 2
    refuses is a :class:`UsageError` (:func:`.ros2_names.full_topic_name`)."""
    return "rt" + full_topic_name(ros_name)


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


def camera_qos() -> Qos:
    """What a camera offers: reliable, keep last 1, volatile. Reliable matches ROS 2 subscribers of either
    profile (a best-effort writer gets none with the default, reliable one: "incompatible QoS"), and a
    reliable reader gets each lost fragment of a large image sent again; keep last 1 resends only the
    newest frame, never a stale one."""
    return Qos(Policy.Reliability.Reliable(duration(milliseconds=100)), Policy.History.KeepLast(1), Policy.Durability.Volatile)


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
    """A Cyclone DDS configuration (a ``CYCLONEDDS_URI``; Cyclone DDS 11 and later) that keeps DDS on this machine:
    ``lo`` only, no multicast, unicast discovery of 127.0.0.1 (what ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``
    gives, :func:`.dds_discovery.dds_settings`)."""
    return dds_settings({"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}).config


#: The domains this process made, by id: alive as long as the process (a participant needs its domain).
_DOMAINS: dict[int, Any] = {}

class Ros2Node:
    """One DDS participant on ``ROS_DOMAIN_ID``, with its ROS 2 publishers and subscribers."""

    def __init__(self) -> None:
        settings = dds_settings()
        self.description = settings.description
        domain = domain_id()
        try:
            # The domain is made once per process with the settings' config, and a participant joins it
            # (else Cyclone would make one from ``CYCLONEDDS_URI`` alone).
            if domain not in _DOMAINS:
                _DOMAINS[domain] = Domain(domain, settings.config)
            self.participant = DomainParticipant(domain)
        except Exception as exc:  # the binding raises DDSException with a return code
            raise InputError(f"DDS: cannot join domain {domain} ({exc}); check CYCLONEDDS_URI and ROS_STATIC_PEERS") from None
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
