"""A running ROS 2 camera as a teach source (``hbvs teach --ros2-image TOPIC``), until ``--duration`` or Ctrl-C."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from typing import Any

from ...core.camera_clock import CameraClock
from ...errors import CameraClockError, InputError
from .frame_source import FrameSource, SourceFrame


#: The frame period (s) the stamps' tolerance assumes (a camera's rate is not known before it runs).
NOMINAL_PERIOD_S = 1.0 / 30.0


class Ros2TopicSource(FrameSource):
    """Frames of ``topic`` (``Image``, or ``CompressedImage`` on ``.../compressed``), stamped by their header,
    with the intrinsics from the sibling ``camera_info`` topic and the operator's ``Twist`` on ``cmd_topic``."""

    kind = "ros2"

    def __init__(self, topic: str, cmd_topic: str | None = None, duration: float | None = None) -> None:
        from .. import ros2_dds as dds
        from ..ros2_live import LatestImage, wait_camera_info

        self.topic = topic
        self.cmd_topic = cmd_topic
        self.duration = duration
        self.dropped = 0
        #: Frames left out for their stamps (not newer than the last, or jumped ahead of this host's clock).
        self.bad_stamps = 0
        node = dds.Ros2Node()
        self._images = LatestImage(node, topic)
        self.camera_problem: str | None = None
        try:
            self.camera = wait_camera_info(node, dds.camera_info_topic(topic))
        except InputError as exc:
            self.camera_problem = str(exc)
        self._commands = node.subscriber(cmd_topic, dds.Twist, dds.command_qos()) if cmd_topic else None
        self._command: tuple[float, float] | None = None
        self.time_base_ns = 0

    def __iter__(self) -> Iterator[SourceFrame]:
        first_ns: int | None = None
        # --duration is this host's time from the first frame, whatever the camera's stamps do; a frame
        # whose stamp is not newer, or jumped, is left out (counted in bad_stamps).
        clock = CameraClock(NOMINAL_PERIOD_S)
        ends_at = math.inf
        while time.monotonic() < ends_at:
            frame = self._images.latest(min(1.0, max(ends_at - time.monotonic(), 0.0)))
            if frame is None:
                continue  # a camera that pauses: wait (Ctrl-C ends the recording)
            self.dropped += frame.skipped
            try:
                usable = clock.admit(frame.stamp, frame.arrival)
            except CameraClockError:
                usable = False
            if not usable:
                self.bad_stamps += 1
                continue
            stamp_ns = int(round(frame.stamp * 1e9))
            if first_ns is None:
                first_ns = self.time_base_ns = stamp_ns
                ends_at = frame.arrival + self.duration if self.duration is not None else math.inf
            t = (stamp_ns - first_ns) * 1e-9
            if self.duration is not None and t >= self.duration - 1e-9:
                return
            yield SourceFrame(t=t, image=frame.image, stamp_ns=stamp_ns, command=self._latest_command())

    def _latest_command(self) -> tuple[float, float] | None:
        if self._commands is None:
            return None
        for sample in self._commands.take(N=64):
            if hasattr(sample, "linear"):
                self._command = (float(sample.linear.x), float(sample.angular.z))
        return self._command if self._command is not None else (0.0, 0.0)  # at rest until the operator drives

    def describe(self) -> dict[str, Any]:
        return {"kind": self.kind, "topic": self.topic, "cmd_topic": self.cmd_topic, "dropped_frames": self.dropped,
                "bad_stamps": self.bad_stamps}
