"""ROS 2 over DDS without ROS (issue 23): the messages hbvs sends and reads are the ROS 2
messages byte for byte (rosbags' typestore decodes ours field for field, and ours decode
its), with the ROS 2 names; and DDS on loopback carries them between two processes."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("cyclonedds")

from rosbags.typesys import Stores, get_typestore  # noqa: E402

from hbvs_cli.io import ros2_dds as dds  # noqa: E402

TYPESTORE = get_typestore(Stores.ROS2_HUMBLE)


def _samples() -> dict[str, object]:
    rng = np.random.default_rng(23)
    header = dds.Header(stamp=dds.Time(sec=1_700_000_123, nanosec=456_789_012), frame_id="camera_optical")
    return {
        "builtin_interfaces/msg/Time": dds.Time(sec=-3, nanosec=999_999_999),
        "std_msgs/msg/Header": header,
        "geometry_msgs/msg/Vector3": dds.Vector3(x=0.25, y=-1.5, z=3e-9),
        "geometry_msgs/msg/Twist": dds.Twist(linear=dds.Vector3(x=0.31), angular=dds.Vector3(z=-0.42)),
        "geometry_msgs/msg/TwistStamped": dds.TwistStamped(header=header, twist=dds.Twist(linear=dds.Vector3(x=-0.1), angular=dds.Vector3(z=0.6))),
        "geometry_msgs/msg/Point": dds.Point(x=1.0, y=2.0, z=3.0),
        "geometry_msgs/msg/Quaternion": dds.Quaternion(x=0.0, y=0.0, z=0.2588190451, w=0.9659258263),
        "geometry_msgs/msg/Pose": dds.Pose(position=dds.Point(x=-2.0, y=0.5), orientation=dds.Quaternion(z=1.0, w=0.0)),
        "geometry_msgs/msg/PoseStamped": dds.PoseStamped(header=header, pose=dds.Pose(position=dds.Point(x=4.0))),
        "sensor_msgs/msg/Image": dds.Image(
            header=header, height=4, width=5, encoding="bgr8", is_bigendian=0, step=15,
            data=rng.integers(0, 256, 60, dtype=np.uint8).tobytes(),
        ),
        "sensor_msgs/msg/CompressedImage": dds.CompressedImage(header=header, format="jpeg", data=bytes(range(7))),
        "sensor_msgs/msg/RegionOfInterest": dds.RegionOfInterest(x_offset=1, y_offset=2, height=3, width=4, do_rectify=True),
        "sensor_msgs/msg/CameraInfo": dds.CameraInfo(
            header=header, height=480, width=640, distortion_model="plumb_bob", d=[0.1, -0.2, 0.001, 0.002, 0.0],
            k=[500.0, 0.0, 319.5, 0.0, 501.0, 239.5, 0.0, 0.0, 1.0], r=[1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0],
            p=[500.0, 0, 319.5, 0, 0, 501.0, 239.5, 0, 0, 0, 1.0, 0], binning_x=0, binning_y=0,
            roi=dds.RegionOfInterest(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
        ),
    }


def _same(ours: object, theirs: object, where: str) -> None:
    """Field for field: ours (an IDL struct) against rosbags' decoded message."""
    if hasattr(ours, "__dataclass_fields__"):
        for name in ours.__dataclass_fields__:
            _same(getattr(ours, name), getattr(theirs, name), f"{where}.{name}")
    elif isinstance(ours, (bytes, list)):
        np.testing.assert_array_equal(np.asarray(theirs), np.frombuffer(ours, np.uint8) if isinstance(ours, bytes) else np.asarray(ours), err_msg=where)
    else:
        assert ours == theirs, where


@pytest.mark.parametrize("ros_type", sorted(dds.MESSAGE_TYPES))
def test_every_message_round_trips_through_rosbags_cdr(ros_type):
    sample = _samples()[ros_type]
    assert type(sample) is dds.MESSAGE_TYPES[ros_type]
    package, _, name = ros_type.split("/")
    assert type(sample).__idl__.idl_transformed_typename == f"{package}::msg::dds_::{name}_"
    ours = sample.serialize()
    _same(sample, TYPESTORE.deserialize_cdr(ours, ros_type), ros_type)
    theirs = bytes(TYPESTORE.serialize_cdr(TYPESTORE.deserialize_cdr(ours, ros_type), ros_type))
    assert theirs == ours
    assert type(sample).deserialize(theirs) == sample


def test_a_full_size_image_is_bytes_on_both_sides():
    data = bytes(np.arange(640 * 480 * 3, dtype=np.uint64).astype(np.uint8))
    image = dds.Image(height=480, width=640, encoding="bgr8", step=1920, data=data)
    ours = image.serialize()
    assert bytes(TYPESTORE.deserialize_cdr(ours, "sensor_msgs/msg/Image").data) == data
    assert isinstance(dds.Image.deserialize(ours).data, bytes)


def test_names_qos_and_domain(monkeypatch):
    assert dds.dds_topic_name("/cmd_vel") == "rt/cmd_vel"
    assert dds.dds_topic_name("camera/image_raw") == "rt/camera/image_raw"
    assert dds.camera_info_topic("/camera/image_raw") == "/camera/camera_info"
    assert dds.camera_info_topic("/camera/image_raw/compressed") == "/camera/camera_info"
    assert dds.camera_info_topic("/front/left/image_rect") == "/front/left/camera_info"
    monkeypatch.delenv("ROS_DOMAIN_ID", raising=False)
    assert dds.domain_id() == 0
    monkeypatch.setenv("ROS_DOMAIN_ID", "42")
    assert dds.domain_id() == 42
    from hbvs_cli.errors import UsageError

    for bad in ("x", "300"):
        monkeypatch.setenv("ROS_DOMAIN_ID", bad)
        with pytest.raises(UsageError):
            dds.domain_id()
    with pytest.raises(UsageError):
        dds.dds_topic_name("/a//b")
    config = dds.loopback_config()
    assert '<NetworkInterface name="lo"/>' in config and "<AllowMulticast>false</AllowMulticast>" in config
    assert '<Peer address="127.0.0.1"/>' in config


@pytest.mark.parametrize("name, rule", [
    ("/a?b*", "'?*' not allowed"), ("/ünï", "'üï' not allowed"), ("/1abc", "token '1abc' starts with a digit"),
    ("/cam/2d", "token '2d' starts with a digit"), ("~/cmd", "'~'"), ("~", "'~'"), ("//x", "'//'"), ("/x/", "ends with '/'"),
    ("/", "names no topic"), ("", "empty"), ("/{node}/cmd", "substitutions"), ("/a b", "' ' not allowed"),
    ("/" + "a" * 253, "longer than 253"),
])
def test_ros2_topic_names_refused_as_ros_2_does(name, rule):
    from hbvs_cli.errors import UsageError
    from hbvs_cli.io.ros2_names import full_topic_name

    with pytest.raises(UsageError, match="^--ros2-cmd .* is not a ROS 2 topic name: ") as caught:
        full_topic_name(name, "--ros2-cmd")
    assert rule in str(caught.value)


@pytest.mark.parametrize("name, full", [
    ("/cmd_vel", "/cmd_vel"), ("cmd_vel", "/cmd_vel"), ("/_private/x9", "/_private/x9"), ("/a/B_2/c", "/a/B_2/c"), ("/" + "a" * 252, "/" + "a" * 252),
])
def test_ros2_topic_names_accepted(name, full):
    from hbvs_cli.io.ros2_names import full_topic_name

    assert full_topic_name(name) == full
    assert dds.dds_topic_name(name) == "rt" + full


LO_ONLY = '<Interfaces><NetworkInterface name="lo"/></Interfaces>'
NO_MULTICAST = "<AllowMulticast>false</AllowMulticast>"
IGNORE_FAST_DDS_TYPES = "<IgnoreTypeInformation>1.15</IgnoreTypeInformation>"


@pytest.mark.parametrize("environ, inside, outside, description", [
    ({}, [IGNORE_FAST_DDS_TYPES], [LO_ONLY, NO_MULTICAST, "<Peer"],
     "DDS: the interface Cyclone DDS picks, discovery subnet (multicast) (nothing set: ROS 2's default)"),
    ({"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}, [LO_ONLY, NO_MULTICAST, '<Peer address="127.0.0.1"/>', IGNORE_FAST_DDS_TYPES], [],
     "DDS: interface lo, discovery localhost, no multicast (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST)"),
    ({"ROS_AUTOMATIC_DISCOVERY_RANGE": "localhost"}, [LO_ONLY], [],
     "DDS: interface lo, discovery localhost, no multicast (ROS_AUTOMATIC_DISCOVERY_RANGE=localhost)"),
    ({"ROS_LOCALHOST_ONLY": "1"}, [LO_ONLY, NO_MULTICAST], [], "DDS: interface lo, discovery localhost, no multicast (ROS_LOCALHOST_ONLY=1)"),
    ({"ROS_LOCALHOST_ONLY": "0"}, [], [LO_ONLY], "DDS: the interface Cyclone DDS picks, discovery subnet (multicast) (nothing set: ROS 2's default)"),
    # The range wins over the deprecated variable, as in ROS 2 Jazzy.
    ({"ROS_LOCALHOST_ONLY": "1", "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"}, [], [LO_ONLY, NO_MULTICAST],
     "DDS: the interface Cyclone DDS picks, discovery subnet (multicast) (ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET)"),
    ({"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET", "ROS_STATIC_PEERS": "192.168.1.20; robot.local;"},
     ['<Peer address="192.168.1.20"/><Peer address="robot.local"/>', "<ParticipantIndex>auto</ParticipantIndex>"], [LO_ONLY, NO_MULTICAST, "127.0.0.1"],
     "DDS: the interface Cyclone DDS picks, discovery subnet (multicast), static peers 192.168.1.20, robot.local (ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET)"),
    ({"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "ROS_STATIC_PEERS": "10.0.0.7"},
     [NO_MULTICAST, '<Peer address="127.0.0.1"/><Peer address="10.0.0.7"/>'], [LO_ONLY],
     "DDS: the interface Cyclone DDS picks, discovery localhost, static peers 10.0.0.7, no multicast (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST)"),
    ({"ROS_AUTOMATIC_DISCOVERY_RANGE": "SYSTEM_DEFAULT", "ROS_LOCALHOST_ONLY": "1"}, [IGNORE_FAST_DDS_TYPES], [LO_ONLY, "<Peer", "<General>"],
     "DDS: Cyclone DDS's defaults (multicast on the interface it picks) (ROS_AUTOMATIC_DISCOVERY_RANGE=SYSTEM_DEFAULT)"),
    ({"ROS_AUTOMATIC_DISCOVERY_RANGE": "NEARBY"}, [LO_ONLY, NO_MULTICAST], [],
     "DDS: interface lo, discovery localhost, no multicast (ROS_AUTOMATIC_DISCOVERY_RANGE='NEARBY' is not one of OFF, LOCALHOST, SUBNET, SYSTEM_DEFAULT: localhost, as ROS 2)"),
    # CYCLONEDDS_URI is the user's whole network configuration: it comes last, so it wins.
    ({"CYCLONEDDS_URI": "file:///etc/robot/cyclone.xml", "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}, [IGNORE_FAST_DDS_TYPES], [LO_ONLY],
     "DDS: the network of CYCLONEDDS_URI (ROS 2's discovery variables not used)"),
])
def test_ros_2_discovery_variables_become_the_cyclone_configuration(environ, inside, outside, description):
    from hbvs_cli.io.dds_discovery import dds_settings

    settings = dds_settings(environ)
    for text in inside:
        assert text in settings.config, (text, settings.config)
    for text in outside:
        assert text not in settings.config, (text, settings.config)
    assert settings.description == description
    if "CYCLONEDDS_URI" in environ:
        assert settings.config.endswith("," + environ["CYCLONEDDS_URI"])


def test_discovery_off_is_a_usage_error():
    from hbvs_cli.errors import UsageError
    from hbvs_cli.io.dds_discovery import dds_settings

    with pytest.raises(UsageError, match="ROS_AUTOMATIC_DISCOVERY_RANGE=OFF"):
        dds_settings({"ROS_AUTOMATIC_DISCOVERY_RANGE": "off", "ROS_STATIC_PEERS": "127.0.0.1"})


def test_every_loopback_configuration_is_one_cyclone_accepts(tmp_path):
    """Each configuration joins a domain in a fresh process (a domain is made once per process). Only
    those whose traffic stays on loopback: SUBNET and SYSTEM_DEFAULT would multicast on the machine's
    network (their XML is the same elements, minus the interface)."""
    environs = [{"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "ROS_STATIC_PEERS": "127.0.0.2"}, {"ROS_LOCALHOST_ONLY": "1"},
                {"CYCLONEDDS_URI": dds.loopback_config()}]
    script = "from hbvs_cli.io import ros2_dds as dds; node = dds.Ros2Node(); print(node.description)"
    for extra in environs:
        env = {k: v for k, v in os.environ.items() if not k.startswith(("ROS_", "CYCLONEDDS"))}
        env.update(extra, ROS_DOMAIN_ID=str(201 + os.getpid() % 10))
        result = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=60)
        assert result.returncode == 0 and result.stdout.startswith("DDS: "), (extra, result.stderr)


def test_two_processes_talk_over_loopback(tmp_path):
    """A command published by one process arrives in another, on lo only."""
    env = dict(os.environ, CYCLONEDDS_URI=dds.loopback_config(), ROS_DOMAIN_ID=str(221 + os.getpid() % 10))
    listener = subprocess.Popen([sys.executable, "-c", textwrap.dedent("""
        import time
        from hbvs_cli.io import ros2_dds as dds
        node = dds.Ros2Node()
        reader = node.subscriber("/hbvs_test/talk", dds.Twist, dds.command_qos())
        got, deadline = [], time.monotonic() + 20
        while len(got) < 5 and time.monotonic() < deadline:
            got += [s.linear.x for s in reader.take(N=10) if hasattr(s, "linear")]
            time.sleep(0.01)
        print(sorted(set(got))[:5])
    """)], stdout=subprocess.PIPE, text=True, env=env)
    talker = subprocess.run([sys.executable, "-c", textwrap.dedent("""
        import time
        from hbvs_cli.io import ros2_dds as dds
        node = dds.Ros2Node()
        writer = node.publisher("/hbvs_test/talk", dds.Twist, dds.command_qos())
        deadline = time.monotonic() + 20
        while writer.get_publication_matched_status().current_count == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
        for k in range(5):
            writer.write(dds.Twist(linear=dds.Vector3(x=0.1 * k)))
        time.sleep(0.5)
    """)], env=env, timeout=60)
    out, _ = listener.communicate(timeout=60)
    assert talker.returncode == 0
    assert out.strip() == "[0.0, 0.1, 0.2, 0.30000000000000004, 0.4]"


INVALID_NAMES = ["/a?b*", "/ünï", "/1abc", "~/cmd", "//x", "/x/"]


@pytest.mark.parametrize("name", INVALID_NAMES)
@pytest.mark.parametrize("command, option", [
    (["repeat", "FIT", "--live", "--ros2-image", "/camera/image_raw", "--ros2-cmd", "NAME"], "--ros2-cmd"),
    (["repeat", "FIT", "--live", "--ros2-image", "NAME"], "--ros2-image"),
    (["robot-sim", "FIT", "--ros2", "--image-topic", "NAME", "--duration", "1"], "--image-topic"),
    (["robot-sim", "FIT", "--ros2", "--cmd-topic", "NAME", "--duration", "1"], "--cmd-topic"),
    (["teach", "--ros2-image", "NAME"], "--ros2-image"),
    (["teach", "--ros2-image", "/camera/image_raw", "--ros2-cmd", "NAME"], "--ros2-cmd"),
])
def test_invalid_ros2_names_are_one_line_usage_errors(tmp_path, monkeypatch, command, option, name):
    """Exit 2, one line naming the option, nothing written; DDS (if joined at all) on loopback."""
    from conftest import call_hbvs

    monkeypatch.delenv("CYCLONEDDS_URI", raising=False)
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    monkeypatch.setenv("ROS_DOMAIN_ID", str(211 + os.getpid() % 10))
    fit = str(Path(__file__).resolve().parents[1] / "samples" / "fit.mcap")
    output = tmp_path / "out.mcap"
    arguments = [fit if a == "FIT" else name if a == "NAME" else a for a in command]
    result = call_hbvs(*arguments, *(["--poses-out", str(output)] if command[0] == "robot-sim" else ["-o", str(output)]))
    lines = result.stderr.decode().strip().splitlines()
    assert result.returncode == 2 and len(lines) == 1, lines
    assert lines[0].startswith(f"hbvs: error: {option} {name!r} is not a ROS 2 topic name"), lines
    assert not output.exists()
