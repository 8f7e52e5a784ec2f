"""ROS 2 over DDS without ROS (issue 23): the messages hbvs sends and reads are the ROS 2
messages byte for byte (rosbags' typestore decodes ours field for field, and ours decode
its), with the ROS 2 names; and DDS on loopback carries them between two processes."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

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
