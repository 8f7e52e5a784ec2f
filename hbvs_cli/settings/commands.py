"""The options of the commands, each declared once as a field of its stage's options dataclass (:mod:`.option`).
Precedence: built-in default < ``--config`` file < command line. Kept light: ``hbvs --help`` imports it."""

from __future__ import annotations

import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from ..errors import UsageError
from ..core.control_settings import ALL_LAWS, DEFAULT_PRESET, FILTER_EKF, FILTERS, GAIN_UNITS, LAW_LATERAL_GAIN, ControllerGains
from ..io.topics import ROS_CMD_VEL_TOPIC, ROS_LIVE_IMAGE_TOPIC
from .option import Options, option, settings_of, shown

OUTPUT_HELP = "Output MCAP file, or - for stdout (a file is written beside it and renamed when complete; a device or FIFO is written in place)."

#: What a defaults table says about a value that the fit file, not the table, decides.
FROM_THE_FIT = "the fit's suggestion"


#: Frame rate of the simulated camera and of an image folder when --fps is not given (Hz).
DEFAULT_FPS = 30.0
#: ``--cmd-type``: geometry_msgs Twist or TwistStamped.
CMD_TYPES = ("twist", "twist-stamped")
#: ``repeat --perception``: rendered images through the detector, or projected points.
PERCEPTIONS = ("points", "images")
#: ``sweep --keep-runs``: which runs' MCAPs a sweep keeps.
KEEP_CHOICES = ("failed", "all", "none")
#: ``sweep --sampling``: a grid, or scipy.stats.qmc's samplers and plain random numbers for ranges.
SAMPLING_METHODS = ("grid", "sobol", "halton", "lhs", "random")
#: ``sweep --cluster``: the batch systems dask-jobqueue starts workers on.
CLUSTER_KINDS = ("slurm", "pbs")


def registered_laws() -> tuple[str, ...]:
    """``--law``'s choices: the laws registered in :data:`~hbvs_cli.core.laws.LAW_REGISTRY`. Until that module is
    imported (numpy: not for ``--help``) nothing can have been added to the shipped ones."""
    laws = sys.modules.get("hbvs_cli.core.laws")
    return tuple(laws.LAW_REGISTRY) if laws is not None else ALL_LAWS


@dataclass(frozen=True)
class TeachOptions(Options):
    """Everything ``hbvs teach`` was asked to do (see ``hbvs teach --help``)."""

    output: str = option(OUTPUT_HELP, default="teach.mcap", flags=("-o", "--output"))
    sim: bool = option("Simulated robot and camera (the default source).", default=False)
    video: Path | None = option("A video file (anything OpenCV reads).", panel="Sources")
    images: str | None = option("A folder of images or a glob; sorted naturally.", panel="Sources")
    camera: str | None = option("A live camera, as repeat --live --camera takes it: an index, /dev/videoN, an RTSP/HTTP URL "
        "(robot-sim --mjpeg's, an IP camera's), or a video file read as --video; --duration or Ctrl-C ends it.", panel="Sources")
    bag: Path | None = option("A ROS 2 bag (folder with metadata.yaml: SQLite or MCAP storage, split, compressed; or one "
        ".mcap file), or an MCAP file of foxglove.CompressedImage (e.g. a teach file).", panel="Sources")
    topic: str | None = option("Image topic of the bag (automatic when there is one).", panel="Sources")
    ros2_image: str | None = option("A running ROS 2 camera: its sensor_msgs/msg/Image topic (.../compressed for CompressedImage), "
        "CameraInfo from the sibling camera_info topic; --duration or Ctrl-C ends it (pip install 'hbvs\\[ros2]').", panel="Sources")
    ros2_cmd: str | None = option("With --ros2-image: the operator's geometry_msgs/msg/Twist topic, recorded as the taught commands.",
        panel="Sources")
    cmd_topic: str | None = option("The bag's command topic (geometry_msgs Twist or TwistStamped, or nav_msgs Odometry), "
        "recorded as the taught (v, w); automatic when there is one.", panel="Sources")
    path: str | None = option("Taught path: a preset (straight, s-curve, arc) or a CSV with columns t,v,w (s, m/s, rad/s).",
        fallback=DEFAULT_PRESET, panel="Simulation")
    route: str | None = option("A simulated route longer than one view instead of one target: corridor (23 m and three turns "
        "past dots, a marker board and two photographs); it brings its own path and targets.", panel="Simulation")
    offset: str | None = option("Start the taught path displaced by DX,DY,DTHETA (m, m, deg), e.g. for a second drive to replay.",
        panel="Simulation")
    target: str | None = option("Target on the wall: dots, aruco or texture.", fallback="dots", panel="Simulation")
    dots: int | None = option("Number of dots of a dots target.", fallback=3, panel="Simulation", bounds={"min": 3})
    texture: Path | None = option("Poster image for --target texture.", shown="a built-in pattern", panel="Simulation")
    calibration: Path | None = option("Camera calibration: ROS camera_info YAML or OpenCV YAML/JSON. Required for video, images and camera.")
    fps: float | None = option("Frame rate (Hz) of the simulated camera or of --images; for --video, replaces the container's rate.",
        shown=f"{DEFAULT_FPS:g} (simulation, --images)", bounds={"min": 0.1})
    duration: float | None = option("Seconds to record.", shown="the whole path or source", bounds={"min": 0.0})
    seed: int | None = option("Seed of the simulated sensor noise.", fallback=0, panel="Simulation", bounds={"min": 0})
    noise: float | None = option("Sensor noise, gray levels (1 sigma).", fallback=2.0, panel="Simulation", bounds={"min": 0.0})
    blur: float | None = option("Gaussian blur sigma (px).", fallback=0.0, panel="Simulation", bounds={"min": 0.0, "max": 100.0})
    noise_grain: float | None = option("Correlation length of the sensor noise (px, Gaussian sigma), as a camera's demosaicing, "
        "denoising and compression leave it; 0 for white noise.", fallback=0.0, panel="Simulation", bounds={"min": 0.0, "max": 20.0})
    exposure: float | None = option("Exposure gain of the simulated camera.", fallback=1.0, panel="Simulation", bounds={"min": 0.05})
    video_out: Path | None = option("Also write the simulated frames as a video (.avi or .mkv: MJPG; .mp4 or .mov: mp4v): "
        "practice footage for docs/walkthrough.md, whose truth is known.", panel="Simulation")
    calibration_out: Path | None = option("Also write the simulated camera's calibration as a ROS camera_info YAML (what "
        "--calibration reads).", panel="Simulation")
    image_format: str = option("Stored images: auto keeps JPEG and PNG files and bag images as they are "
        "and stores frames hbvs compresses (simulator, video, camera) as JPEG at --quality; png (lossless) or jpeg for all.",
        default="auto", flags=("--format",))
    gray: bool = option("Store one gray channel even from a colour source (12-20 % smaller; colour JPEGs are "
        "encoded again at --quality); the dot detector then sees luminance only, not a dot that differs in hue. "
        "Colour sources are stored in colour by default; the simulator's frames are gray anyway.", default=False)
    jpeg_quality: int = option("JPEG quality of the frames hbvs compresses.", default=90, flags=("--quality",),
        bounds={"min": 1, "max": 100})

    def source_kind(self) -> str:
        """The one source asked for (``sim`` when none is)."""
        given = [name for name, value in (("video", self.video), ("images", self.images), ("camera", self.camera), ("bag", self.bag),
                                          ("ros2", self.ros2_image)) if value is not None]
        if self.sim:
            given.insert(0, "sim")
        if len(given) > 1:
            raise UsageError(f"give exactly one source, got {', '.join('--' + g for g in given)}")
        return given[0] if given else "sim"

    def for_simulation(self) -> TeachOptions:
        """These options with the simulation's defaults filled in where none was given."""
        missing = {name: value for name, value in SIMULATION_DEFAULTS.items() if getattr(self, name) is None}
        return replace(self, **missing, fps=DEFAULT_FPS if self.fps is None else self.fps)


#: The fields of ``hbvs teach``'s options.
TEACH_SETTINGS = settings_of(TeachOptions)
#: The simulated robot's and camera's options and their defaults (a recorded source refuses them).
SIMULATION_DEFAULTS: dict[str, Any] = {s.name: s.fallback for s in TEACH_SETTINGS if s.panel == "Simulation"}


#: The default start offset of ``repeat --sim`` (m, m, deg): where the robot was put down by hand.
DEFAULT_OFFSET = "-0.1,0.05,2"


@dataclass(frozen=True)
class FitOptions(Options):
    """Everything ``hbvs fit`` was asked to do (see ``hbvs fit --help``)."""

    input: str = option("Teach MCAP file, or - for stdin.", argument=True)
    output: str = option(OUTPUT_HELP, default="fit.mcap", flags=("-o", "--output"))
    target: str = option("auto, dots, aruco, chessboard, charuco or texture.", default="auto")
    reference: str = option("The frame that is F*: first, last or a frame index.", default="first")
    smoothing: str = option("Spline smoothing: auto (generalised cross-validation) or the penalty lambda (s^3).", default="auto")
    target_size: float | None = option("Metric target size (m) for d*: the marker's side (aruco) or the largest dot-to-dot "
        "distance (dots) or a square's side (chessboard, charuco).", bounds={"min": 0.0})
    max_gap: float = option("Longest stretch (s) without the target that the spline may bridge.", default=1.0, bounds={"min": 0.0})
    max_lost: float = option("Largest fraction of frames without the target before fit fails.", default=0.3,
        bounds={"min": 0.0, "max": 1.0})
    copy_images: bool = option("Copy the taught images into the output, so it opens alone in Foxglove (by default open it "
        "together with the teach file).", default=False, flags=("--with-images",))
    seed: int = option("Seed of the robust (RANSAC) estimation.", default=0, bounds={"min": 0})
    allow_truncated: bool = option("Replace an existing output even when the input ended early (no end record: the writer "
        "upstream died).", default=False)
    marker_dict: str | None = option("Marker dictionary, e.g. DICT_6X6_250 or DICT_APRILTAG_36h11 (default with --target auto: "
        "every one is scanned).")
    marker_id: int | None = option("The marker to use (default: every marker seen consistently, all corners as points).", bounds={"min": 0})
    board: str | None = option("A ChArUco board's squares across and down, e.g. 6x4 (default: inferred from its markers).")
    target_points: Path | None = option("CSV of the target points' positions on the wall in metres (x,y per line, in the "
        "order the target's points are found or any order for dots): pins the plane normal n* and gives d*.")


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


@dataclass(frozen=True)
class RepeatOptions(Options):
    """Everything ``hbvs repeat`` was asked to do (see ``hbvs repeat --help``)."""

    input: str = option("Fit MCAP file (from hbvs fit), or - for stdin.", argument=True)
    output: str = option(OUTPUT_HELP, default="run.mcap", flags=("-o", "--output"))
    sim: bool = option("Closed loop with a simulated robot and camera.", default=False, panel="Mode")
    replay: Path | None = option("Open loop: the frames of a teach recording are the live camera.", panel="Mode")
    offset: str | None = option("Start pose offset DX,DY,DTHETA (m, m, deg) in the taught start frame: where the robot was put down by hand.",
        fallback=DEFAULT_OFFSET, config="offset", panel="Simulation")
    perception: str | None = option("images (render and detect) or points (project and add --pixel-noise).",
        fallback="images", config="perception", panel="Simulation", choices=PERCEPTIONS)
    pixel_noise: float | None = option("Pixel noise (px, 1 sigma) added to the measured points: the projected ones "
        "(--perception points) or the detector's (images).",
        fallback=0.0, config="pixel_noise", panel="Simulation", bounds={"min": 0.0})
    rate: float | None = option("Camera and control rate (Hz).", shown="the taught rate", config="rate", panel="Simulation",
        bounds={"min": 0.1})
    depth: float | None = option("Assumed d* (m) to build a world when the teach came from real footage.", panel="Simulation",
        bounds={"min": 0.0})
    seed: int = option("Seed of the simulated noise and faults.", default=0, panel="Simulation", bounds={"min": 0})
    config: Path | None = option("TOML file with gains and limits (options given here win).", panel="Controller")
    law: str | None = option("lateral-gain, paper (k_2 = 1, the paper's law exactly), or a baseline: non-adaptive "
        "(gamma = 0, dhat fixed at dhat0) or kanayama (Kanayama et al. 1990 on the pose at depth dhat0).",
        fallback=LAW_LATERAL_GAIN, config="law", panel="Controller", choices=registered_laws)
    k_v: float | None = option(f"k_v ({GAIN_UNITS['k_v']}) of (29).", shown=shown(DEFAULT_GAINS.k_v), config="k_v", flags=("--kv",),
        panel="Controller")
    k_w: float | None = option(f"k_w ({GAIN_UNITS['k_w']}) of (30).", shown=shown(DEFAULT_GAINS.k_w), config="k_w", flags=("--kw",),
        panel="Controller")
    gamma: float | None = option(f"gamma_1 ({GAIN_UNITS['gamma']}) of the update law (31) (from x_hd1_dot and the detector's noise).",
        shown=FROM_THE_FIT, config="gamma", panel="Controller")
    k_2: float | None = option(f"Lateral gain k_2, k_w^2 / (4 x_hd1_dot^2) (see docs/method.md).",
        shown=FROM_THE_FIT, config="k_2", flags=("--k2",), panel="Controller")
    dhat0: float | None = option("Initial depth estimate (m).", shown=FROM_THE_FIT, config="dhat0", panel="Controller",
        bounds={"min": MIN_DEPTH, "max": MAX_DEPTH})
    speed: float | None = option("Play the taught trajectory at this multiple of its pace.", fallback=1.0, config="speed", panel="Controller")
    max_v: float | None = option("|v| limit (m/s); inf for none.", fallback=DEFAULT_MAX_V, config="max_v", panel="Actuators")
    max_w: float | None = option("|w| limit (rad/s); inf for none.", fallback=DEFAULT_MAX_W, config="max_w", panel="Actuators")
    max_accel: float | None = option("Acceleration limit (m/s^2 and rad/s^2); inf for none.", shown="inf", config="max_accel",
        panel="Actuators")
    base_lag: float | None = option("The drive's time constant (s): its speed reaches 63 % of a step in the command after this "
        "long. The state filter predicts the motion through it (else the lag reads as depth).", fallback=0.0,
        config="base_lag", panel="Actuators", bounds={"min": 0.0, "max": 5.0})
    latency: int | None = option("Measurement latency in frames.", fallback=0, config="latency", panel="Actuators",
        bounds={"min": 0, "max": MAX_LATENCY_FRAMES})
    lost_timeout: float | None = option("Stop the run after the target was lost this long (s).",
        fallback=DEFAULT_LOST_TIMEOUT, config="lost_timeout", bounds={"min": 0.0, "max": MAX_LOST_TIMEOUT})
    cmd_out: str | None = option("Also write one JSON line per step (t, v, w) to FILE, FIFO or - (stdout): with --live the commands "
        "sent to the robot, as they go (for a driver); with --sim and --replay a log (unpaced).")
    record_images: bool = option("Store the camera images with detected and desired points.", default=False)
    occlude: list[str] = option("Hide the target from START to END seconds (repeatable), e.g. 8:10.", panel="Faults", repeatable=True)
    drop_rate: float = option("Fraction of camera frames dropped.", default=0.0, panel="Faults", bounds={"min": 0.0, "max": 1.0})
    outlier_rate: float = option("Fraction of frames with a spurious blob (dots) or wrong matches.", default=0.0, panel="Faults",
        bounds={"min": 0.0, "max": 1.0})
    exposure_step: str | None = option("Sudden exposure change T:GAIN (s, gain factor).", panel="Faults")
    allow_truncated: bool = option("Replace an existing output even when an input ended early (no end record).", default=False)
    state_filter: str | None = option("State filter between the camera and the law: ekf or none (the raw measurement, the paper exactly).",
        fallback=FILTER_EKF, config="filter", flags=("--filter",), panel="Controller", choices=FILTERS)
    foxglove: int | None = option("Serve the run to the Foxglove app while it runs on ws://127.0.0.1:PORT (8765 when --foxglove comes "
        "without a port; pip install 'hbvs\\[live]'). The run file is unchanged.", panel="Live view")
    foxglove_speed: float = option("With --foxglove: pace the run at this multiple of real time (0: as fast as it goes).",
        default=1.0, panel="Live view", bounds={"min": 0.0})
    # --live: a real robot, a ROS 2 system or any simulator (docs/robot.md).
    live: bool = option("Closed loop with a robot: every camera frame measured, a command sent at once (docs/robot.md).",
        default=False, panel="Mode")
    camera: str | None = option("With --live: frames from OpenCV (an index, /dev/videoN, an RTSP/HTTP URL, or a video file "
        "played at its own rate); give --calibration.", panel="Live robot")
    ros2_image: str | None = option("With --live: frames from this ROS 2 topic (sensor_msgs/msg/Image or CompressedImage; the "
        "calibration from its sibling camera_info topic unless --calibration).", panel="Live robot")
    calibration: Path | None = option("With --live: the camera's calibration (ROS camera_info YAML or OpenCV YAML/JSON).", panel="Live robot")
    ros2_cmd: str | None = option("With --live: publish geometry_msgs/msg/Twist commands on this ROS 2 topic (reliable QoS). "
        f"Default {ROS_CMD_VEL_TOPIC} unless only --cmd-out is given.", panel="Live robot")
    cmd_type: str = option("With --ros2-cmd: twist or twist-stamped.", default="twist", panel="Live robot", choices=CMD_TYPES)
    stale_timeout: float = option("With --live: send zero commands when no usable frame came for this long (s); at most "
        "--lost-timeout.", default=DEFAULT_STALE_TIMEOUT, panel="Live robot", bounds={"min": 0.01, "max": MAX_STALE_TIMEOUT})
    dry_run: bool = option("With --live: measure and compute everything, but publish zero commands.", default=False, panel="Live robot")

REPEAT_SETTINGS = settings_of(RepeatOptions)
#: The settings by name.
REPEAT = {setting.name: setting for setting in REPEAT_SETTINGS}
#: ``repeat --sim``'s faults (its Faults panel), in their order: a run's metadata records them, ``--live`` refuses them.
SIM_FAULTS = tuple(setting.name for setting in REPEAT_SETTINGS if setting.panel == "Faults")


#: ``hbvs robot-sim``: a stand-in robot in its own process, over ROS 2 (docs/robot.md).
@dataclass(frozen=True)
class RobotSimOptions(Options):
    """Everything ``hbvs robot-sim`` was asked to do."""

    input: str = option("Fit MCAP file (from hbvs fit): its taught world is rendered.", argument=True)
    ros2: bool = option("Speak ROS 2 over DDS (pip install 'hbvs\\[ros2]').", default=False)
    mjpeg: int | None = option("Without ROS: serve the camera as MJPEG on http://127.0.0.1:PORT/ (repeat --live --camera URL).",
        bounds={"min": 1, "max": 65535})
    cmd_in: str | None = option("Without ROS: the commands as JSON lines {\"v\", \"w\"} (repeat --cmd-out) from FILE, FIFO or -.")
    offset: str = option("Start pose offset DX,DY,DTHETA (m, m, deg) from the taught start, as repeat --sim.", default=DEFAULT_OFFSET)
    rate: float | None = option("Camera rate (Hz).", shown="the taught rate", bounds={"min": 0.1})
    depth: float | None = option("Assumed d* (m) to build a world when the teach came from real footage.", bounds={"min": 0.0})
    seed: int = option("Seed of the sensor noise.", default=0, bounds={"min": 0})
    duration: float | None = option("Seconds to run (default: until Ctrl-C or SIGTERM).", bounds={"min": 0.0})
    image_topic: str = option("Camera topic (sensor_msgs/msg/Image; CameraInfo on the sibling camera_info topic).",
        default=ROS_LIVE_IMAGE_TOPIC)
    image_format: str = option("raw (sensor_msgs/msg/Image) or jpeg (CompressedImage on IMAGE_TOPIC/compressed).",
        default="raw", choices=("raw", "jpeg"))
    cmd_topic: str = option("Command topic (geometry_msgs/msg/Twist or TwistStamped, as --cmd-type).", default=ROS_CMD_VEL_TOPIC)
    cmd_type: str = option("twist or twist-stamped.", default="twist", choices=CMD_TYPES)
    poses_out: str | None = option("Also write the true pose of every frame as JSON lines (stamp, x, y, phi) to FILE or -.")
    occlude: list[str] = option("Hide the target from START to END seconds after the start (a blank frame), e.g. 3:5.", repeatable=True)
    base: str = option("The base's dynamics: kinematic (obeys at once), small (a small differential drive: 0.26 m/s, "
        "1.8 rad/s, 0.6 m/s^2, 3 rad/s^2, 0.12 s motor lag) or V,W,ACCEL,ALPHA,LAG.", default="kinematic")
    stamp_fault: str | None = option("A camera clock fault from T s after the robot first moved: freeze@T, back:S@T, jump:S@T (one frame S s ahead), "
        "second-clock:S@T (every other frame from a clock S s ahead), max@T (one frame at 2^31-1 s), stall:S@T "
        "(no frame for S s).", panel="Faults")


#: Resolution of a raster figure when ``--dpi`` is not given (dots per inch).
DEFAULT_DPI = 200.0


@dataclass(frozen=True)
class ReportOptions(Options):
    """Everything ``hbvs report`` was asked to do (see ``hbvs report --help``)."""

    runs: list[str] = option("Run MCAP files from hbvs repeat, or one fit file from hbvs fit (- for one on stdin), or the results "
        "folder of hbvs sweep.", argument=True, repeatable=True)
    json_output: bool = option("Print the metrics as one JSON object instead of a table.", default=False, flags=("--json",))
    plot: Path | None = option("Write a figure; the suffix picks the format: .pdf or .svg (vector, for papers), .png (raster). "
        "A fit file gives the fit figure (Remark 1).", panel="Figure")
    fail_above: list[str] = option("KEY=VALUE: exit 1 when a metric (dotted JSON key) exceeds VALUE; repeatable.", repeatable=True)
    export_tum: Path | None = option("Write taught and repeated trajectories in TUM format into this folder.")
    tolerance: list[str] = option("Settling tolerance NAME=VALUE (e1, e2, ebar2, e3, position_m, heading_deg); repeatable.",
        repeatable=True)
    require_converged: bool = option("Exit 1 when any run did not converge (the verdict): for CI. For a sweep's folder: "
        "unless every planned run converged (failed, stopped and missing runs count as not converged).", default=False)
    labels: list[str] = option("NAME of each run in tables and legends, once per run in order (default: its law).",
        flags=("--label",), repeatable=True)
    dpi: float | None = option("Resolution of a raster figure.", fallback=DEFAULT_DPI, panel="Figure", bounds={"min": 10.0, "max": 2400.0})
    size: str | None = option("Figure size WxH in inches (default: 7 wide, as tall as the panels need); one column: 3.5x8 with "
        "--panels position,heading,v,w,top.", panel="Figure")
    panels: str | None = option("Comma-separated panels, in order (default all): position, heading, e1, ebar2, e2, e3, v, w, dhat, "
        "V, top; for a fit file: theta_d, x_hd1, x_hd2 (each also NAME_residual), x_hd1_dot.", panel="Figure")


@dataclass(frozen=True)
class SweepOptions(Options):
    """Everything ``hbvs sweep`` was asked to do (see ``hbvs sweep --help``)."""

    fit: str = option("Fit MCAP file (from hbvs fit); every run is hbvs repeat --sim on it.", argument=True)
    output: Path = option("Results folder: runs.parquet, runs.csv, summary figures; the same command resumes into it.",
        default=Path("sweep-results"), flags=("-o", "--output"))
    spec: Path | None = option("TOML spec: seed, repeats, sampling, samples and the tables vary and fixed (docs/sweeps.md).")
    vary: list[str] = option("NAME=LO:HI:N (grid), NAME=LO:HI (sampled range) or NAME=A,B,C; repeatable; replaces the spec's.",
        repeatable=True)
    fixed: list[str] = option("NAME=VALUE held for every run, e.g. perception=points; repeatable.", flags=("--set",), repeatable=True)
    repeats: int | None = option("Runs per point, each with its own seed.", config="repeats", fallback=1, bounds={"min": 1})
    seed: int | None = option("Sweep seed: run i has the seed of SeedSequence(\\[seed, i]).", config="seed", fallback=0, bounds={"min": 0})
    sampling: str | None = option("grid, or sobol, halton, lhs (scipy.stats.qmc), random for ranges.", config="sampling", fallback="grid",
        choices=SAMPLING_METHODS)
    samples: int | None = option("Samples of the ranges (not grid).", config="samples", fallback=64, bounds={"min": 1})
    scheduler: str | None = option("Address of a running Dask scheduler, e.g. tcp://HOST:8786.", panel="Engine")
    cluster: str | None = option("slurm or pbs: workers as batch jobs (dask-jobqueue; pip install 'hbvs\\[sweep-cluster]').",
        panel="Engine", choices=CLUSTER_KINDS)
    workers: int | None = option("Local worker processes (default one per core), or batch jobs with --cluster.", panel="Engine",
        bounds={"min": 1})
    dashboard: str | None = option("Serve Dask's dashboard (off by default; it has no authentication) on PORT of 127.0.0.1, or on "
        "HOST:PORT, HOST an IPv4 address or a host name (every interface only if you name 0.0.0.0; no IPv6).", panel="Engine",
        metavar="[HOST:]PORT")
    keep_runs: str = option("Keep run MCAPs in RESULTS/runs/: failed (default: failed or stopped runs), all or none.",
        default="failed", choices=KEEP_CHOICES)
    json_output: bool = option("Print the summary as JSON instead of tables.", default=False, flags=("--json",))
    plots: bool = option("Draw the summary figures into the results folder.", default=True, flags=("--plots/--no-plots",))


#: The settings by name.
SWEEP = {setting.name: setting for setting in settings_of(SweepOptions)}


@dataclass(frozen=True)
class ExportOptions(Options):
    """What ``hbvs export`` was asked to do (see ``hbvs export --help``)."""

    input: str = option("A teach, fit or run MCAP file from hbvs, or - for stdin.", argument=True)
    output: str = option("The ROS 2 bag folder to write (MCAP storage, CDR); written beside it and moved into place when "
        "complete.", flags=("-o", "--output"), required=True)
    allow_truncated: bool = option("Replace an existing bag even when the input ended early (no end record: the writer "
        "upstream died).", default=False)


@dataclass(frozen=True)
class InfoOptions(Options):
    """What ``hbvs info`` was asked to do (see ``hbvs info --help``)."""

    input: str = option("An MCAP file (an hbvs teach, fit or run file, or any other), or - for stdin.", argument=True)
    json_output: bool = option("Print one JSON object instead of the text.", default=False, flags=("--json",))
