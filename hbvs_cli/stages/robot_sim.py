"""``hbvs robot-sim FIT``: what ``repeat --sim`` simulates, as a robot in its own process for ``repeat --live``:
the unicycle in real time under the latest command, rendered at ``--rate``, over ROS 2 or MJPEG and JSON lines."""

from __future__ import annotations

import json
import math
import queue
import sys
import threading
import time
from typing import IO, Any

import numpy as np

from ..core.frames import compose_planar_pose
from ..errors import InputError, UsageError
from ..io.calibration import calibration_to_foxglove
from ..core.fit_model import SensorSettings
from ..io.fit_file import FitFile, read_fit_file
from ..io.images import encode_image
from ..io.output_target import open_text_output
from ..io.ros2_names import check_topic_names
from ..io.route_file import route_of
from ..io.topics import ROS_TRUE_POSE_TOPIC
from ..sim.route_world import make_route_renderer, recorded_route
from ..sim.stand_in import MAX_PLAUSIBLE_V, MAX_PLAUSIBLE_W, StampFault, parse_base, stand_in_world
from .console import Console
from .frame_decoding import fit_reference_image
from .options import parse_interval, parse_offset
from ..settings.commands import RobotSimOptions
from ..stop_signals import raise_if_stopped


class _Ros2Robot:
    """Commands from a ROS 2 Twist topic; camera, CameraInfo and true pose published."""

    def __init__(self, options: RobotSimOptions, camera: Any) -> None:
        from ..io import ros2_dds as dds  # lazy: an optional extra

        self.dds = dds
        self.jpeg = options.image_format == "jpeg"
        calibration = calibration_to_foxglove(camera, "camera_optical", 0)  # K, identity R, [K | 0], no distortion
        self.info = dds.CameraInfo(
            header=dds.Header(frame_id="camera_optical"), height=camera.height, width=camera.width, distortion_model=calibration.distortion_model,
            d=list(calibration.D), k=list(calibration.K), r=list(calibration.R), p=list(calibration.P),
        )
        node = dds.Ros2Node()
        image_topic = options.image_topic + ("/compressed" if self.jpeg else "")
        self.image_writer = node.publisher(image_topic, dds.CompressedImage if self.jpeg else dds.Image, dds.camera_qos())
        self.info_writer = node.publisher(dds.camera_info_topic(image_topic), dds.CameraInfo, dds.camera_qos())
        self.pose_writer = node.publisher(ROS_TRUE_POSE_TOPIC, dds.PoseStamped, dds.command_qos())
        self.stamped = options.cmd_type == "twist-stamped"
        self.commands = node.subscriber(options.cmd_topic, dds.TwistStamped if self.stamped else dds.Twist, dds.command_qos())
        self.description = f"{image_topic}, commands from {options.cmd_topic} (ROS_DOMAIN_ID {dds.domain_id()}); {node.description}"

    def take_commands(self) -> list[tuple[float, float]]:
        received = []
        for sample in self.commands.take(N=32):
            if not hasattr(sample, "linear") and not hasattr(sample, "twist"):
                continue  # a publisher going away
            twist = sample.twist if self.stamped else sample
            received.append((float(twist.linear.x), float(twist.angular.z)))
        return received

    def publish(self, image: np.ndarray, stamp_s: float, pose: tuple[float, float, float]) -> None:
        dds = self.dds
        stamp = dds.stamp_of(stamp_s)
        header = dds.Header(stamp=stamp, frame_id="camera_optical")
        if self.jpeg:
            self.image_writer.write(dds.CompressedImage(header=header, format="jpeg", data=encode_image(image, "jpeg")))
        else:
            colour = image.ndim == 3
            self.image_writer.write(dds.Image(
                header=header, height=image.shape[0], width=image.shape[1], encoding="bgr8" if colour else "mono8",
                step=image.shape[1] * (3 if colour else 1), data=np.ascontiguousarray(image).tobytes(),
            ))
        self.info.header = header
        self.info_writer.write(self.info)
        x, y, phi = pose
        self.pose_writer.write(dds.PoseStamped(
            header=dds.Header(stamp=stamp, frame_id="world"),
            pose=dds.Pose(position=dds.Point(x=x, y=y), orientation=dds.Quaternion(z=math.sin(phi / 2), w=math.cos(phi / 2))),
        ))

    def close(self) -> None:
        pass


class _PlainRobot:
    """Without ROS: the camera as MJPEG over HTTP on 127.0.0.1, commands as JSON lines."""

    def __init__(self, options: RobotSimOptions) -> None:
        from ..io.mjpeg_server import MjpegServer

        self._source = options.cmd_in
        #: The commands read, then the problem that stopped the reader (text), if one did.
        self._received: queue.SimpleQueue[tuple[float, float] | str] = queue.SimpleQueue()
        self._server = MjpegServer(options.mjpeg)
        # Opened by the reader thread: a FIFO's open waits for its writer, who looks at the camera first.
        self._reader = threading.Thread(target=self._read, name="hbvs-cmd-in", daemon=True)
        self._reader.start()
        self.description = f"http://127.0.0.1:{options.mjpeg}/ (MJPEG), commands from {options.cmd_in}"

    def _read(self) -> None:
        try:
            stream: IO[str] = sys.stdin if self._source == "-" else open(self._source, encoding="utf-8")  # noqa: SIM115
        except OSError as exc:
            self._received.put(f"--cmd-in {self._source}: {exc.strerror}")
            return
        for number, line in enumerate(stream, 1):
            if not line.strip():
                continue
            try:
                data = json.loads(line)
                self._received.put((float(data["v"]), float(data["w"])))
            except (ValueError, KeyError, TypeError):
                self._received.put(f"--cmd-in line {number}: not a command (a JSON object with v and w): {line.strip()[:80]!r}")
                return

    def take_commands(self) -> list[tuple[float, float]]:
        received = []
        while not self._received.empty():
            command = self._received.get()
            if isinstance(command, str):
                raise InputError(command)
            received.append(command)
        return received

    def publish(self, image: np.ndarray, stamp_s: float, pose: tuple[float, float, float]) -> None:
        self._server.publish(encode_image(image, "jpeg"))

    def close(self) -> None:
        self._server.close()


def _transport(options: RobotSimOptions, camera: Any) -> Any:
    plain = options.mjpeg is not None or options.cmd_in is not None
    if options.ros2 == plain:
        raise UsageError("robot-sim needs one transport: --ros2 (ROS 2 topics over DDS), or --mjpeg PORT with --cmd-in FILE")
    if plain and (options.mjpeg is None or options.cmd_in is None):
        raise UsageError("--mjpeg PORT and --cmd-in FILE go together (the camera out, the commands in)")
    return _Ros2Robot(options, camera) if options.ros2 else _PlainRobot(options)


def _taught_world(fit: FitFile, options: RobotSimOptions) -> tuple[Any, np.ndarray]:
    """The renderer of the fit's taught world (a route's: all its targets, issue 47) and the taught start pose."""
    if fit.route_record is None:
        return stand_in_world(fit.model, fit_reference_image(fit), options.depth, options.input)[1:]
    plan = route_of(fit, options.input)
    if plan.world is None or plan.taught_poses is None or options.depth is not None:
        raise UsageError(f"{options.input}: robot-sim renders a route from its simulated teach (and takes no --depth); "
                         "this route fit has none")
    sensor = fit.model.render or SensorSettings()
    renderer = make_route_renderer(recorded_route(plan.world, fit.model.camera), sensor.noise, sensor.blur, sensor.exposure,
                                   sensor.noise_grain)
    return renderer, plan.taught_poses[0, 1:]


def run_robot_sim(options: RobotSimOptions, console: Console) -> None:
    """Run the stand-in robot until ``--duration`` or a stop signal."""
    if options.ros2:
        check_topic_names((options.image_topic, "--image-topic"), (options.cmd_topic, "--cmd-topic"))
    fit = read_fit_file(options.input)
    model = fit.model
    rate = float(options.rate) if options.rate is not None else 1.0 / model.taught_frame_interval()
    renderer, taught_start = _taught_world(fit, options)
    rng = np.random.default_rng(options.seed)
    pose = tuple(float(v) for v in compose_planar_pose(taught_start, parse_offset(options.offset)))
    camera = model.camera
    if camera.distortion_model != "none" and any(camera.distortion):
        raise UsageError("robot-sim renders an undistorted camera; this fit's camera has lens distortion")
    occlusions = [parse_interval(text, "--occlude") for text in options.occlude]
    base = parse_base(options.base)
    fault = StampFault(options.stamp_fault) if options.stamp_fault is not None else None
    robot = _transport(options, camera)
    console.info(f"robot-sim: {camera.width}x{camera.height} at {rate:g} Hz on {robot.description}")
    frames = received = ignored = 0
    moving_since: float | None = None
    interrupted = False
    command = (0.0, 0.0)
    period = 1.0 / rate
    try:
        with open_text_output(options.poses_out, "pose stream", keep_on_error=True) as poses_out:
            start = last = time.monotonic()
            try:
                while options.duration is None or last - start < options.duration:
                    raise_if_stopped()
                    next_frame = start + frames * period
                    # Until the next frame is due: apply each command from the moment it arrives.
                    while True:
                        now = time.monotonic()
                        for new in robot.take_commands():
                            received += 1
                            if not (abs(new[0]) <= MAX_PLAUSIBLE_V and abs(new[1]) <= MAX_PLAUSIBLE_W):  # NaN too
                                ignored += 1
                                if ignored == 1:
                                    console.warn(f"robot-sim: ignored a command v {new[0]!r} m/s, w {new[1]!r} rad/s (not finite, "
                                                 f"or beyond {MAX_PLAUSIBLE_V:g} m/s or {MAX_PLAUSIBLE_W:g} rad/s)")
                                continue
                            pose = base.advance(pose, command, now - last)
                            last, command = now, new
                        if now >= next_frame:
                            break
                        time.sleep(min(0.002, next_frame - now))
                    now = time.monotonic()
                    pose = base.advance(pose, command, now - last)
                    last = now
                    stamp = time.time()
                    image = renderer.render(np.array(pose), rng)
                    occluded = any(begin <= now - start < end for begin, end in occlusions)
                    if occluded:
                        image[...] = int(np.mean(image))  # nothing to see: the target is covered
                    if moving_since is None and command != (0.0, 0.0):
                        moving_since = now
                    # The fault strikes T s into the drive (a stand-in cannot know when its driver started).
                    driving = now - moving_since if moving_since is not None else -math.inf
                    sent_stamp = fault.stamp(stamp, driving, frames) if fault is not None else stamp
                    if sent_stamp is not None:
                        robot.publish(image, sent_stamp, pose)
                    if poses_out is not None:
                        x, y, phi = pose
                        poses_out.write(json.dumps({"stamp": stamp, "x": x, "y": y, "phi": phi, "v": command[0], "w": command[1],
                                                    "v_base": base.v, "w_base": base.w, "occluded": occluded,
                                                    "published": sent_stamp is not None}) + "\n")
                        poses_out.flush()
                    frames += 1
            except KeyboardInterrupt:
                interrupted = True  # Ctrl-C is how a stand-in ends: keep its poses
    finally:
        robot.close()
    if ignored > 1:
        console.warn(f"robot-sim: {ignored} commands ignored in all")
    console.info(f"robot-sim: {frames} frames, {received} commands ({ignored} ignored){' (stopped by Ctrl-C)' if interrupted else ''}; "
                 f"final pose x {pose[0]:.3f} m, y {pose[1]:.3f} m, phi {math.degrees(pose[2]):.2f} deg")
