"""A running ROS 2 camera as a teach source (``hbvs teach --ros2-image TOPIC``), until ``--duration`` or Ctrl-C."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

from ...errors import InputError
from .frame_source import FrameSource, SourceFrame


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
        node = dds.Ros2Node()
        self._images = LatestImage(node, topic)
        self.camera = None
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
        while True:
            frame = self._images.latest(1.0)
            if frame is None:
                continue  # a camera that pauses: wait (Ctrl-C ends the recording)
            self.dropped += frame.skipped
            stamp_ns = int(round(frame.stamp * 1e9))
            if first_ns is None:
                first_ns = self.time_base_ns = stamp_ns
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
        return {"kind": self.kind, "topic": self.topic, "cmd_topic": self.cmd_topic, "dropped_frames": self.dropped}
