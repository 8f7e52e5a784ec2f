"""The run file: what ``hbvs repeat`` writes and ``hbvs report`` reads.

Topics:

=======================  ==============================  ==========================================
``/repeat/state``        ``hbvs.ControllerState``        every control step (errors, commands, dhat, V)
``/repeat/cmd_vel``      ``hbvs.VelocityCommand``        the command sent (after actuator limits)
``/repeat/events``       ``foxglove.Log``                target lost / back, saturation, faults, stop
``/ground_truth/pose``   ``foxglove.PoseInFrame``        true robot pose (``--sim``)
``/desired/pose``        ``foxglove.PoseInFrame``        taught pose at the same time (``--sim``)
``/camera/image``        ``foxglove.CompressedImage``    camera images (``--record-images``)
``/camera/annotations``  ``foxglove.ImageAnnotations``   detected (green) and desired (orange) points
``/camera/calibration``  ``foxglove.CameraCalibration``  the camera
=======================  ==============================  ==========================================

Metadata record ``hbvs``: ``file_kind = run``, version, ``mode`` (sim or replay), ``law``,
``gains``, ``settings`` (every option and the seed), ``d_true`` (m, when known) and
``condition35`` (from the fit).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import RecordingError
from .mcap_io import McapStream, read_metadata
from .messages import planar_pose_from_message
from .topics import COMMAND_TOPIC, DESIRED_POSE_TOPIC, EVENTS_TOPIC, STATE_TOPIC, TOPICS, TRUE_POSE_TOPIC

FILE_KIND = "run"

#: Per-step numeric fields of ``hbvs.ControllerState`` kept by :class:`RunData` (NaN for null).
STATE_FIELDS = (
    "t", "x_h1", "x_h2", "theta", "x_hd1", "x_hd2", "theta_d", "x_hd1_dot", "x_hd2_dot", "theta_d_dot",
    "e1", "e2", "ebar2", "e3", "v_c", "w_c", "v_law", "w_law", "dhat", "residual", "V",
    # The state filter's estimate and std (NaN without a filter, or in an older file).
    "theta_est", "x_h1_est", "x_h2_est", "theta_std", "x_h1_std", "x_h2_std", "noise_px",
)


@dataclass
class RunData:
    """A whole run as arrays (one row per control step).

    Attributes
    ----------
    name : str
    info : dict
        The ``hbvs`` metadata record (mode, law, gains, settings, d_true...).
    state : dict of ndarray
        :data:`STATE_FIELDS`, each shape (K,), NaN where the message had null.
    saturated, lost : ndarray of bool, shape (K,)
        ``lost`` holds through dropped frames: it is the state of the last frame that arrived.
    lost_reason : list of str
    true_pose, desired_pose : ndarray, shape (K, 3) or None
        (x, y, phi) at the step times (``--sim`` runs).
    events : list of (t, level, text)
    truncated : bool
        The file ended early (a crashed or killed run).
    dropped : ndarray of bool, shape (K,), or None
        Steps whose camera frame was dropped (``frame_dropped``; all False in files
        written before hbvs recorded it). ``None`` when not given (a run built in memory).
    """

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

    @property
    def steps(self) -> int:
        return int(self.state["t"].size)


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
    """Refuse metadata whose entries have types ``hbvs report`` cannot use, or that holds
    NaN or infinity (hbvs writes those as null; the report's JSON cannot hold them)."""
    for key, types in INFO_TYPES.items():
        value = info.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, types)):
            raise RecordingError(f"{name}: malformed hbvs metadata: {key} = {str(value)[:60]!r}")
    pending = list(info.values())
    while pending:
        value = pending.pop()
        if isinstance(value, dict):
            pending.extend(value.values())
        elif isinstance(value, list):
            pending.extend(value)
        elif isinstance(value, float) and not math.isfinite(value):
            raise RecordingError(f"{name}: malformed hbvs metadata: it holds NaN or infinity")


def _event(data: dict[str, Any], log_time: int, name: str) -> tuple[int, int, str]:
    """(log time, level, text) of a ``foxglove.Log`` message."""
    level = data.get("level", 0)
    if isinstance(level, bool) or not isinstance(level, int):
        raise RecordingError(f"{name}: malformed event message (level {str(level)[:40]!r} is not a whole number)")
    return log_time, level, str(data.get("message", ""))


def read_run(source: Any, name: str = "") -> RunData:
    """Read a run file (or ``-``) into :class:`RunData`.

    Raises
    ------
    RecordingError
        Not an MCAP file, not a run file, malformed messages, or no steps.
    """
    stream = McapStream(source, schemas=TOPICS[FILE_KIND], name=name)
    columns: dict[str, list[float]] = {key: [] for key in STATE_FIELDS}
    saturated: list[bool] = []
    lost: list[bool] = []
    reasons: list[str] = []
    dropped: list[bool] = []
    true_pose: dict[int, tuple[float, float, float]] = {}
    desired_pose: dict[int, tuple[float, float, float]] = {}
    step_times: list[int] = []
    events: list[tuple[int, int, str]] = []
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
        elif message.topic == TRUE_POSE_TOPIC:
            true_pose[message.log_time] = planar_pose_from_message(message.json(stream.name), stream.name)
        elif message.topic == DESIRED_POSE_TOPIC:
            desired_pose[message.log_time] = planar_pose_from_message(message.json(stream.name), stream.name)
        elif message.topic == EVENTS_TOPIC:
            events.append(_event(message.json(stream.name), message.log_time, stream.name))
    info = read_metadata(stream, "hbvs")
    if info.get("file_kind") != FILE_KIND:
        kind = info.get("file_kind")
        what = f"a {kind!r} file" if kind else "not an hbvs run file"
        raise NotARunFile(f"{stream.name}: {what}; hbvs report reads the output of hbvs repeat", kind if isinstance(kind, str) else None)
    _check_info(info, stream.name)
    if not step_times:
        raise RecordingError(f"{stream.name}: the run has no control steps")
    state = {key: np.array(values) for key, values in columns.items()}
    if not np.all(np.isfinite(state["t"])) or np.any(np.diff(state["t"]) < 0):
        raise RecordingError(f"{stream.name}: the step times are missing, not finite or go backwards")
    # Log times count from the file's time base (a fixed epoch, or a replayed recording's
    # stamps): events are placed on the steps' clock, t = 0 at the base.
    base_ns = step_times[0] - int(round(state["t"][0] * 1e9))
    events = [((log_time - base_ns) * 1e-9, level, text) for log_time, level, text in events]

    def aligned(poses: dict[int, tuple[float, float, float]]) -> np.ndarray | None:
        if not poses:
            return None
        rows = [poses.get(t) for t in step_times]
        if any(r is None for r in rows):
            return None
        return np.array(rows, dtype=float)

    return RunData(
        name=stream.name, info=info, state=state, saturated=np.array(saturated), lost=np.array(lost),
        lost_reason=reasons, true_pose=aligned(true_pose), desired_pose=aligned(desired_pose),
        events=events, truncated=stream.truncated, dropped=np.array(dropped, dtype=bool),
    )
