"""``hbvs repeat FIT --live``: the closed loop with a robot (docs/robot.md), each newest frame decided by the
:class:`~hbvs_cli.core.simulator.ServoStep` of ``--sim``. Zero commands go out on every way out, and only zeros
before the target is seen near its taught start view."""

from __future__ import annotations

import json
import math
import threading
import time
from collections import deque
from contextlib import ExitStack, suppress
from dataclasses import dataclass
from typing import IO, Any, Callable, Iterator, Protocol

import numpy as np

from ..core.camera_clock import CameraClock
from ..core.servo_loop import ServoInput, run_servo
from ..core.simulator import ServoStep
from ..errors import CommandConflictError, HbvsError, InputError, NotAtStartError, TargetLostError, UsageError
from ..io.calibration import load_calibration
from ..io.messages import LOG_ERROR, LOG_INFO, LOG_WARNING
from ..io.ros2_names import check_topic_names
from ..io.run_file import RunWriter
from ..io.sources.frame_source import LiveFrame
from ..io.topics import ROS_CMD_VEL_TOPIC
from ..settings.commands import SIM_FAULTS, RepeatOptions
from ..stop_signals import Terminated, raise_if_stopped

#: Consecutive frames with the target near its taught start view before the first non-zero command.
START_FRAMES = 5
#: How far from the taught start a live run may begin (m at the fit's depth estimate, deg).
START_TOLERANCE_M = 0.3
START_TOLERANCE_DEG = 15.0
#: Zero commands sent at each stop (more than one, for a late or lost subscriber).
ZERO_REPEATS = 3
#: A frame is "late" when its interval exceeds this many control periods.
LATE_FACTOR = 1.5
#: How long (s) a stale camera is polled at a time while the robot stands still.
STALE_POLL_S = 0.01
#: How often (s) the deadman looks at a zero command (a non-zero one it waits for to the moment).
DEADMAN_POLL_S = 0.05
#: How long (s) the command publisher waits, at the end, for its readers to acknowledge the last zero.
COMMAND_DELIVERY_S = 1.0
#: Steps the status line's frame rate and latency are taken over.
STATUS_WINDOW = 60
#: Largest relative difference between the given calibration and the fit's camera.
CALIBRATION_TOLERANCE = 0.02


def write_command(stream: IO[str] | None, t: float, v: float, w: float) -> None:
    """A command as a JSON line ``{"t", "v", "w"}`` (s, m/s, rad/s) on ``--cmd-out``'s stream."""
    if stream is not None:
        stream.write(json.dumps({"t": round(t, 9), "v": v, "w": w}) + "\n")
        stream.flush()


class CommandOut:
    """Where commands go: the robot's :class:`CommandSink` (or None) and/or a JSON-lines stream; zero on :meth:`stop`.
    ``stale_timeout_s``: a deadman thread replaces a non-zero command that stood this long (s) by zero, whatever the
    loop is doing (a slow frame, a source that hangs). :meth:`close` ends it."""

    def __init__(self, publisher: CommandSink | None, stream: IO[str] | None, dry_run: bool, stale_timeout_s: float) -> None:
        self._publisher = publisher
        self._stream = stream
        self.dry_run = dry_run
        #: ``time.monotonic()`` of the last command sent.
        self.sent_at = time.monotonic()
        #: The last command sent (m/s, rad/s), and its run time (s).
        self.last = (0.0, 0.0)
        self._t = 0.0
        self._lock = threading.RLock()  # the deadman stops while holding it
        self._closed = threading.Event()
        self._deadman = threading.Thread(target=self._watch, args=(stale_timeout_s,), name="hbvs-deadman", daemon=True)
        self._deadman.start()

    def send(self, t: float, v: float, w: float) -> None:
        if self.dry_run:
            v, w = 0.0, 0.0
        with self._lock:
            if self._publisher is not None:
                self._publisher.publish(v, w)
            write_command(self._stream, t, v, w)
            self.sent_at, self.last, self._t = time.monotonic(), (v, w), t

    def stop(self, t: float) -> None:
        """Zero, :data:`ZERO_REPEATS` times; a failing output does not keep the others from it."""
        with self._lock:
            for _ in range(ZERO_REPEATS):
                if self._publisher is not None:
                    with suppress(Exception):  # stopping must reach every output it can
                        self._publisher.publish(0.0, 0.0)
            with suppress(OSError, ValueError):
                write_command(self._stream, t, 0.0, 0.0)
            self.sent_at, self.last, self._t = time.monotonic(), (0.0, 0.0), t

    def _watch(self, stale_timeout_s: float) -> None:
        while not self._closed.is_set():
            with self._lock:
                now = time.monotonic()
                due = self.sent_at + stale_timeout_s if self.last != (0.0, 0.0) else None
                if due is not None and now >= due:
                    self.stop(self._t + (now - self.sent_at))
                    continue
            self._closed.wait(min(due - now, DEADMAN_POLL_S) if due is not None else DEADMAN_POLL_S)

    def close(self) -> None:
        """End the deadman thread (after the last :meth:`stop`)."""
        self._closed.set()
        self._deadman.join()

    def other_commanders(self) -> int:
        """Other writers on the command topic now (0 without a ROS 2 topic)."""
        return self._publisher.other_publishers() if self._publisher is not None else 0

    def check_one_commander(self) -> None:
        """:class:`CommandConflictError` when another node commanded the robot since the last check."""
        if self._publisher is not None and self._publisher.foreign_commands():
            raise CommandConflictError(
                f"another node published on {self._publisher.topic} while hbvs was driving: zero sent, hbvs stopped "
                "(one commander at a time; stop the other node, e.g. a teleop, and start again)"
            )


def stop_reason(error: BaseException) -> str:
    """Why a live run ended early, in the run file's words."""
    if isinstance(error, KeyboardInterrupt):
        return "interrupted (SIGINT, Ctrl-C)"
    if isinstance(error, Terminated):
        return "terminated (SIGTERM)"
    if isinstance(error, HbvsError):
        return str(error)
    return f"internal error ({type(error).__name__})"


def check_live_options(options: RepeatOptions, lost_timeout: float) -> None:
    """Refuse options a live run cannot honour (``lost_timeout``: the resolved --lost-timeout, s)."""
    if (options.camera is None) == (options.ros2_image is None):
        raise UsageError("--live needs one frame source: --camera DEV or --ros2-image TOPIC")
    check_topic_names((options.ros2_image, "--ros2-image"), (options.ros2_cmd, "--ros2-cmd"))
    if options.stale_timeout > lost_timeout:
        raise UsageError(f"--stale-timeout {options.stale_timeout:g} s is longer than --lost-timeout {lost_timeout:g} s: the "
                         "robot would stop for a lost camera before it stopped for a stale one")
    for name in (*SIM_FAULTS, "record_images", "depth"):
        value = getattr(options, name)
        if value not in (None, False, 0.0, []):
            raise UsageError(f"--{name.replace('_', '-')} is for --sim; a live run's faults are real")


class LiveSource(Protocol):
    """A robot's camera: the newest frame not returned yet, waiting at most ``timeout_s`` (s), else None (a source
    that can end, as a video file, says so with an ``ended`` attribute)."""

    def latest(self, timeout_s: float) -> LiveFrame | None: ...


class CommandSink(Protocol):
    """A robot's command input: ``publish(v, w)`` (m/s, rad/s; zeros stop it), ``topic`` its name, and the other
    commanders it sees: ``other_publishers()`` now, ``foreign_commands()`` commands they sent since the last call."""

    topic: str

    def publish(self, v: float, w: float) -> None: ...
    def other_publishers(self) -> int: ...
    def foreign_commands(self) -> int: ...


@dataclass
class RobotLink:
    """An opened robot interface: its command sink (None: ``--cmd-out`` only), what opens its camera (the source
    and the intrinsics, once the run file is open: a camera that cannot be used is recorded), the camera's name."""

    commands: CommandSink | None
    open_camera: Callable[[], tuple[LiveSource, Any]]
    source_name: str


@dataclass(frozen=True)
class RobotInterface:
    """A way to a robot: ``chosen(options)`` whether the options ask for it; ``open(options, stack, lost_timeout_s,
    info)`` its :class:`RobotLink` (``stack`` closes what it opens, ``info`` tells the user)."""

    name: str
    chosen: Callable[[RepeatOptions], bool]
    open: Callable[[RepeatOptions, ExitStack, float, Callable[[str], None]], RobotLink]


#: The robot interfaces ``repeat --live`` knows: the last registered one the options choose is used (one frame
#: source is given: :func:`check_live_options`).
ROBOT_INTERFACES: list[RobotInterface] = []
register_robot_interface = ROBOT_INTERFACES.append


def robot_interface(options: RepeatOptions) -> RobotInterface:
    return next(interface for interface in reversed(ROBOT_INTERFACES) if interface.chosen(options))


def _ros2_commands(options: RepeatOptions, stack: ExitStack, info: Callable[[str], None]) -> tuple[Any, CommandSink | None]:
    """A ROS 2 node (None without a ROS 2 topic) and the publisher on --ros2-cmd, else /cmd_vel unless only --cmd-out;
    when ``stack`` closes (after the last zero), the publisher waits up to :data:`COMMAND_DELIVERY_S` for its readers."""
    topic = options.ros2_cmd if options.ros2_cmd is not None else (
        None if options.cmd_out is not None and options.ros2_image is None else ROS_CMD_VEL_TOPIC)
    if options.ros2_image is None and topic is None:
        return None, None
    from ..io import ros2_dds as dds  # lazy: an optional extra
    from ..io.dds_discovery import dds_settings
    from ..io.ros2_live import CommandPublisher

    info(f"repeat --live: {dds_settings().description}")
    node = dds.Ros2Node()
    if topic is None:
        return node, None
    commands = CommandPublisher(node, topic, stamped=options.cmd_type == "twist-stamped")
    stack.callback(commands.wait_delivered, COMMAND_DELIVERY_S)
    return node, commands


def _open_camera(options: RepeatOptions, stack: ExitStack, lost_timeout: float, info: Callable[[str], None]) -> RobotLink:
    """``--camera``: frames from OpenCV (an index, /dev/videoN, RTSP, HTTP such as ``robot-sim --mjpeg``'s, a video file)."""
    if options.calibration is None:
        raise UsageError("--camera needs --calibration FILE (the camera's intrinsics)")
    from ..io.sources.live_camera import LatestCameraFrame

    return RobotLink(_ros2_commands(options, stack, info)[1], lambda: (
        stack.enter_context(LatestCameraFrame(options.camera)), load_calibration(options.calibration)), options.camera)


def _open_ros2(options: RepeatOptions, stack: ExitStack, lost_timeout: float, info: Callable[[str], None]) -> RobotLink:
    """``--ros2-image``: frames and (without --calibration) CameraInfo, awaited for the discovery time or ``lost_timeout`` (s)."""
    from ..io import ros2_dds as dds
    from ..io.ros2_live import DISCOVERY_TIMEOUT_S, LatestImage, wait_camera_info

    node, commands = _ros2_commands(options, stack, info)
    timeout_s = max(lost_timeout, DISCOVERY_TIMEOUT_S)
    return RobotLink(commands, lambda: (LatestImage(node, options.ros2_image, timeout_s), (
        load_calibration(options.calibration) if options.calibration is not None
        else wait_camera_info(node, dds.camera_info_topic(options.ros2_image), timeout_s))), options.ros2_image)


register_robot_interface(RobotInterface("camera", lambda options: options.camera is not None, _open_camera))
register_robot_interface(RobotInterface("ros2", lambda options: options.ros2_image is not None, _open_ros2))


def check_camera(camera: Any, fit_camera: Any, what: str) -> None:
    """The live camera must be the fit's: same size, intrinsics within 2 %."""
    if (camera.width, camera.height) != (fit_camera.width, fit_camera.height):
        raise InputError(f"{what}: {camera.width}x{camera.height}, the fit's camera is {fit_camera.width}x{fit_camera.height}")
    for name in ("fx", "fy", "cx", "cy"):
        live, taught = float(getattr(camera, name)), float(getattr(fit_camera, name))
        if abs(live - taught) > CALIBRATION_TOLERANCE * max(abs(taught), 1.0):
            raise InputError(f"{what}: {name} {live:g} disagrees with the fit's camera ({taught:g})")


@dataclass
class TargetSight:
    """What a repeat sees of one target through its fit: a frame's observation (14), and the desired signals
    (Remark 1) at run time t (s). A route's (:class:`~.repeat_route.RouteSight`) has the same methods."""

    detector: Any
    estimator: Any
    trajectory: Any

    def __post_init__(self) -> None:
        self.t_start, self.t_end = self.trajectory.t_start, self.trajectory.t_end
        #: Whether frames are decoded in colour (only dots seen in colour use it).
        self.colour = self.detector.spec.contrast == "colour"

    def observe(self, image: np.ndarray, t: float) -> Any:
        return self.estimator.from_pixels(self.detector.detect(image))

    def evaluate(self, t: float) -> Any:
        return self.trajectory.evaluate(t)


def measure(frame: Any, sight: Any, model: Any, t: float) -> Any:
    """The observation of one live frame at run time ``t`` (s) (``sight``: a :class:`TargetSight`'s methods)."""
    image = frame.image
    height, width = image.shape[:2]
    if (width, height) != (model.camera.width, model.camera.height):
        raise InputError(f"a live frame is {width}x{height}, the fit's camera {model.camera.width}x{model.camera.height}")
    return sight.observe(image, t)


class LostWatch:
    """--lost-timeout in a run's time: :meth:`stops` once the target was lost longer (each step held ``dt`` s),
    logging it on ``log``; :attr:`stopped` then says why the run stopped (else None)."""

    def __init__(self, lost_timeout: float, log: Any) -> None:
        self.lost_timeout, self.log = lost_timeout, log
        self.lost_for = 0.0
        self.stopped: str | None = None

    def stops(self, record: Any, dt: float) -> bool:
        self.lost_for = self.lost_for + dt if record.lost else 0.0
        if self.lost_for <= self.lost_timeout:
            return False
        self.log.event(record.t, LOG_ERROR, f"target lost for more than {self.lost_timeout:g} s: run stopped")
        self.stopped = f"the target was lost for more than --lost-timeout {self.lost_timeout:g} s (at t = {record.t:.2f} s)"
        return True


class LiveStats:
    """What the status line shows of the last :data:`STATUS_WINDOW` steps: frame rate, latency, drops."""

    def __init__(self) -> None:
        self.arrivals: deque[float] = deque(maxlen=STATUS_WINDOW)
        self.latencies: deque[float] = deque(maxlen=STATUS_WINDOW)
        self.dropped = 0

    def add(self, arrival: float, latency: float, skipped: int) -> None:
        self.arrivals.append(arrival)
        self.latencies.append(latency)
        self.dropped += skipped


def status_text(t: float, duration: float, record: Any, stats: LiveStats) -> str:
    """One line of at most 80 columns: run time, e1, e2, e3 (19), dhat, frame rate, p95 latency, frames dropped."""
    errors = record.output.errors if record.output is not None else None
    shown = (f"e {float(errors.e1):+.3f} {float(errors.e2):+.3f} {math.degrees(float(errors.e3)):+.2f}°"
             if errors is not None else f"{'target lost':<22}")
    arrivals = stats.arrivals
    rate = (len(arrivals) - 1) / (arrivals[-1] - arrivals[0]) if len(arrivals) >= 2 and arrivals[-1] > arrivals[0] else math.nan
    p95 = float(np.percentile(stats.latencies, 95)) if stats.latencies else math.nan
    return (f"t {t:.1f}/{duration:.0f}s  {shown}  dhat {record.dhat:.2f}m  {rate:.0f}Hz  "
            f"p95 {1e3 * p95:.0f}ms  drop {stats.dropped}")


@dataclass
class LiveLoop:
    """The loop of ``repeat --live``: frames in, commands out, the run file written. Only frames the camera clock
    admits are used, and a command never outlives its measurement by more than ``--stale-timeout``."""

    source: LiveSource
    #: What is seen and should be seen (:class:`TargetSight`, or a route's).
    sight: Any
    model: Any
    servo: ServoStep
    out: CommandOut
    run: RunWriter
    log: Any
    tally: Any
    options: RepeatOptions
    settings: Any
    #: Where the status line goes (a terminal), or None.
    status: Callable[[str], None] | None = None
    #: Where a warning goes (stderr).
    warn: Callable[[str], None] = lambda text: None
    #: Run time of the last step (s).
    t: float = 0.0
    #: Why the run stopped early (None: it ended with the trajectory).
    stopped: str | None = None

    def __post_init__(self) -> None:
        #: The control period and the taught trajectory's duration (s).
        self.period = 1.0 / self.settings.rate
        self.duration = self.sight.t_end - self.sight.t_start
        self.clock = CameraClock(self.period)
        self.stats = LiveStats()
        #: ``time.monotonic()`` when the command of the last used frame went out.
        self.used_at = time.monotonic()
        #: The frame being acted on, its interval from the one before (s, None for the first), the
        #: period its command is held for (s), and its latency from arrival to command (s).
        self.frame: Any = None
        self.interval: float | None = None
        self.dt = 0.0
        self.latency = 0.0

    def now(self) -> float:
        """The run time (s) now: the last step's, plus the time since its command went out."""
        return self.t + (time.monotonic() - self.used_at)

    def _usable(self, frame: Any) -> bool:
        """A frame came: is it newer than the last used, on this host's clock? (CameraClockError if its stamp jumped.)"""
        return frame is not None and self.clock.admit(frame.stamp, frame.arrival)

    def _no_frame_reason(self, seconds: float) -> str:
        if self.clock.refused:
            return (f"no usable camera frame for {seconds:.2f} s: {self.clock.refused} frames came with stamps not newer than "
                    "the last one used (the camera's clock froze or stepped back)")
        return f"no camera frame for {seconds:.2f} s (the camera or its link stopped)"

    def wait_for_start(self) -> None:
        """Send zeros until the target is seen near its taught start view in :data:`START_FRAMES` frames in a row."""
        desired = self.sight.evaluate(0.0)
        lost_timeout = self.settings.lost_timeout
        near = far = 0
        waited_since = seen_at = time.monotonic()
        while near < START_FRAMES:
            raise_if_stopped()
            self.out.check_one_commander()
            frame = self.source.latest(self.options.stale_timeout)
            if not self._usable(frame):
                if time.monotonic() - waited_since > lost_timeout:
                    raise TargetLostError(self._no_frame_reason(time.monotonic() - waited_since) + " before the start (--lost-timeout)")
                continue
            waited_since = time.monotonic()
            observation = measure(frame, self.sight, self.model, 0.0)
            self.out.send(0.0, 0.0, 0.0)
            if observation.status != "ok" or observation.measurement is None:
                near = far = 0
                if time.monotonic() - seen_at > lost_timeout:
                    raise NotAtStartError(
                        f"the target is not in view ({observation.status} for {lost_timeout:g} s, --lost-timeout): "
                        "the robot is not at the taught start, or its camera sees something else"
                    )
                continue
            seen_at = time.monotonic()
            m = observation.measurement
            # x_h is x_f / d* (21): at the fit's depth estimate, metres.
            distance = math.hypot(float(m.x_h1) - float(desired.x_hd1), float(m.x_h2) - float(desired.x_hd2)) * self.settings.dhat0
            heading = math.degrees(abs(math.remainder(float(m.theta) - float(desired.theta_d), 2 * math.pi)))
            if distance <= START_TOLERANCE_M and heading <= START_TOLERANCE_DEG:
                near, far = near + 1, 0
            else:
                near, far = 0, far + 1
                if far >= START_FRAMES:
                    raise NotAtStartError(
                        f"the robot seems {distance:.2f} m and {heading:.1f} deg from the taught start (at most "
                        f"{START_TOLERANCE_M:g} m and {START_TOLERANCE_DEG:g} deg); put it there and start again"
                    )
        self.used_at = time.monotonic()
        # By now discovery has long met the camera's node, and any other on the command topic.
        others = self.out.other_commanders()
        if others:
            text = f"{others} other node(s) can publish on the command topic; hbvs stops if one of them sends a command"
            self.log.event(0.0, LOG_WARNING, text)
            self.warn(text)

    def __iter__(self) -> Iterator[ServoInput]:
        """The loop's inputs (a ServoSource): each newest usable frame, measured, until the end or a stop."""
        period, duration = self.period, self.duration
        first_stamp: float | None = None
        previous_stamp: float | None = None
        while True:
            raise_if_stopped()
            self.out.check_one_commander()
            frame = self._next_frame()
            if frame is None:
                return  # the camera is gone (self.stopped says so)
            if first_stamp is None:
                first_stamp = frame.stamp
                self.run.start(int(round(first_stamp * 1e9)))
            # The camera clock admitted the stamp: it is newer, and not ahead of this host's clock.
            t = frame.stamp - first_stamp
            if t >= duration:
                self.t = t
                self.run.event(t, LOG_INFO, "end of the taught trajectory: stopped")
                return
            self.frame, self.interval = frame, (frame.stamp - previous_stamp if previous_stamp is not None else None)
            # The command is held until the next frame: about one frame interval.
            self.dt = min(max(self.interval if self.interval is not None else period, 0.2 * period), 5.0 * period)
            observation = measure(frame, self.sight, self.model, t)
            previous_stamp, self.t = frame.stamp, t
            yield ServoInput(t, self.dt, observation, self.sight.evaluate(t), _NO_POSE)

    def act(self, record: Any) -> None:
        """Send the command (a lost target's is zero: :attr:`ServoStep.stop_when_lost`)."""
        self.out.send(record.t, record.v_c, record.w_c)
        self.used_at = self.out.sent_at
        self.latency = time.monotonic() - self.frame.arrival

    def drive(self) -> None:
        """Measure, decide and send each newest usable frame until the end or a stop (:attr:`stopped` says why)."""
        period, duration = self.period, self.duration
        lost = LostWatch(self.settings.lost_timeout, self.log)
        for record in run_servo(self, self.servo):
            frame, t = self.frame, record.t
            self.log.step(record)
            self.run.timing(t, frame.stamp, self.latency, self.interval, frame.skipped,
                            self.interval is not None and self.interval > LATE_FACTOR * period, self.options.dry_run)
            self.tally.add(record)
            self.stats.add(frame.arrival, self.latency, frame.skipped)
            if self.status is not None:
                self.status(status_text(t, duration, record, self.stats))
            if lost.stops(record, self.dt):
                self.stopped = lost.stopped
                return

    def _next_frame(self) -> Any:
        """The next usable frame; zeros once none came for --stale-timeout after the last used one; None
        (:attr:`stopped` set) after --lost-timeout or the source's end."""
        stale_timeout = self.options.stale_timeout
        stale = False
        while True:
            wait = stale_timeout - (time.monotonic() - self.used_at)
            # Once stale, still polled briefly: a camera that comes back is driven from again.
            frame = self.source.latest(wait if wait > 0 and not stale else STALE_POLL_S)
            if self._usable(frame):
                if stale:
                    self.run.event(self.t, LOG_INFO, "camera frames back")
                return frame
            silent = time.monotonic() - self.used_at
            if silent < stale_timeout:
                continue
            if not stale:
                self.out.stop(self.t)
                self.servo.previous = (0.0, 0.0)
                self.run.event(self.t, LOG_WARNING, f"no usable camera frame for {stale_timeout:g} s (--stale-timeout): stopped")
                stale = True
            if silent > self.settings.lost_timeout or getattr(self.source, "ended", False):
                self.stopped = self._no_frame_reason(silent)
                self.run.event(self.t, LOG_ERROR, self.stopped + ": run stopped")
                return None


#: A live run has no ground truth: the pose recorded with each step.
_NO_POSE = np.full(3, np.nan)
