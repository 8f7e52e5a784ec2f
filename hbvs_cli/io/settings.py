"""The options of the commands, declared once: name, type, default, help, bounds, config key.

Each table gives the command's typer signature (:mod:`hbvs_cli.cli.signature`) and its stage's options
dataclass. Precedence: built-in default < ``--config`` file < command line. Kept light: ``hbvs --help`` imports it."""

from __future__ import annotations

from dataclasses import dataclass, field, fields, make_dataclass
from pathlib import Path
from typing import Any, Mapping, Optional

from ..core.control_settings import DEFAULT_PRESET, FILTER_EKF, GAIN_UNITS, LAW_LATERAL_GAIN, ControllerGains
from ..io.shipped import shipped_name
from ..io.topics import ROS_CMD_VEL_TOPIC, ROS_LIVE_IMAGE_TOPIC

OUTPUT_HELP = "Output MCAP file, or - for stdout (a file is written beside it and renamed when complete; a device or FIFO is written in place)."

#: What a defaults table says about a value that the fit file, not the table, decides.
FROM_THE_FIT = "the fit's suggestion"


@dataclass(frozen=True)
class Setting:
    """One option of a stage: ``default`` what the options hold when it is not given (None: "not given");
    ``fallback`` the value used when neither the option nor the ``config`` key of a ``--config`` file gives
    one; ``shown`` the default in ``--help``'s words; ``bounds`` the ``min`` and ``max`` the command line checks."""

    name: str
    type: type
    help: str
    default: Any = None
    fallback: Any = None
    shown: str | None = None
    config: str | None = None
    flags: tuple[str, ...] = ()
    panel: str | None = None
    argument: bool = False
    required: bool = False
    repeatable: bool = False
    bounds: Mapping[str, float] = field(default_factory=dict)
    metavar: str | None = None

    @property
    def option_names(self) -> tuple[str, ...]:
        return self.flags or ("--" + self.name.replace("_", "-"),)

    @property
    def shown_default(self) -> str | None:
        """The default as ``--help`` shows it (None: nothing to show)."""
        if self.shown is not None:
            return self.shown
        value = self.fallback if self.default is None else self.default
        if value is None or value is False or self.argument or self.repeatable:
            return None
        return _shown(value)

    def bound_violation(self, value: float) -> str | None:
        """Why ``value`` is outside :attr:`bounds`, in the command line's words, or None."""
        low, high = self.bounds.get("min"), self.bounds.get("max")
        option = self.option_names[-1]
        if value != value:  # NaN compares false with every bound
            return f"Invalid value for '{option}': Input should be a number, got nan"
        if low is not None and not value >= low:
            return f"Invalid value for '{option}': Input should be greater than or equal to {_shown(low)}"
        if high is not None and not value <= high:
            return f"Invalid value for '{option}': Input should be less than or equal to {_shown(high)}"
        return None

    def resolve(self, given: Any, config: Mapping[str, Any], fallback: Any = None) -> Any:
        """The option if given, else the config's value, else ``fallback`` or this setting's own."""
        if given is not None:
            return given
        if self.config is not None and self.config in config:
            return config[self.config]
        return self.fallback if fallback is None else fallback


def _shown(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


#: Frame rate of the simulated camera and of an image folder when --fps is not given (Hz).
DEFAULT_FPS = 30.0

TEACH_SETTINGS: tuple[Setting, ...] = (
    Setting("output", str, OUTPUT_HELP, default="teach.mcap", flags=("-o", "--output")),
    Setting("sim", bool, "Simulated robot and camera (the default source).", default=False),
    Setting("video", Path, "A video file (anything OpenCV reads).", panel="Sources"),
    Setting("images", str, "A folder of images or a glob; sorted naturally.", panel="Sources"),
    Setting("camera", str, "A live camera, as repeat --live --camera takes it: an index, /dev/videoN, an RTSP/HTTP URL "
            "(robot-sim --mjpeg's, an IP camera's), or a video file read as --video; --duration or Ctrl-C ends it.",
            panel="Sources"),
    Setting("bag", Path, "A ROS 2 bag (folder with metadata.yaml: SQLite or MCAP storage, split, compressed; or one "
            ".mcap file), or an MCAP file of foxglove.CompressedImage (e.g. a teach file).", panel="Sources"),
    Setting("topic", str, "Image topic of the bag (automatic when there is one).", panel="Sources"),
    Setting("ros2_image", str, "A running ROS 2 camera: its sensor_msgs/msg/Image topic (.../compressed for CompressedImage), "
            "CameraInfo from the sibling camera_info topic; --duration or Ctrl-C ends it (pip install 'hbvs\\[ros2]').",
            panel="Sources"),
    Setting("ros2_cmd", str, "With --ros2-image: the operator's geometry_msgs/msg/Twist topic, recorded as the taught commands.",
            panel="Sources"),
    Setting("cmd_topic", str, "The bag's command topic (geometry_msgs Twist or TwistStamped, or nav_msgs Odometry), "
            "recorded as the taught (v, w); automatic when there is one.", panel="Sources"),
    Setting("path", str, "Taught path: a preset (straight, s-curve, arc) or a CSV with columns t,v,w (s, m/s, rad/s).",
            fallback=DEFAULT_PRESET, panel="Simulation"),
    Setting("route", str, "A simulated route longer than one view instead of one target: corridor (23 m and three turns "
            "past dots, a marker board and two photographs); it brings its own path and targets.", panel="Simulation"),
    Setting("offset", str, "Start the taught path displaced by DX,DY,DTHETA (m, m, deg), e.g. for a second drive to replay.",
            panel="Simulation"),
    Setting("target", str, "Target on the wall: dots, aruco or texture.", fallback="dots", panel="Simulation"),
    Setting("dots", int, "Number of dots of a dots target.", fallback=3, panel="Simulation", bounds={"min": 3}),
    Setting("texture", Path, "Poster image for --target texture.", shown="a built-in pattern", panel="Simulation"),
    Setting("calibration", Path, "Camera calibration: ROS camera_info YAML or OpenCV YAML/JSON. Required for video, images and camera."),
    Setting("fps", float, "Frame rate (Hz) of the simulated camera or of --images; for --video, replaces the container's rate.",
            shown=f"{DEFAULT_FPS:g} (simulation, --images)", bounds={"min": 0.1}),
    Setting("duration", float, "Seconds to record.", shown="the whole path or source", bounds={"min": 0.0}),
    Setting("seed", int, "Seed of the simulated sensor noise.", fallback=0, panel="Simulation", bounds={"min": 0}),
    Setting("noise", float, "Sensor noise, gray levels (1 sigma).", fallback=2.0, panel="Simulation", bounds={"min": 0.0}),
    Setting("blur", float, "Gaussian blur sigma (px).", fallback=0.0, panel="Simulation", bounds={"min": 0.0, "max": 100.0}),
    Setting("noise_grain", float, "Correlation length of the sensor noise (px, Gaussian sigma), as a camera's demosaicing, "
            "denoising and compression leave it; 0 for white noise.", fallback=0.0, panel="Simulation",
            bounds={"min": 0.0, "max": 20.0}),
    Setting("exposure", float, "Exposure gain of the simulated camera.", fallback=1.0, panel="Simulation", bounds={"min": 0.05}),
    Setting("video_out", Path, "Also write the simulated frames as a video (.avi or .mkv: MJPG; .mp4 or .mov: mp4v): "
            "practice footage for docs/walkthrough.md, whose truth is known.", panel="Simulation"),
    Setting("calibration_out", Path, "Also write the simulated camera's calibration as a ROS camera_info YAML (what "
            "--calibration reads).", panel="Simulation"),
    Setting("image_format", str, "Stored images: auto keeps JPEG and PNG files and bag images as they are "
            "and stores frames hbvs compresses (simulator, video, camera) as JPEG at --quality; png (lossless) or jpeg for all.",
            default="auto", flags=("--format",)),
    Setting("gray", bool, "Store one gray channel even from a colour source (12-20 % smaller; colour JPEGs are "
            "encoded again at --quality); the dot detector then sees luminance only, not a dot that differs in hue. "
            "Colour sources are stored in colour by default; the simulator's frames are gray anyway.", default=False),
    Setting("jpeg_quality", int, "JPEG quality of the frames hbvs compresses.", default=90, flags=("--quality",),
            bounds={"min": 1, "max": 100}),
)

#: The simulated robot's and camera's options and their defaults (a recorded source refuses them).
SIMULATION_DEFAULTS: dict[str, Any] = {s.name: s.fallback for s in TEACH_SETTINGS if s.panel == "Simulation"}


#: The default start offset of ``repeat --sim`` (m, m, deg): where the robot was put down by hand.
DEFAULT_OFFSET = "-0.1,0.05,2"
FIT_SETTINGS: tuple[Setting, ...] = (
    Setting("input", str, "Teach MCAP file, or - for stdin.", argument=True),
    Setting("output", str, OUTPUT_HELP, default="fit.mcap", flags=("-o", "--output")),
    Setting("target", str, "auto, dots, aruco, chessboard, charuco or texture.", default="auto"),
    Setting("reference", str, "The frame that is F*: first, last or a frame index.", default="first"),
    Setting("smoothing", str, "Spline smoothing: auto (generalised cross-validation) or the penalty lambda (s^3).", default="auto"),
    Setting("target_size", float, "Metric target size (m) for d*: the marker's side (aruco) or the largest dot-to-dot "
            "distance (dots) or a square's side (chessboard, charuco).", bounds={"min": 0.0}),
    Setting("max_gap", float, "Longest stretch (s) without the target that the spline may bridge.", default=1.0, bounds={"min": 0.0}),
    Setting("max_lost", float, "Largest fraction of frames without the target before fit fails.", default=0.3,
            bounds={"min": 0.0, "max": 1.0}),
    Setting("copy_images", bool, "Copy the taught images into the output, so it opens alone in Foxglove (by default open it "
            "together with the teach file).", default=False, flags=("--with-images",)),
    Setting("seed", int, "Seed of the robust (RANSAC) estimation.", default=0, bounds={"min": 0}),
    Setting("allow_truncated", bool, "Replace an existing output even when the input ended early (no end record: the writer "
            "upstream died).", default=False),
    Setting("marker_dict", str, "Marker dictionary, e.g. DICT_6X6_250 or DICT_APRILTAG_36h11 (default with --target auto: "
            "every one is scanned)."),
    Setting("marker_id", int, "The marker to use (default: every marker seen consistently, all corners as points).",
            bounds={"min": 0}),
    Setting("board", str, "A ChArUco board's squares across and down, e.g. 6x4 (default: inferred from its markers)."),
    Setting("target_points", Path, "CSV of the target points' positions on the wall in metres (x,y per line, in the "
            "order the target's points are found or any order for dots): pins the plane normal n* and gives d*."),
)

#: Default actuator limits of the simulated robot (m/s, rad/s): a small indoor platform.
DEFAULT_MAX_V = 0.5
DEFAULT_MAX_W = 0.6
#: Seconds without the target before a run is stopped.
DEFAULT_LOST_TIMEOUT = 3.0
#: Depths an initial estimate may take (m): below 1 mm the state filter's variances underflow.
MIN_DEPTH, MAX_DEPTH = 1e-3, 1e3
#: Longest measurement latency (frames): more than any run has steps at the default limit.
MAX_LATENCY_FRAMES = 1_000_000
#: Seconds without a camera frame before a live run commands zero (a stalled camera or link).
DEFAULT_STALE_TIMEOUT = 0.3
#: The longest a command may stand on one frame (s): beyond it a robot drives blind.
MAX_STALE_TIMEOUT = 10.0
#: The longest a run may wait for its target or camera (s).
MAX_LOST_TIMEOUT = 3600.0
#: Gains without a fit's suggestion (core's defaults; samples/gains.toml lists the same).
DEFAULT_GAINS = ControllerGains()

REPEAT_SETTINGS: tuple[Setting, ...] = (
    Setting("input", str, "Fit MCAP file (from hbvs fit), or - for stdin.", argument=True),
    Setting("output", str, OUTPUT_HELP, default="run.mcap", flags=("-o", "--output")),
    Setting("sim", bool, "Closed loop with a simulated robot and camera.", default=False, panel="Mode"),
    Setting("replay", Path, "Open loop: the frames of a teach recording are the live camera.", panel="Mode"),
    Setting("offset", str, "Start pose offset DX,DY,DTHETA (m, m, deg) in the taught start frame: where the robot was put down by hand.",
            fallback=DEFAULT_OFFSET, config="offset", panel="Simulation"),
    Setting("perception", str, "images (render and detect) or points (project and add --pixel-noise).",
            fallback="images", config="perception", panel="Simulation"),
    Setting("pixel_noise", float, "Pixel noise (px, 1 sigma) added to the measured points: the projected ones "
            "(--perception points) or the detector's (images).",
            fallback=0.0, config="pixel_noise", panel="Simulation", bounds={"min": 0.0}),
    Setting("rate", float, "Camera and control rate (Hz).", shown="the taught rate", config="rate", panel="Simulation",
            bounds={"min": 0.1}),
    Setting("depth", float, "Assumed d* (m) to build a world when the teach came from real footage.", panel="Simulation",
            bounds={"min": 0.0}),
    Setting("seed", int, "Seed of the simulated noise and faults.", default=0, panel="Simulation", bounds={"min": 0}),
    Setting("config", Path, "TOML file with gains and limits (options given here win).", panel="Controller"),
    Setting("law", str, "lateral-gain, paper (k_2 = 1, the paper's law exactly), or a baseline: non-adaptive "
            "(gamma = 0, dhat fixed at dhat0) or kanayama (Kanayama et al. 1990 on the pose at depth dhat0).",
            fallback=LAW_LATERAL_GAIN, config="law", panel="Controller"),
    Setting("k_v", float, f"k_v ({GAIN_UNITS['k_v']}) of (29).", shown=_shown(DEFAULT_GAINS.k_v), config="k_v", flags=("--kv",),
            panel="Controller"),
    Setting("k_w", float, f"k_w ({GAIN_UNITS['k_w']}) of (30).", shown=_shown(DEFAULT_GAINS.k_w), config="k_w", flags=("--kw",),
            panel="Controller"),
    Setting("gamma", float, f"gamma_1 ({GAIN_UNITS['gamma']}) of the update law (31) (from x_hd1_dot and the detector's noise).",
            shown=FROM_THE_FIT, config="gamma", panel="Controller"),
    Setting("k_2", float, f"Lateral gain k_2, k_w^2 / (4 x_hd1_dot^2) (see {shipped_name('docs/method.md')}).",
            shown=FROM_THE_FIT, config="k_2", flags=("--k2",), panel="Controller"),
    Setting("dhat0", float, "Initial depth estimate (m).", shown=FROM_THE_FIT, config="dhat0", panel="Controller",
            bounds={"min": MIN_DEPTH, "max": MAX_DEPTH}),
    Setting("speed", float, "Play the taught trajectory at this multiple of its pace.", fallback=1.0, config="speed", panel="Controller"),
    Setting("max_v", float, "|v| limit (m/s); inf for none.", fallback=DEFAULT_MAX_V, config="max_v", panel="Actuators"),
    Setting("max_w", float, "|w| limit (rad/s); inf for none.", fallback=DEFAULT_MAX_W, config="max_w", panel="Actuators"),
    Setting("max_accel", float, "Acceleration limit (m/s^2 and rad/s^2); inf for none.", shown="inf", config="max_accel",
            panel="Actuators"),
    Setting("base_lag", float, "The drive's time constant (s): its speed reaches 63 % of a step in the command after this "
            "long. The state filter predicts the motion through it (else the lag reads as depth).", fallback=0.0,
            config="base_lag", panel="Actuators", bounds={"min": 0.0, "max": 5.0}),
    Setting("latency", int, "Measurement latency in frames.", fallback=0, config="latency", panel="Actuators",
            bounds={"min": 0, "max": MAX_LATENCY_FRAMES}),
    Setting("lost_timeout", float, "Stop the run after the target was lost this long (s).",
            fallback=DEFAULT_LOST_TIMEOUT, config="lost_timeout", bounds={"min": 0.0, "max": MAX_LOST_TIMEOUT}),
    Setting("cmd_out", str, "Also write one JSON line per step (t, v, w) to FILE, FIFO or - (stdout): with --live the commands "
            "sent to the robot, as they go (for a driver); with --sim and --replay a log (unpaced)."),
    Setting("record_images", bool, "Store the camera images with detected and desired points.", default=False),
    Setting("occlude", str, "Hide the target from START to END seconds (repeatable), e.g. 8:10.", panel="Faults", repeatable=True),
    Setting("drop_rate", float, "Fraction of camera frames dropped.", default=0.0, panel="Faults", bounds={"min": 0.0, "max": 1.0}),
    Setting("outlier_rate", float, "Fraction of frames with a spurious blob (dots) or wrong matches.", default=0.0, panel="Faults",
            bounds={"min": 0.0, "max": 1.0}),
    Setting("exposure_step", str, "Sudden exposure change T:GAIN (s, gain factor).", panel="Faults"),
    Setting("allow_truncated", bool, "Replace an existing output even when an input ended early (no end record).", default=False),
    Setting("state_filter", str, "State filter between the camera and the law: ekf or none (the raw measurement, the paper exactly).",
            fallback=FILTER_EKF, config="filter", flags=("--filter",), panel="Controller"),
    Setting("foxglove", int, "Serve the run to the Foxglove app while it runs on ws://127.0.0.1:PORT (8765 when --foxglove comes "
            "without a port; pip install 'hbvs\\[live]'). The run file is unchanged.", panel="Live view"),
    Setting("foxglove_speed", float, "With --foxglove: pace the run at this multiple of real time (0: as fast as it goes).",
            default=1.0, panel="Live view", bounds={"min": 0.0}),
    # --live: a real robot, a ROS 2 system or any simulator (docs/robot.md).
    Setting("live", bool, "Closed loop with a robot: every camera frame measured, a command sent at once (docs/robot.md).",
            default=False, panel="Mode"),
    Setting("camera", str, "With --live: frames from OpenCV (an index, /dev/videoN, an RTSP/HTTP URL, or a video file "
            "played at its own rate); give --calibration.", panel="Live robot"),
    Setting("ros2_image", str, "With --live: frames from this ROS 2 topic (sensor_msgs/msg/Image or CompressedImage; the "
            "calibration from its sibling camera_info topic unless --calibration).", panel="Live robot"),
    Setting("calibration", Path, "With --live: the camera's calibration (ROS camera_info YAML or OpenCV YAML/JSON).", panel="Live robot"),
    Setting("ros2_cmd", str, "With --live: publish geometry_msgs/msg/Twist commands on this ROS 2 topic (reliable QoS). "
            f"Default {ROS_CMD_VEL_TOPIC} unless only --cmd-out is given.", panel="Live robot"),
    Setting("cmd_type", str, "With --ros2-cmd: twist or twist-stamped.", default="twist", panel="Live robot"),
    Setting("stale_timeout", float, "With --live: send zero commands when no usable frame came for this long (s); at most "
            "--lost-timeout.", default=DEFAULT_STALE_TIMEOUT, panel="Live robot", bounds={"min": 0.01, "max": MAX_STALE_TIMEOUT}),
    Setting("dry_run", bool, "With --live: measure and compute everything, but publish zero commands.", default=False,
            panel="Live robot"),
)

#: The settings by name.
REPEAT = {setting.name: setting for setting in REPEAT_SETTINGS}


def options_class(name: str, settings: tuple[Setting, ...], doc: str) -> type:
    """A frozen dataclass with one field per setting (in order; the arguments first)."""
    specs: list[tuple[str, Any, Any]] = []
    for setting in sorted(settings, key=lambda s: not (s.argument or s.required)):
        kind: Any = setting.type
        if setting.repeatable:
            specs.append((setting.name, list[kind], field(default_factory=list)))
        elif setting.argument or setting.required:
            specs.append((setting.name, kind))  # type: ignore[arg-type]
        else:
            specs.append((setting.name, kind if setting.default is not None else Optional[kind], field(default=setting.default)))
    cls = make_dataclass(name, specs, frozen=True)
    cls.__module__ = __name__  # pickled by name (sweep workers): it lives here
    cls.__doc__ = doc
    return cls


FitOptions = options_class("FitOptions", FIT_SETTINGS, "Everything ``hbvs fit`` was asked to do (see ``hbvs fit --help``).")
RepeatOptions = options_class("RepeatOptions", REPEAT_SETTINGS, "Everything ``hbvs repeat`` was asked to do (see ``hbvs repeat --help``).")


def options_from_command_line(cls: type, values: Mapping[str, Any]) -> Any:
    """The options dataclass from the values typer parsed (an absent repeatable option is None there)."""
    names = {f.name for f in fields(cls)}
    lists = {f.name for f in fields(cls) if f.default_factory is list}
    return cls(**{key: (list(value or []) if isinstance(value, (list, tuple)) or value is None and key in lists else value)
                  for key, value in values.items() if key in names})


#: The fields of ``hbvs teach``'s options (the stage's ``TeachOptions`` adds its methods).
TeachFields = options_class("TeachFields", TEACH_SETTINGS, "Everything ``hbvs teach`` was asked to do (see ``hbvs teach --help``).")


#: ``hbvs robot-sim``: a stand-in robot in its own process, over ROS 2 (docs/robot.md).
ROBOT_SIM_SETTINGS: tuple[Setting, ...] = (
    Setting("input", str, "Fit MCAP file (from hbvs fit): its taught world is rendered.", argument=True),
    Setting("ros2", bool, "Speak ROS 2 over DDS (pip install 'hbvs\\[ros2]').", default=False),
    Setting("mjpeg", int, "Without ROS: serve the camera as MJPEG on http://127.0.0.1:PORT/ (repeat --live --camera URL).",
            bounds={"min": 1, "max": 65535}),
    Setting("cmd_in", str, "Without ROS: the commands as JSON lines {\"v\", \"w\"} (repeat --cmd-out) from FILE, FIFO or -."),
    Setting("offset", str, "Start pose offset DX,DY,DTHETA (m, m, deg) from the taught start, as repeat --sim.",
            default=DEFAULT_OFFSET),
    Setting("rate", float, "Camera rate (Hz).", shown="the taught rate", bounds={"min": 0.1}),
    Setting("depth", float, "Assumed d* (m) to build a world when the teach came from real footage.", bounds={"min": 0.0}),
    Setting("seed", int, "Seed of the sensor noise.", default=0, bounds={"min": 0}),
    Setting("duration", float, "Seconds to run (default: until Ctrl-C or SIGTERM).", bounds={"min": 0.0}),
    Setting("image_topic", str, "Camera topic (sensor_msgs/msg/Image; CameraInfo on the sibling camera_info topic).",
            default=ROS_LIVE_IMAGE_TOPIC),
    Setting("image_format", str, "raw (sensor_msgs/msg/Image) or jpeg (CompressedImage on IMAGE_TOPIC/compressed).",
            default="raw"),
    Setting("cmd_topic", str, "Command topic (geometry_msgs/msg/Twist or TwistStamped, as --cmd-type).", default=ROS_CMD_VEL_TOPIC),
    Setting("cmd_type", str, "twist or twist-stamped.", default="twist"),
    Setting("poses_out", str, "Also write the true pose of every frame as JSON lines (stamp, x, y, phi) to FILE or -."),
    Setting("occlude", str, "Hide the target from START to END seconds after the start (a blank frame), e.g. 3:5.",
            repeatable=True),
    Setting("base", str, "The base's dynamics: kinematic (obeys at once), small (a small differential drive: 0.26 m/s, "
            "1.8 rad/s, 0.6 m/s^2, 3 rad/s^2, 0.12 s motor lag) or V,W,ACCEL,ALPHA,LAG.", default="kinematic"),
    Setting("stamp_fault", str, "A camera clock fault from T s after the robot first moved: freeze@T, back:S@T, jump:S@T (one frame S s ahead), "
            "second-clock:S@T (every other frame from a clock S s ahead), max@T (one frame at 2^31-1 s), stall:S@T "
            "(no frame for S s).", panel="Faults"),
)
RobotSimOptions = options_class("RobotSimOptions", ROBOT_SIM_SETTINGS, "Everything ``hbvs robot-sim`` was asked to do.")


#: Resolution of a raster figure when ``--dpi`` is not given (dots per inch).
DEFAULT_DPI = 200.0

REPORT_SETTINGS: tuple[Setting, ...] = (
    Setting("runs", str, "Run MCAP files from hbvs repeat, or one fit file from hbvs fit (- for one on stdin), or the results "
            "folder of hbvs sweep.", argument=True, repeatable=True),
    Setting("json_output", bool, "Print the metrics as one JSON object instead of a table.", default=False, flags=("--json",)),
    Setting("plot", Path, "Write a figure; the suffix picks the format: .pdf or .svg (vector, for papers), .png (raster). "
            "A fit file gives the fit figure (Remark 1).", panel="Figure"),
    Setting("fail_above", str, "KEY=VALUE: exit 1 when a metric (dotted JSON key) exceeds VALUE; repeatable.", repeatable=True),
    Setting("export_tum", Path, "Write taught and repeated trajectories in TUM format into this folder."),
    Setting("tolerance", str, "Settling tolerance NAME=VALUE (e1, e2, ebar2, e3, position_m, heading_deg); repeatable.",
            repeatable=True),
    Setting("require_converged", bool, "Exit 1 when any run did not converge (the verdict): for CI. For a sweep's folder: "
            "unless every planned run converged (failed, stopped and missing runs count as not converged).", default=False),
    Setting("labels", str, "NAME of each run in tables and legends, once per run in order (default: its law).",
            flags=("--label",), repeatable=True),
    Setting("dpi", float, "Resolution of a raster figure.", fallback=DEFAULT_DPI, panel="Figure",
            bounds={"min": 10.0, "max": 2400.0}),
    Setting("size", str, "Figure size WxH in inches (default: 7 wide, as tall as the panels need); one column: 3.5x8 with "
            "--panels position,heading,v,w,top.", panel="Figure"),
    Setting("panels", str, "Comma-separated panels, in order (default all): position, heading, e1, ebar2, e2, e3, v, w, dhat, "
            "V, top; for a fit file: theta_d, x_hd1, x_hd2 (each also NAME_residual), x_hd1_dot.", panel="Figure"),
)
REPORT = {setting.name: setting for setting in REPORT_SETTINGS}
ReportOptions = options_class("ReportOptions", REPORT_SETTINGS, "Everything ``hbvs report`` was asked to do (see ``hbvs report --help``).")

SWEEP_SETTINGS: tuple[Setting, ...] = (
    Setting("fit", str, "Fit MCAP file (from hbvs fit); every run is hbvs repeat --sim on it.", argument=True),
    Setting("output", Path, "Results folder: runs.parquet, runs.csv, summary figures; the same command resumes into it.",
            default=Path("sweep-results"), flags=("-o", "--output")),
    Setting("spec", Path, "TOML spec: seed, repeats, sampling, samples and the tables vary and fixed (docs/sweeps.md)."),
    Setting("vary", str, "NAME=LO:HI:N (grid), NAME=LO:HI (sampled range) or NAME=A,B,C; repeatable; replaces the spec's.",
            repeatable=True),
    Setting("fixed", str, "NAME=VALUE held for every run, e.g. perception=points; repeatable.", flags=("--set",), repeatable=True),
    Setting("repeats", int, "Runs per point, each with its own seed.", config="repeats", fallback=1, bounds={"min": 1}),
    Setting("seed", int, "Sweep seed: run i has the seed of SeedSequence(\\[seed, i]).", config="seed", fallback=0, bounds={"min": 0}),
    Setting("sampling", str, "grid, or sobol, halton, lhs (scipy.stats.qmc), random for ranges.", config="sampling", fallback="grid"),
    Setting("samples", int, "Samples of the ranges (not grid).", config="samples", fallback=64, bounds={"min": 1}),
    Setting("scheduler", str, "Address of a running Dask scheduler, e.g. tcp://HOST:8786.", panel="Engine"),
    Setting("cluster", str, "slurm or pbs: workers as batch jobs (dask-jobqueue; pip install 'hbvs\\[sweep-cluster]').",
            panel="Engine"),
    Setting("workers", int, "Local worker processes (default one per core), or batch jobs with --cluster.", panel="Engine",
            bounds={"min": 1}),
    Setting("dashboard", str, "Serve Dask's dashboard (off by default; it has no authentication) on PORT of 127.0.0.1, or on "
            "HOST:PORT, HOST an IPv4 address or a host name (every interface only if you name 0.0.0.0; no IPv6).", panel="Engine",
            metavar="[HOST:]PORT"),
    Setting("keep_runs", str, "Keep run MCAPs in RESULTS/runs/: failed (default: failed or stopped runs), all or none.",
            default="failed"),
    Setting("json_output", bool, "Print the summary as JSON instead of tables.", default=False, flags=("--json",)),
    Setting("plots", bool, "Draw the summary figures into the results folder.", default=True, flags=("--plots/--no-plots",)),
)
#: The settings by name.
SWEEP = {setting.name: setting for setting in SWEEP_SETTINGS}
SweepOptions = options_class("SweepOptions", SWEEP_SETTINGS, "Everything ``hbvs sweep`` was asked to do (see ``hbvs sweep --help``).")

EXPORT_SETTINGS: tuple[Setting, ...] = (
    Setting("input", str, "A teach, fit or run MCAP file from hbvs, or - for stdin.", argument=True),
    Setting("output", str, "The ROS 2 bag folder to write (MCAP storage, CDR); written beside it and moved into place when "
            "complete.", flags=("-o", "--output"), required=True),
    Setting("allow_truncated", bool, "Replace an existing bag even when the input ended early (no end record: the writer "
            "upstream died).", default=False),
)
ExportOptions = options_class("ExportOptions", EXPORT_SETTINGS, "What ``hbvs export`` was asked to do (see ``hbvs export --help``).")

INFO_SETTINGS: tuple[Setting, ...] = (
    Setting("input", str, "An MCAP file (an hbvs teach, fit or run file, or any other), or - for stdin.", argument=True),
    Setting("json_output", bool, "Print one JSON object instead of the text.", default=False, flags=("--json",)),
)
InfoOptions = options_class("InfoOptions", INFO_SETTINGS, "What ``hbvs info`` was asked to do (see ``hbvs info --help``).")
