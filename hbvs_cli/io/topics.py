"""The one table of hbvs's topics and schema names, per file kind (teach, fit, run); no other
module spells a topic (``tests/test_repository.py`` checks)."""

from __future__ import annotations

# ----------------------------------------------------------------------------- schema names
COMPRESSED_IMAGE_SCHEMA = "foxglove.CompressedImage"
CAMERA_CALIBRATION_SCHEMA = "foxglove.CameraCalibration"
IMAGE_ANNOTATIONS_SCHEMA = "foxglove.ImageAnnotations"
POSE_IN_FRAME_SCHEMA = "foxglove.PoseInFrame"
LOG_SCHEMA = "foxglove.Log"
VELOCITY_COMMAND_SCHEMA = "hbvs.VelocityCommand"
DESIRED_SIGNAL_SCHEMA = "hbvs.DesiredSignal"
FIT_MODEL_SCHEMA = "hbvs.FitModel"
ROUTE_SCHEMA = "hbvs.Route"
CONTROLLER_STATE_SCHEMA = "hbvs.ControllerState"
LOOP_TIMING_SCHEMA = "hbvs.LoopTiming"

#: MCAP metadata record holding the simulated world of a teach file.
WORLD_METADATA = "hbvs.world"
#: MCAP metadata record of a teach file's calibration's stated uncertainty: ``sigma``, the standard
#: deviations of (fx, fy, cx, cy, *distortion), written just before the calibration it belongs to.
CALIBRATION_METADATA = "hbvs.calibration"
#: MCAP metadata record of a live run that stopped before its end: ``t`` (s) and ``reason``.
STOPPED_METADATA = "hbvs.stopped"
#: MCAP metadata record of a route's repeat, written again at each switch made: ``switch_times``
#: (s), every switch made so far (a live run's and a replay's come when the next target is seen,
#: not at the planned times of the ``route`` metadata).
ROUTE_SWITCHES_METADATA = "hbvs.route_switches"

# ----------------------------------------------------------------------------- topics
#: The camera's images (every file kind that carries images).
IMAGE_TOPIC = "/camera/image"
#: The camera's intrinsics, once per file.
CALIBRATION_TOPIC = "/camera/calibration"
#: Detected and desired target points drawn over the images.
ANNOTATIONS_TOPIC = "/camera/annotations"
#: The operator's commands during teach.
TEACH_COMMAND_TOPIC = "/teach/cmd_vel"
#: The simulator's true pose of the robot.
TRUE_POSE_TOPIC = "/ground_truth/pose"
#: The fitted model (calibration, d*, n*, splines' knots), once per fit file.
MODEL_TOPIC = "/fit/model"
#: A route fit's segments and the transitions between them (after one model per segment).
ROUTE_TOPIC = "/fit/route"
#: The desired trajectory before and after smoothing.
RAW_DESIRED_TOPIC = "/desired/raw"
SMOOTH_DESIRED_TOPIC = "/desired/smooth"
#: The reference image F* and the detector's template.
REFERENCE_IMAGE_TOPIC = "/reference/image"
TEMPLATE_IMAGE_TOPIC = "/detector/template"
#: The controller's state, commands and events during repeat.
STATE_TOPIC = "/repeat/state"
COMMAND_TOPIC = "/repeat/cmd_vel"
EVENTS_TOPIC = "/repeat/events"
#: The taught pose the robot should be at (simulated runs).
DESIRED_POSE_TOPIC = "/desired/pose"
#: Per step of a live run (``repeat --live``): the frame's stamp, the latency from its
#: arrival to the command's publication, the frame interval, frames dropped since the last
#: step (``hbvs.LoopTiming``). Not in simulated or replayed runs.
TIMING_TOPIC = "/repeat/timing"

# ----------------------------------------------------------------------------- Foxglove 3D scene
FRAME_TRANSFORM_SCHEMA = "foxglove.FrameTransform"
SCENE_UPDATE_SCHEMA = "foxglove.SceneUpdate"
#: world -> base_link (the robot, every pose) and base_link -> camera_optical (once).
TRANSFORM_TOPIC = "/tf"
#: The target and the taught path drawn in Foxglove's 3D panel.
SCENE_TOPIC = "/scene"

#: Topics of each file kind: topic -> schema name.
TOPICS: dict[str, dict[str, str]] = {
    "teach": {
        IMAGE_TOPIC: COMPRESSED_IMAGE_SCHEMA,
        CALIBRATION_TOPIC: CAMERA_CALIBRATION_SCHEMA,
        TEACH_COMMAND_TOPIC: VELOCITY_COMMAND_SCHEMA,
        TRUE_POSE_TOPIC: POSE_IN_FRAME_SCHEMA,
        TRANSFORM_TOPIC: FRAME_TRANSFORM_SCHEMA,
        SCENE_TOPIC: SCENE_UPDATE_SCHEMA,
    },
    "fit": {
        MODEL_TOPIC: FIT_MODEL_SCHEMA,
        ROUTE_TOPIC: ROUTE_SCHEMA,
        RAW_DESIRED_TOPIC: DESIRED_SIGNAL_SCHEMA,
        SMOOTH_DESIRED_TOPIC: DESIRED_SIGNAL_SCHEMA,
        IMAGE_TOPIC: COMPRESSED_IMAGE_SCHEMA,
        ANNOTATIONS_TOPIC: IMAGE_ANNOTATIONS_SCHEMA,
        CALIBRATION_TOPIC: CAMERA_CALIBRATION_SCHEMA,
        REFERENCE_IMAGE_TOPIC: COMPRESSED_IMAGE_SCHEMA,
        TEMPLATE_IMAGE_TOPIC: COMPRESSED_IMAGE_SCHEMA,
        TRANSFORM_TOPIC: FRAME_TRANSFORM_SCHEMA,
        SCENE_TOPIC: SCENE_UPDATE_SCHEMA,
    },
    "run": {
        STATE_TOPIC: CONTROLLER_STATE_SCHEMA,
        COMMAND_TOPIC: VELOCITY_COMMAND_SCHEMA,
        EVENTS_TOPIC: LOG_SCHEMA,
        TIMING_TOPIC: LOOP_TIMING_SCHEMA,
        TRUE_POSE_TOPIC: POSE_IN_FRAME_SCHEMA,
        DESIRED_POSE_TOPIC: POSE_IN_FRAME_SCHEMA,
        IMAGE_TOPIC: COMPRESSED_IMAGE_SCHEMA,
        ANNOTATIONS_TOPIC: IMAGE_ANNOTATIONS_SCHEMA,
        CALIBRATION_TOPIC: CAMERA_CALIBRATION_SCHEMA,
        TRANSFORM_TOPIC: FRAME_TRANSFORM_SCHEMA,
        SCENE_TOPIC: SCENE_UPDATE_SCHEMA,
    },
}

# The ROS 2 types hbvs reads from bags (``teach --bag``) and writes (``hbvs export``).
ROS_IMAGE_SCHEMA = "sensor_msgs/msg/Image"
ROS_COMPRESSED_IMAGE_SCHEMA = "sensor_msgs/msg/CompressedImage"
ROS_CAMERA_INFO_SCHEMA = "sensor_msgs/msg/CameraInfo"
ROS_TWIST_SCHEMA = "geometry_msgs/msg/Twist"
ROS_TWIST_STAMPED_SCHEMA = "geometry_msgs/msg/TwistStamped"
ROS_ODOMETRY_SCHEMA = "nav_msgs/msg/Odometry"
ROS_POSE_STAMPED_SCHEMA = "geometry_msgs/msg/PoseStamped"
ROS_PATH_SCHEMA = "nav_msgs/msg/Path"
ROS_TF_SCHEMA = "tf2_msgs/msg/TFMessage"

# ``hbvs export`` writes a ROS 2 bag (MCAP storage, CDR) with these topics.
#: The command sent (run) or taught (teach).
ROS_CMD_VEL_TOPIC = "/cmd_vel"
#: The true pose (simulation) and the taught pose at the same time (runs).
ROS_TRUE_POSE_TOPIC = TRUE_POSE_TOPIC
ROS_DESIRED_POSE_TOPIC = DESIRED_POSE_TOPIC
#: The taught path, whole, once.
ROS_TAUGHT_PATH_TOPIC = "/taught_path"
ROS_IMAGE_TOPIC = "/camera/image/compressed"
ROS_CAMERA_INFO_TOPIC = "/camera/camera_info"
ROS_REFERENCE_IMAGE_TOPIC = "/reference/image/compressed"
ROS_TF_TOPIC = TRANSFORM_TOPIC
ROS_TF_STATIC_TOPIC = "/tf_static"

# ``repeat --live`` and ``robot-sim --ros2`` (DDS topic ``rt/<name>``: :mod:`hbvs_cli.io.ros2_dds`).
#: The camera of a robot (sensor_msgs Image; ``/compressed`` beside it for CompressedImage),
#: its CameraInfo on the sibling ``camera_info`` topic (ROS_CAMERA_INFO_TOPIC), the commands
#: on ROS_CMD_VEL_TOPIC and the stand-in robot's true pose on ROS_TRUE_POSE_TOPIC.
ROS_LIVE_IMAGE_TOPIC = "/camera/image_raw"
