"""The run file: what ``hbvs repeat`` writes and ``hbvs report`` reads (topics in
:data:`~.topics.TOPICS` ``["run"]`` and docs/files.md)."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from ..core.camera import CameraIntrinsics
from ..errors import RecordingError
from .calibration import calibration_to_foxglove
from .file_info import list_of
from .images import write_compressed_image
from .mcap import McapStream, McapWriter, read_metadata, seconds_to_ns, time_message
from .messages import CAMERA_FRAME, LOG_ERROR, annotations_message, log_message, planar_pose_from_message, pose_message, velocity_message
from .topics import (
    ANNOTATIONS_TOPIC, CALIBRATION_TOPIC, COMMAND_TOPIC, DESIRED_POSE_TOPIC, EVENTS_TOPIC, IMAGE_TOPIC, STATE_TOPIC,
    ROUTE_SWITCHES_METADATA, STOPPED_METADATA, TIMING_TOPIC, TOPICS, TRUE_POSE_TOPIC,
)

FILE_KIND = "run"
RUN_SCHEMAS = TOPICS[FILE_KIND]

#: Per-step numeric fields of ``hbvs.ControllerState`` kept by :class:`RunData` (NaN for null).
STATE_FIELDS = (
    "t", "x_h1", "x_h2", "theta", "x_hd1", "x_hd2", "theta_d", "x_hd1_dot", "x_hd2_dot", "theta_d_dot",
    "e1", "e2", "ebar2", "e3", "v_c", "w_c", "v_law", "w_law", "dhat", "residual", "V",
    "theta_est", "x_h1_est", "x_h2_est", "theta_std", "x_h1_std", "x_h2_std", "noise_px",
)

#: Per-step fields of ``hbvs.LoopTiming`` (live runs) kept by :class:`RunData`.
TIMING_FIELDS = ("t", "frame_stamp", "latency_s", "frame_interval_s", "dropped", "late")


@dataclass
class RunData:
    """A whole run as arrays over its K control steps: ``state`` maps :data:`STATE_FIELDS` to (K,)
    (NaN for null); ``saturated``, ``lost``, ``dropped`` (K,) bool; ``true_pose`` and ``desired_pose``
    (K, 3) (x, y, phi) in m, m, rad for ``--sim`` runs, ``camera_height`` (m) the z of the first true pose;
    ``timing`` a live run's :data:`TIMING_FIELDS`."""

    name: str
    info: dict[str, Any]
    state: dict[str, np.ndarray]
    saturated: np.ndarray
    lost: np.ndarray
    lost_reason: list[str]
    true_pose: np.ndarray | None
    desired_pose: np.ndarray | None
    events: list[tuple[float, int, str]] = field(default_factory=list)
    truncated: bool = False
    dropped: np.ndarray | None = None
    timing: dict[str, np.ndarray] | None = None
    camera_height: float | None = None

    @property
    def steps(self) -> int:
        return int(self.state["t"].size)

    @property
    def duration_s(self) -> float:
        return float(self.state["t"][-1] - self.state["t"][0])

    def has_poses(self) -> bool:
        return self.true_pose is not None and self.desired_pose is not None


#: Metadata entries ``hbvs report`` reads, and the types they must have when present.
INFO_TYPES: dict[str, tuple[type, ...]] = {
    "mode": (str,), "law": (str,), "settings": (dict,), "gains": (dict,), "condition35": (dict,),
    "d_true": (int, float), "dhat0": (int, float), "fit_frames": (dict,),
}


class NotARunFile(RecordingError):
    """A readable hbvs file of another kind (``kind``: ``"fit"``, ``"teach"``, or None)."""

    def __init__(self, message: str, kind: str | None) -> None:
        super().__init__(message)
        self.kind = kind


def _number(value: Any) -> float:
    if value is None:
        return float("nan")
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TypeError(f"expected a number, got {value!r}")
    return float(value)


def _check_info(info: dict[str, Any], name: str) -> None:
    """Refuse metadata of types ``hbvs report`` cannot use, or holding NaN or infinity."""
    for key, types in INFO_TYPES.items():
        value = info.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, types)):
            raise RecordingError(f"{name}: malformed hbvs metadata: {key} = {str(value)[:60]!r}")
    try:
        json.dumps(info, allow_nan=False)  # decoded JSON throughout: only NaN or infinity is refused
    except ValueError:
        raise RecordingError(f"{name}: malformed hbvs metadata: it holds NaN or infinity") from None


def read_run(source: Any, name: str = "") -> RunData:
    """Read a run file (or ``-``) into :class:`RunData`; :class:`RecordingError` if it is not one."""
    stream = McapStream(source, schemas=TOPICS[FILE_KIND], name=name)
    columns: dict[str, list[float]] = {key: [] for key in STATE_FIELDS}
    saturated: list[bool] = []
    lost: list[bool] = []
    reasons: list[str] = []
    dropped: list[bool] = []
    poses: dict[str, dict[int, tuple[float, float, float]]] = {TRUE_POSE_TOPIC: {}, DESIRED_POSE_TOPIC: {}}
    step_times: list[int] = []
    events: list[tuple[int, int, str]] = []
    timing: dict[str, list[float]] = {key: [] for key in TIMING_FIELDS}
    height: float | None = None
    for message in stream:
        if message.topic == STATE_TOPIC:
            data = message.json(stream.name)
            try:
                for key in STATE_FIELDS:
                    columns[key].append(_number(data.get(key)))
                saturated.append(bool(data["saturated"]))
                lost.append(bool(data["target_lost"]))
                reasons.append(str(data.get("lost_reason", "")))
                dropped.append(bool(data.get("frame_dropped", False)))
            except (KeyError, TypeError, ValueError) as exc:
                raise RecordingError(f"{stream.name}: malformed controller state message ({exc})") from None
            step_times.append(message.log_time)
        elif message.topic in poses:
            pose = message.foxglove(stream.name)
            poses[message.topic][message.log_time] = planar_pose_from_message(pose, stream.name)
            if message.topic == TRUE_POSE_TOPIC and height is None:
                height = float(pose.pose.position.z)
        elif message.topic == EVENTS_TOPIC:
            log = message.foxglove(stream.name)
            events.append((message.log_time, int(log.level), log.message))
        elif message.topic == TIMING_TOPIC:
            data = message.json(stream.name)
            try:
                for key in TIMING_FIELDS:
                    value = data.get(key)
                    timing[key].append(float(value) if isinstance(value, bool) else _number(value))
            except (TypeError, ValueError) as exc:
                raise RecordingError(f"{stream.name}: malformed loop timing message ({exc})") from None
    info = read_metadata(stream, "hbvs")
    if info.get("file_kind") != FILE_KIND:
        kind = info.get("file_kind")
        what = f"a {kind!r} file" if kind else "not an hbvs run file"
        raise NotARunFile(f"{stream.name}: {what}; hbvs report reads the output of hbvs repeat", kind if isinstance(kind, str) else None)
    made = read_metadata(stream, ROUTE_SWITCHES_METADATA).get("switch_times")
    if made is not None and list_of(made) is None:
        raise RecordingError(f"{stream.name}: malformed hbvs metadata: {ROUTE_SWITCHES_METADATA} = {str(made)[:60]!r}")
    if made is not None and isinstance(info.get("route"), dict):
        info["route"] = {**info["route"], "planned_switch_times": info["route"].get("switch_times"), "switch_times": made}
    _check_info(info, stream.name)
    if not step_times:
        stopped = read_metadata(stream, STOPPED_METADATA).get("reason")
        raise RecordingError(f"{stream.name}: the run has no control steps" + (f"; it stopped before its first: {stopped}" if stopped else ""))
    state = {key: np.array(values) for key, values in columns.items()}
    if not np.all(np.isfinite(state["t"])) or np.any(np.diff(state["t"]) < 0):
        raise RecordingError(f"{stream.name}: the step times are missing, not finite or go backwards")
    # Events placed on the steps' clock (log times count from the file's time base).
    base_ns = step_times[0] - int(round(state["t"][0] * 1e9))
    events = [((log_time - base_ns) * 1e-9, level, text) for log_time, level, text in events]

    def aligned(topic: str) -> np.ndarray | None:
        rows = [poses[topic].get(t) for t in step_times]
        return np.array(rows, dtype=float) if poses[topic] and all(row is not None for row in rows) else None

    return RunData(
        name=stream.name, info=info, state=state, saturated=np.array(saturated), lost=np.array(lost),
        lost_reason=reasons, true_pose=aligned(TRUE_POSE_TOPIC), desired_pose=aligned(DESIRED_POSE_TOPIC),
        events=events, truncated=stream.truncated, dropped=np.array(dropped, dtype=bool),
        timing={key: np.array(values, dtype=float) for key, values in timing.items()} if timing["t"] else None,
        camera_height=height,
    )


class RunWriter:
    """Writes a run file from plain values, every message stamped ``base_ns`` plus its run time
    ``t`` (s); ``base_ns`` None when only the first frame gives it (call :meth:`start` then)."""

    def __init__(self, writer: McapWriter, info: dict[str, Any], camera: CameraIntrinsics, base_ns: int | None = 0) -> None:
        self.writer = writer
        self.camera = camera
        self.base_ns = 0
        self._started = False
        writer.metadata("hbvs", info)
        if base_ns is not None:
            self.start(base_ns)

    def start(self, base_ns: int) -> None:
        """Set the log time of ``t = 0`` and write the calibration there (once)."""
        if self._started:
            return
        self.base_ns = int(base_ns)
        self._started = True
        self.writer.write(CALIBRATION_TOPIC, RUN_SCHEMAS[CALIBRATION_TOPIC], self.base_ns,
                          calibration_to_foxglove(self.camera, CAMERA_FRAME, self.base_ns))

    def log_time_ns(self, t: float) -> int:
        """The log time (ns) of run time ``t`` (s)."""
        return self.base_ns + seconds_to_ns(t)

    def event(self, t: float, level: int, text: str) -> None:
        """A ``foxglove.Log`` line on the events topic (``level``: one of messages.LOG_*)."""
        ns = self.log_time_ns(t)
        self.writer.write(EVENTS_TOPIC, RUN_SCHEMAS[EVENTS_TOPIC], ns, log_message(ns, level, text))

    def state(self, t: float, values: dict[str, Any]) -> None:
        """One ``hbvs.ControllerState``: ``t`` and ``values`` (NaN and infinity written as null)."""
        ns = self.log_time_ns(t)
        self._write_flat(STATE_TOPIC, ns, {"timestamp": time_message(ns), "t": t, **values})

    def command(self, t: float, v: float, w: float, saturated: bool) -> None:
        """The command sent (m/s, rad/s), after the actuator limits."""
        ns = self.log_time_ns(t)
        self._write_flat(COMMAND_TOPIC, ns, velocity_message(time_message(ns), v, w, saturated), clean=False)

    def timing(self, t: float, frame_stamp: float, latency_s: float, frame_interval_s: float | None, dropped: int,
               late: bool, dry_run: bool) -> None:
        """One step's timing in a live run (``hbvs.LoopTiming``; times in s)."""
        ns = self.log_time_ns(t)
        self._write_flat(TIMING_TOPIC, ns, {
            "timestamp": time_message(ns), "t": t, "frame_stamp": frame_stamp, "latency_s": latency_s,
            "frame_interval_s": frame_interval_s, "dropped": int(dropped), "late": bool(late), "dry_run": bool(dry_run),
        })

    def stopped(self, t: float, reason: str) -> None:
        """The run stopped before its end at ``t`` (s): an error event and the ``hbvs.stopped`` metadata
        record with ``reason`` (``hbvs report`` and ``hbvs info`` show them)."""
        self.event(t, LOG_ERROR, f"{reason}: zero sent, run stopped")
        self.writer.metadata(STOPPED_METADATA, {"t": t, "reason": reason})

    def route_switches(self, times: Sequence[float]) -> None:
        """The switches a route's repeat made so far, at run times ``times`` (s): written again at
        each, so a run stopped half way keeps those it made."""
        self.writer.metadata(ROUTE_SWITCHES_METADATA, {"switch_times": [float(t) for t in times]})

    def poses(self, t: float, true_pose: Sequence[float], desired_pose: Sequence[float], height: float) -> None:
        """The true and taught poses ``(x, y, phi)`` (m, m, rad) at ``t``; camera ``height`` (m)."""
        ns = self.log_time_ns(t)
        self.writer.write(TRUE_POSE_TOPIC, RUN_SCHEMAS[TRUE_POSE_TOPIC], ns, pose_message(ns, true_pose, height))
        self.writer.write(DESIRED_POSE_TOPIC, RUN_SCHEMAS[DESIRED_POSE_TOPIC], ns, pose_message(ns, desired_pose, height))

    def image(self, t: float, data: bytes, image_format: str, detected: np.ndarray | None, desired: np.ndarray | None,
              label: str) -> None:
        """A camera image (encoded ``data``) and its annotations: detected and desired pixels."""
        ns = self.log_time_ns(t)
        write_compressed_image(self.writer, IMAGE_TOPIC, ns, data, image_format, CAMERA_FRAME)
        self.writer.write(ANNOTATIONS_TOPIC, RUN_SCHEMAS[ANNOTATIONS_TOPIC], ns, annotations_message(ns, detected, desired, label))

    def _write_flat(self, topic: str, ns: int, message: dict[str, Any], clean: bool = True) -> None:
        """Write plain values without the general JSON cleaning pass (several messages a control period);
        ``clean=False`` when no value can be NaN."""
        if clean:
            for key, value in message.items():
                if isinstance(value, float) and not math.isfinite(value):
                    message[key] = None
        data = json.dumps(message, separators=(",", ":"), allow_nan=False).encode("utf-8")
        self.writer.write_encoded(topic, RUN_SCHEMAS[topic], ns, data)

