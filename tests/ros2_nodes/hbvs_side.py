"""hbvs's side of tests/test_ros2_real.py, run by hbvs's Python: the same DDS endpoints as
``repeat --live`` (LatestImage, CommandPublisher) and ``robot-sim --ros2`` (a camera with
``camera_qos``), counting what crosses.

    python hbvs_side.py images   --topic T --seconds S    (LatestImage: frames taken, newest or skipped)
    python hbvs_side.py camera   --topic T --count N --rate HZ
    python hbvs_side.py commands --topic T --count N --rate HZ

Prints ``{"ready": ...}`` with the DDS line once the node is up, then one JSON line of counts.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from hbvs_cli.io import ros2_dds as dds
from hbvs_cli.io.ros2_live import CommandPublisher, LatestImage

WIDTH, HEIGHT = 640, 480
MATCH_TIMEOUT_S = 30.0
#: The listener ends this long (s) after its last frame.
IDLE_S = 1.0


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


def wait_matched(writer) -> None:
    deadline = time.monotonic() + MATCH_TIMEOUT_S
    while writer.get_publication_matched_status().current_count == 0 and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(0.5)  # the reader's side of the match settles too


def images(node, options) -> None:
    """Every sample LatestImage takes (the newest decoded, the others counted as skipped)."""
    source = LatestImage(node, options.topic, MATCH_TIMEOUT_S)
    taken, stamps = 0, []
    deadline = time.monotonic() + options.seconds
    last = time.monotonic()
    while time.monotonic() < deadline and not (taken and time.monotonic() - last > IDLE_S):
        frame = source.latest(0.1)
        if frame is not None:
            taken += 1 + frame.skipped
            stamps.append(frame.stamp)
            shape = list(frame.image.shape)
            last = time.monotonic()
    emit(received=taken, decoded=len(stamps), first_stamp=stamps[0] if stamps else None, shape=shape if taken else None)


def camera(node, options) -> None:
    """640x480 bgr8 frames as robot-sim sends them (its QoS), at ``--rate``."""
    writer = node.publisher(options.topic, dds.Image, dds.camera_qos())
    pixels = bytearray(np.arange(WIDTH * HEIGHT * 3, dtype=np.uint8).tobytes())
    wait_matched(writer)
    start = time.monotonic()
    sent_stamps = []
    for number in range(options.count):
        time.sleep(max(0.0, start + number / options.rate - time.monotonic()))
        pixels[0] = number % 256
        stamp = dds.stamp_of(time.time())
        sent_stamps.append(dds.seconds_of(stamp))
        writer.write(dds.Image(header=dds.Header(stamp=stamp, frame_id="camera_optical"), height=HEIGHT,
                               width=WIDTH, encoding="bgr8", step=WIDTH * 3, data=bytes(pixels)))
    emit(sent=options.count, seconds=time.monotonic() - start, stamps=sent_stamps)
    time.sleep(0.5)  # reliable repairs of the last frames


def commands(node, options) -> None:
    """``--count`` Twists (v = 0.001 k m/s, w = -0.002 k rad/s) at ``--rate``, as repeat --live sends them."""
    publisher = CommandPublisher(node, options.topic)
    wait_matched(publisher.writer)
    start = time.monotonic()
    for number in range(options.count):
        time.sleep(max(0.0, start + number / options.rate - time.monotonic()))
        publisher.publish(0.001 * number, -0.002 * number)
    emit(sent=options.count, seconds=time.monotonic() - start)
    time.sleep(0.5)  # reliable repairs of the last commands


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("role", choices=("images", "camera", "commands"))
    parser.add_argument("--topic", required=True)
    parser.add_argument("--count", type=int, default=90)
    parser.add_argument("--rate", type=float, default=30.0)
    parser.add_argument("--seconds", type=float, default=10.0)
    options = parser.parse_args()
    node = dds.Ros2Node()
    emit(ready=True, dds=node.description)
    {"images": images, "camera": camera, "commands": commands}[options.role](node, options)


if __name__ == "__main__":
    main()
