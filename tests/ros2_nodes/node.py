"""Real ROS 2 nodes (rclpy, the release's default middleware rmw_fastrtps_cpp) for
tests/test_ros2_real.py, run by a ROS 2 release's own Python (a venv with the ros-<release>-*
wheels, where hbvs is not importable):

    python node.py camera  --topic T --format raw|jpeg [--jpeg-file F] --qos sensor|default --rate HZ --count N
    python node.py images  --topic T --qos sensor|default --seconds S     (counts Image/CompressedImage)
    python node.py twists  --topic T --seconds S                          (counts Twist, default QoS)
    python node.py relay   --topic T --seconds S [--stop-file F]  (T and its camera_info -> /robot/...; /robot/cmd_vel -> /cmd_vel)

Each prints ``{"ready": ...}`` once its node is up, then one last JSON line with what it sent or
received; stdout only. A camera waits for a subscriber before its first frame (what a late
joiner sees is the test's start order, not frames sent to nobody).
"""

from __future__ import annotations

import argparse
import array
import json
import os
import time

import rclpy
from geometry_msgs.msg import Twist
from rclpy.qos import QoSProfile, qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, CompressedImage, Image

WIDTH, HEIGHT = 640, 480
#: Seconds a camera waits for its first subscriber.
MATCH_TIMEOUT_S = 30.0
#: A listener ends this long (s) after its last message.
IDLE_S = 1.0


def qos(name: str) -> QoSProfile:
    """ROS 2's sensor-data profile (best effort, keep last 5) or its default (reliable, keep last 10)."""
    return qos_profile_sensor_data if name == "sensor" else QoSProfile(depth=10)


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


def camera(node, options) -> None:
    """``--count`` frames at ``--rate``: bgr8 640x480 (the first byte the frame's number mod 256) or the
    JPEG of ``--jpeg-file``, each stamped now, with a CameraInfo on the sibling topic."""
    compressed = options.format == "jpeg"
    publisher = node.create_publisher(CompressedImage if compressed else Image, options.topic, qos(options.qos))
    info_topic = options.topic.rsplit("/", 2 if compressed else 1)[0] + "/camera_info"
    info_publisher = node.create_publisher(CameraInfo, info_topic, qos(options.qos))
    pixels = bytearray(bytes(range(256)) * (WIDTH * HEIGHT * 3 // 256))
    if compressed:
        with open(options.jpeg_file, "rb") as stream:
            jpeg = array.array("B", stream.read())
    emit(ready=True)
    deadline = time.monotonic() + MATCH_TIMEOUT_S
    while publisher.get_subscription_count() == 0 and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.02)
    time.sleep(0.5)  # the subscriber's side of the match settles too
    period = 1.0 / options.rate
    start = time.monotonic()
    sent_stamps = []
    for number in range(options.count):
        time.sleep(max(0.0, start + number * period - time.monotonic()))
        stamp = node.get_clock().now().to_msg()
        sent_stamps.append(stamp.sec + stamp.nanosec * 1e-9)
        if compressed:
            message = CompressedImage(format="jpeg", data=jpeg)
        else:
            pixels[0] = number % 256
            message = Image(height=HEIGHT, width=WIDTH, encoding="bgr8", step=WIDTH * 3, data=array.array("B", pixels))
        message.header.stamp = stamp
        message.header.frame_id = "camera_optical"
        publisher.publish(message)
        info = CameraInfo(height=HEIGHT, width=WIDTH, distortion_model="plumb_bob", d=[0.0] * 5,
                          k=[500.0, 0.0, 319.5, 0.0, 500.0, 239.5, 0.0, 0.0, 1.0])
        info.header.stamp = stamp
        info_publisher.publish(info)
    emit(sent=options.count, seconds=time.monotonic() - start, stamps=sent_stamps)
    time.sleep(0.5)  # reliable repairs of the last frames


def images(node, options) -> None:
    """Frames on ``--topic`` (CompressedImage if it ends in /compressed) for ``--seconds``."""
    kind = CompressedImage if options.topic.endswith("/compressed") else Image
    stamps = []
    node.create_subscription(kind, options.topic, lambda message: stamps.append(
        (message.header.stamp.sec, message.header.stamp.nanosec, len(message.data))), qos(options.qos))
    _spin(node, options.seconds, stamps)
    seconds = sorted({sec + nanosec * 1e-9 for sec, nanosec, _ in stamps})
    emit(received=len(stamps), distinct=len(seconds), first_stamp=seconds[0] if seconds else None,
         sizes=sorted({size for _, _, size in stamps}))


def twists(node, options) -> None:
    """Every Twist on ``--topic`` (ROS 2's default QoS) for ``--seconds``."""
    received = []
    node.create_subscription(Twist, options.topic, lambda message: received.append((message.linear.x, message.angular.z)), qos("default"))
    _spin(node, options.seconds, received)
    emit(received=len(received), v=[v for v, _ in received], w=[w for _, w in received])


def teleop(node, options) -> None:
    """A teleop left running: a Twist (0.05 m/s) on ``--topic`` at ``--rate`` with ROS 2's default QoS,
    for ``--seconds``."""
    publisher = node.create_publisher(Twist, options.topic, qos("default"))
    emit(ready=True)
    message = Twist()
    message.linear.x = 0.05
    sent = 0
    deadline = time.monotonic() + options.seconds
    while time.monotonic() < deadline:
        publisher.publish(message)
        sent += 1
        rclpy.spin_once(node, timeout_sec=1.0 / options.rate)
    emit(sent=sent)


def relay(node, options) -> None:
    """A ROS 2 node between hbvs's robot and hbvs's controller: ``--topic``'s Image (and its
    camera_info) republished under /robot, and /robot/cmd_vel's Twists republished on /cmd_vel,
    each with ROS 2's default QoS, for ``--seconds`` or until ``--stop-file`` exists (rclpy takes
    Ctrl-C and SIGTERM for itself)."""
    image_out = node.create_publisher(Image, "/robot" + options.topic, qos("default"))
    info_topic = options.topic.rsplit("/", 1)[0] + "/camera_info"
    info_out = node.create_publisher(CameraInfo, "/robot" + info_topic, qos("default"))
    twist_out = node.create_publisher(Twist, "/cmd_vel", qos("default"))
    counts = {"images": 0, "infos": 0, "twists": 0}

    def forward(publisher, key):
        def callback(message):
            publisher.publish(message)
            counts[key] += 1
        return callback

    node.create_subscription(Image, options.topic, forward(image_out, "images"), qos("default"))
    node.create_subscription(CameraInfo, info_topic, forward(info_out, "infos"), qos("default"))
    node.create_subscription(Twist, "/robot/cmd_vel", forward(twist_out, "twists"), qos("default"))
    emit(ready=True)
    deadline = time.monotonic() + options.seconds
    while time.monotonic() < deadline and not (options.stop_file and os.path.exists(options.stop_file)):
        rclpy.spin_once(node, timeout_sec=0.05)
    emit(**counts)


def _spin(node, seconds: float, received: list) -> None:
    """Until ``seconds`` pass, or :data:`IDLE_S` without a message once some came."""
    emit(ready=True)
    deadline = time.monotonic() + seconds
    last, count = time.monotonic(), 0
    while time.monotonic() < deadline and not (received and time.monotonic() - last > IDLE_S):
        rclpy.spin_once(node, timeout_sec=0.05)
        if len(received) != count:
            last, count = time.monotonic(), len(received)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("role", choices=("camera", "images", "twists", "teleop", "relay"))
    parser.add_argument("--topic", required=True)
    parser.add_argument("--qos", choices=("sensor", "default"), default="default")
    parser.add_argument("--format", choices=("raw", "jpeg"), default="raw")
    parser.add_argument("--jpeg-file", help="with --format jpeg: the JPEG sent as every frame (made by the test)")
    parser.add_argument("--rate", type=float, default=30.0)
    parser.add_argument("--count", type=int, default=90)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--stop-file", help="relay: end once this file exists")
    options = parser.parse_args()
    rclpy.init()
    node = rclpy.create_node(f"hbvs_test_{options.role}")
    try:
        {"camera": camera, "images": images, "twists": twists, "teleop": teleop, "relay": relay}[options.role](node, options)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
