"""``hbvs robot-sim FIT --ros2``: a stand-in robot in its own process.

It is what ``repeat --sim`` simulates, split off as a robot on the network: it starts at
the taught start plus ``--offset`` in the fit's taught world (:func:`hbvs_cli.sim.simulation_world`),
integrates the unicycle in real time under the latest velocity command it received
(``/cmd_vel``), renders the camera with the same renderer as ``repeat --sim`` at ``--rate``
and publishes it as a ROS 2 camera does: ``sensor_msgs/msg/Image`` (or a JPEG
``CompressedImage``) with sensor-data QoS, ``CameraInfo`` on the sibling ``camera_info``
topic, and its true pose as ``geometry_msgs/msg/PoseStamped`` on ``/ground_truth/pose``.
Stamps are the wall clock (as ROS 2 drivers stamp). Users try ``repeat --live`` against it
before a robot; the tests run the live loop across processes with it.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass

import numpy as np

from ..core.desired import taught_frame_interval
from ..core.frames import compose_planar_pose
from ..core.unicycle import integrate_unicycle
from ..errors import UsageError
from ..io.fit_file import read_fit_file
from ..io.images import encode_image
from ..io.output_target import open_text_output
from ..io.topics import ROS_TRUE_POSE_TOPIC
from ..sim.scene import renderer_for, simulation_world
from .console import Console
from .options import parse_interval, parse_offset
from .settings import RobotSimOptions


@dataclass
class RobotSimSummary:
    frames: int
    commands: int
    final_pose: tuple[float, float, float]


def run_robot_sim(options: RobotSimOptions, console: Console) -> RobotSimSummary:
    """Run the stand-in robot until ``--duration`` or a stop signal."""
    if not options.ros2:
        raise UsageError("robot-sim needs a transport: --ros2 (ROS 2 topics over DDS)")
    if options.image_format not in ("raw", "jpeg"):
        raise UsageError(f"--image-format must be raw or jpeg, got {options.image_format!r}")
    if options.cmd_type not in ("twist", "twist-stamped"):
        raise UsageError(f"--cmd-type must be twist or twist-stamped, got {options.cmd_type!r}")
    from ..io import ros2_dds as dds  # lazy: an optional extra

    fit = read_fit_file(options.input)
    model = fit.model
    taught = taught_frame_interval(model.taught_path.t if model.taught_path is not None else None, model.frames.get("frame_interval_s"))
    rate = float(options.rate) if options.rate is not None else 1.0 / taught
    scene = simulation_world(model, fit.reference_image, options.depth)
    renderer = renderer_for(scene, model)
    rng = np.random.default_rng(options.seed)
    pose = tuple(float(v) for v in compose_planar_pose(scene.taught_pose_at_run_time(0.0), parse_offset(options.offset)))
    camera = model.camera
    info = dds.CameraInfo(
        header=dds.Header(frame_id="camera_optical"), height=camera.height, width=camera.width,
        distortion_model="plumb_bob", d=[0.0] * 5,
        k=[camera.fx, 0.0, camera.cx, 0.0, camera.fy, camera.cy, 0.0, 0.0, 1.0],
        r=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p=[camera.fx, 0.0, camera.cx, 0.0, 0.0, camera.fy, camera.cy, 0.0, 0.0, 0.0, 1.0, 0.0],
    )
    if camera.distortion_model != "none" and any(camera.distortion):
        raise UsageError("robot-sim renders an undistorted camera; this fit's camera has lens distortion")
    node = dds.Ros2Node()
    image_topic = options.image_topic + ("/compressed" if options.image_format == "jpeg" else "")
    image_type = dds.CompressedImage if options.image_format == "jpeg" else dds.Image
    image_writer = node.publisher(image_topic, image_type, dds.sensor_qos())
    info_writer = node.publisher(dds.camera_info_topic(image_topic), dds.CameraInfo, dds.sensor_qos())
    pose_writer = node.publisher(ROS_TRUE_POSE_TOPIC, dds.PoseStamped, dds.command_qos())
    stamped = options.cmd_type == "twist-stamped"
    commands = node.subscriber(options.cmd_topic, dds.TwistStamped if stamped else dds.Twist, dds.command_qos())
    console.info(
        f"robot-sim: {camera.width}x{camera.height} at {rate:g} Hz on {image_topic}, commands from {options.cmd_topic} "
        f"(ROS_DOMAIN_ID {dds.domain_id()})"
    )
    occlusions = [parse_interval(text, "--occlude") for text in options.occlude]
    frames = received = 0
    interrupted = False
    command = (0.0, 0.0)
    period = 1.0 / rate
    with open_text_output(options.poses_out, "pose stream") as poses_out:
        start = last = time.monotonic()
        try:
            while options.duration is None or last - start < options.duration:
                next_frame = start + frames * period
                # Until the next frame is due: apply each command from the moment it arrives.
                while True:
                    now = time.monotonic()
                    for sample in commands.take(N=32):
                        if not hasattr(sample, "linear") and not hasattr(sample, "twist"):
                            continue  # a publisher going away
                        twist = sample.twist if stamped else sample
                        pose = integrate_unicycle(pose, command[0], command[1], now - last)
                        last = now
                        command = (float(twist.linear.x), float(twist.angular.z))
                        received += 1
                    if now >= next_frame:
                        break
                    time.sleep(min(0.002, next_frame - now))
                now = time.monotonic()
                pose = integrate_unicycle(pose, command[0], command[1], now - last)
                last = now
                stamp = dds.stamp_of(time.time())
                header = dds.Header(stamp=stamp, frame_id="camera_optical")
                image = renderer.render(np.array(pose), rng)
                occluded = any(begin <= now - start < end for begin, end in occlusions)
                if occluded:
                    image[...] = int(np.mean(image))  # nothing to see: the target is covered
                if options.image_format == "jpeg":
                    image_writer.write(dds.CompressedImage(header=header, format="jpeg", data=encode_image(image, "jpeg")))
                else:
                    colour = image.ndim == 3
                    image_writer.write(dds.Image(
                        header=header, height=image.shape[0], width=image.shape[1], encoding="bgr8" if colour else "mono8",
                        step=image.shape[1] * (3 if colour else 1), data=np.ascontiguousarray(image).tobytes(),
                    ))
                info.header = header
                info_writer.write(info)
                x, y, phi = pose
                pose_writer.write(dds.PoseStamped(
                    header=dds.Header(stamp=stamp, frame_id="world"),
                    pose=dds.Pose(position=dds.Point(x=x, y=y), orientation=dds.Quaternion(z=math.sin(phi / 2), w=math.cos(phi / 2))),
                ))
                if poses_out is not None:
                    poses_out.write(json.dumps({"stamp": dds.seconds_of(stamp), "x": x, "y": y, "phi": phi,
                                                "v": command[0], "w": command[1], "occluded": occluded}) + "\n")
                    poses_out.flush()
                frames += 1
        except KeyboardInterrupt:
            interrupted = True  # Ctrl-C is how a stand-in ends: keep its poses
    console.info(f"robot-sim: {frames} frames, {received} commands{' (stopped by Ctrl-C)' if interrupted else ''}; final pose x {pose[0]:.3f} m, y {pose[1]:.3f} m, "
                 f"phi {math.degrees(pose[2]):.2f} deg")
    return RobotSimSummary(frames=frames, commands=received, final_pose=pose)
