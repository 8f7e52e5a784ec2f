"""The one table of hbvs's topics and schema names.

Every MCAP file hbvs writes is one of three kinds (teach, fit, run); each kind has a fixed
set of topics, each topic one schema. The names are written here and nowhere else: the
writers, the readers, the stages and the documentation's tables all take them from this
module (``tests/test_repository.py`` checks that no other module spells a topic).
"""

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
CONTROLLER_STATE_SCHEMA = "hbvs.ControllerState"

#: MCAP metadata record holding the simulated world of a teach file.
WORLD_METADATA = "hbvs.world"

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

#: Topics of each file kind: topic -> schema name.
TOPICS: dict[str, dict[str, str]] = {
    "teach": {
        IMAGE_TOPIC: COMPRESSED_IMAGE_SCHEMA,
        CALIBRATION_TOPIC: CAMERA_CALIBRATION_SCHEMA,
        TEACH_COMMAND_TOPIC: VELOCITY_COMMAND_SCHEMA,
        TRUE_POSE_TOPIC: POSE_IN_FRAME_SCHEMA,
    },
    "fit": {
        MODEL_TOPIC: FIT_MODEL_SCHEMA,
        RAW_DESIRED_TOPIC: DESIRED_SIGNAL_SCHEMA,
        SMOOTH_DESIRED_TOPIC: DESIRED_SIGNAL_SCHEMA,
        IMAGE_TOPIC: COMPRESSED_IMAGE_SCHEMA,
        ANNOTATIONS_TOPIC: IMAGE_ANNOTATIONS_SCHEMA,
        CALIBRATION_TOPIC: CAMERA_CALIBRATION_SCHEMA,
        REFERENCE_IMAGE_TOPIC: COMPRESSED_IMAGE_SCHEMA,
        TEMPLATE_IMAGE_TOPIC: COMPRESSED_IMAGE_SCHEMA,
    },
    "run": {
        STATE_TOPIC: CONTROLLER_STATE_SCHEMA,
        COMMAND_TOPIC: VELOCITY_COMMAND_SCHEMA,
        EVENTS_TOPIC: LOG_SCHEMA,
        TRUE_POSE_TOPIC: POSE_IN_FRAME_SCHEMA,
        DESIRED_POSE_TOPIC: POSE_IN_FRAME_SCHEMA,
        IMAGE_TOPIC: COMPRESSED_IMAGE_SCHEMA,
        ANNOTATIONS_TOPIC: IMAGE_ANNOTATIONS_SCHEMA,
        CALIBRATION_TOPIC: CAMERA_CALIBRATION_SCHEMA,
    },
}

# ----------------------------------------------------------------------------- ROS 2 message types
# The ROS 2 types hbvs reads from bags (``teach --bag``).
ROS_IMAGE_SCHEMA = "sensor_msgs/msg/Image"
ROS_COMPRESSED_IMAGE_SCHEMA = "sensor_msgs/msg/CompressedImage"
ROS_CAMERA_INFO_SCHEMA = "sensor_msgs/msg/CameraInfo"
ROS_TWIST_SCHEMA = "geometry_msgs/msg/Twist"
ROS_TWIST_STAMPED_SCHEMA = "geometry_msgs/msg/TwistStamped"
ROS_ODOMETRY_SCHEMA = "nav_msgs/msg/Odometry"
