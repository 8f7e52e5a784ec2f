"""The fit file: what ``hbvs fit`` writes and ``hbvs repeat`` reads (topics in
:data:`~.topics.TOPICS` ``["fit"]`` and docs/files.md)."""

from __future__ import annotations

import base64
import binascii
import json
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import __version__
from ..core.camera import CameraIntrinsics, camera_description
from ..core.control_settings import GAIN_NAMES, ControllerGains
from ..core.desired import DesiredFit
from ..core.fit_model import MAX_TARGET_POINTS, FitModel, TaughtPath
from ..core.trajectory import SplineTrajectory
from ..errors import HbvsError, RecordingError
from .calibration import intrinsics_from_values
from .images import read_compressed_image
from .mcap import McapStream, read_metadata, time_message
from .topics import MODEL_TOPIC, RAW_DESIRED_TOPIC, REFERENCE_IMAGE_TOPIC, SMOOTH_DESIRED_TOPIC, TEMPLATE_IMAGE_TOPIC, TOPICS
from .teach_file import PARSE_ERRORS, render_settings_problem, world_description

FILE_KIND = "fit"
FORMAT_VERSION = 1


def camera_from_dict(data: dict[str, Any]) -> CameraIntrinsics:
    """The inverse of :func:`~hbvs_cli.core.camera.camera_description`, checked as a calibration file."""
    K = [data["fx"], 0.0, data["cx"], 0.0, data["fy"], data["cy"], 0.0, 0.0, 1.0]
    return intrinsics_from_values(
        K, data["width"], data["height"], str(data.get("distortion_model", "none")), data.get("distortion", ()), "camera",
    )


def _positive_number(value: Any, what: str, optional: bool = False) -> float | None:
    """``value`` as a finite positive float (None allowed when ``optional``); ValueError otherwise."""
    if value is None and optional:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 < value < math.inf:
        raise ValueError(f"{what} must be a positive number, got {value!r}")
    return float(value)


def _check_detector(detector: Any, kind: str, points: int) -> dict[str, Any]:
    """The recorded detector description, checked for what repeat reads from it."""
    if not isinstance(detector, dict):
        raise ValueError("detector must be a mapping")
    if detector.get("kind", kind) != kind:
        raise ValueError(f"detector kind {detector.get('kind')!r} differs from the target kind {kind!r}")
    for key in ("n_points", "marker_id"):
        value = detector.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 1100):
            raise ValueError(f"detector {key} must be a small whole number, got {value!r}")
    ids = detector.get("marker_ids")
    if ids is not None and (not isinstance(ids, list) or len(ids) > MAX_TARGET_POINTS // 4
                            or not all(isinstance(i, int) and not isinstance(i, bool) and 0 <= i <= 1100 for i in ids)):
        raise ValueError(f"detector marker_ids must be a list of small whole numbers, got {ids!r}")
    for key in ("marker_dict", "polarity", "contrast"):
        if detector.get(key) is not None and not isinstance(detector.get(key), str):
            raise ValueError(f"detector {key} must be text")
    board = detector.get("board")
    # A chessboard's board is its inner corners per row and rows; a ChArUco board's, its squares.
    inner = 1 if kind == "charuco" else 0
    if board is not None and (not isinstance(board, list) or len(board) != 2 or not all(isinstance(n, int) and not isinstance(n, bool) and 3 <= n <= 100 for n in board)
                              or (board[0] - inner) * (board[1] - inner) != points):
        what = "squares across and down" if inner else "corners per row, rows"
        raise ValueError(f"detector board must be [{what}] of the {points} points, got {board!r}")
    for key in ("template_pixels", "initial_pixels"):
        value = detector.get(key)
        if value is None:
            continue
        array = np.asarray(value, dtype=float)
        if array.ndim != 2 or array.shape[1] != 2 or array.shape[0] > MAX_TARGET_POINTS:
            raise ValueError(f"detector {key} must be rows of (u, v) pixels")
        if key == "initial_pixels" and array.shape[0] != points:
            raise ValueError(f"detector initial_pixels has {array.shape[0]} points, the reference {points}")
    return dict(detector)


def taught_path_to_dict(path: TaughtPath) -> dict[str, Any]:
    """The ``taught_path`` object of a fit model: per-frame arrays as base64 float64 (compact)."""
    return {
        "encoding": "float64-le-base64", "t": _pack(path.t), "v": _pack(path.v), "w": _pack(path.w),
        "start_pose": path.start_pose.tolist(), "reference_pose": path.reference_pose.tolist(),
    }


def taught_path_from_dict(data: dict[str, Any]) -> TaughtPath:
    """Inverse of :func:`taught_path_to_dict`; ValueError when malformed."""
    if data.get("encoding") != "float64-le-base64":
        raise ValueError("taught_path: unknown array encoding")
    t, v, w = (_unpack(data[key], f"taught_path.{key}") for key in ("t", "v", "w"))
    start = np.asarray(data["start_pose"], dtype=float)
    reference = np.asarray(data["reference_pose"], dtype=float)
    if t.size < 2 or v.shape != t.shape or w.shape != t.shape or start.shape != (3,) or reference.shape != (3,):
        raise ValueError("taught_path arrays have inconsistent shapes")
    if not all(np.all(np.isfinite(a)) for a in (t, v, w, start, reference)):
        raise ValueError("taught_path holds NaN or infinity")
    if np.any(np.diff(t) <= 0.0):
        raise ValueError("taught_path times must increase strictly")
    return TaughtPath(t=t, v=v, w=w, start_pose=start, reference_pose=reference)


def _pack(array: np.ndarray) -> str:
    return base64.b64encode(np.ascontiguousarray(array, dtype="<f8").tobytes()).decode("ascii")


def _unpack(text: Any, what: str) -> np.ndarray:
    if not isinstance(text, str):
        raise ValueError(f"{what} must be a base64 string")
    try:
        raw = base64.b64decode(text, validate=True)
    except (ValueError, binascii.Error):
        raise ValueError(f"{what} is not valid base64") from None
    if len(raw) % 8:
        raise ValueError(f"{what} does not hold whole float64 numbers")
    return np.frombuffer(raw, dtype="<f8").astype(float)


def model_message(model: FitModel, log_time_ns: int) -> dict[str, Any]:
    """The ``hbvs.FitModel`` message of a model, stamped ``log_time_ns``."""
    return {
        "format_version": FORMAT_VERSION,
        "timestamp": time_message(log_time_ns),
        "hbvs_version": __version__,
        "target_kind": model.target_kind,
        "camera": camera_description(model.camera),
        "reference": {
            "index": model.reference_index, "t": model.reference_t, "pixels": model.reference_pixels.tolist(),
            "m_ref": model.m_ref.tolist(),
        },
        "normal": model.normal.tolist(),
        "normal_margin": model.normal_margin,
        "trajectory": model.trajectory.to_dict(),
        "dhat0": model.dhat0,
        "dhat0_source": model.dhat0_source,
        "depth": model.depth,
        "frames": model.frames,
        "condition35": model.condition35,
        "residual_px": model.residual_px,
        "detector": model.detector,
        "world": model.world_description,
        "taught_path": taught_path_to_dict(model.taught_path) if model.taught_path is not None else None,
        "render": model.render,
        "gains": model.gains,
        "uncertainty": model.uncertainty,
    }


def model_from_message(message: dict[str, Any], source: str = "") -> FitModel:
    """The model of a ``hbvs.FitModel`` message, everything ``repeat`` uses checked here (one clear
    message rather than a failure deep inside the simulation); :class:`RecordingError` when malformed."""
    try:
        if message.get("format_version") != FORMAT_VERSION:
            raise ValueError(f"unsupported model format_version {message.get('format_version')!r}")
        reference = message["reference"]
        m_ref = np.asarray(reference["m_ref"], dtype=float)
        pixels = np.asarray(reference["pixels"], dtype=float)
        normal = np.asarray(message["normal"], dtype=float)
        if m_ref.ndim != 2 or m_ref.shape[1] != 3 or not 3 <= m_ref.shape[0] <= MAX_TARGET_POINTS or pixels.shape != (m_ref.shape[0], 2):
            raise ValueError(f"reference points must be 3 to {MAX_TARGET_POINTS} rows of [1, m_y, m_z] with matching pixels")
        if not (np.all(np.isfinite(m_ref)) and np.all(np.isfinite(pixels))):
            raise ValueError("reference points hold NaN or infinity")
        if normal.shape != (3,) or not np.all(np.isfinite(normal)) or not np.linalg.norm(normal) > 0:
            raise ValueError("normal must be 3 finite numbers, not all zero")
        dhat0 = _positive_number(message["dhat0"], "dhat0")
        kind = str(message["target_kind"])
        if kind not in ("dots", "aruco", "chessboard", "charuco", "texture"):
            raise ValueError(f"unknown target kind {kind!r}")
        world = world_description(message["world"], source) if message.get("world") else None
        taught = taught_path_from_dict(message["taught_path"]) if message.get("taught_path") else None
        frames = dict(message.get("frames") or {})
        _positive_number(frames.get("frame_interval_s"), "frames.frame_interval_s", optional=True)
        render = message.get("render")
        if render is not None and render_settings_problem(render) is not None:
            raise ValueError(f"render: {render_settings_problem(render)}")
        margin = message.get("normal_margin")
        gains = message.get("gains")
        if gains is not None:
            if not isinstance(gains, dict):
                raise ValueError("gains must be an object")
            ControllerGains(**{k: _positive_number(gains.get(k), f"gains.{k}") for k in GAIN_NAMES})
        return FitModel(
            target_kind=kind, camera=camera_from_dict(message["camera"]), reference_index=int(reference["index"]),
            reference_t=float(reference["t"]), reference_pixels=pixels, m_ref=m_ref, normal=normal,
            normal_margin=float(margin) if margin is not None else float("nan"),
            trajectory=SplineTrajectory.from_dict(message["trajectory"]), dhat0=dhat0,
            dhat0_source=str(message.get("dhat0_source", "")), depth=dict(message.get("depth") or {}), frames=frames,
            condition35=dict(message.get("condition35") or {}), residual_px=dict(message.get("residual_px") or {}),
            detector=_check_detector(message.get("detector") or {}, kind, m_ref.shape[0]), world_description=world,
            taught_path=taught, render=dict(render) if render is not None else None,
            gains=dict(gains) if gains is not None else None,
            uncertainty=dict(message["uncertainty"]) if isinstance(message.get("uncertainty"), dict) else None,
        )
    except (HbvsError, *PARSE_ERRORS) as exc:
        raise RecordingError(f"{source}: the fit model is malformed: {exc}") from None


def checked_model_message(model: FitModel, log_time_ns: int, source: str) -> dict[str, Any]:
    """The model's message, once :func:`model_from_message` accepts it as it will be stored
    (JSON: NaN and infinity become null); :class:`RecordingError` otherwise."""
    from .mcap import encode_json

    message = model_message(model, log_time_ns)
    try:
        model_from_message(json.loads(encode_json(message)), source)
    except RecordingError as exc:
        text = str(exc).split("the fit model is malformed: ", 1)[-1]
        raise RecordingError(f"{source}: the recording gives a fit model that repeat could not use ({text}); nothing was written") from None
    return message


@dataclass
class FitFile:
    """What ``repeat`` reads from a fit file: the model and its images."""

    model: FitModel
    reference_image: bytes | None
    template_image: bytes | None
    info: dict[str, Any]
    truncated: bool = False


def read_fit_file(source: Any, name: str = "") -> FitFile:
    """Read the model and images of a fit file or stream; :class:`RecordingError` if it has none."""
    topics = {MODEL_TOPIC, REFERENCE_IMAGE_TOPIC, TEMPLATE_IMAGE_TOPIC}
    stream = McapStream(source, topics=topics, schemas=TOPICS[FILE_KIND], name=name)
    model_message: dict[str, Any] | None = None
    images: dict[str, bytes] = {}
    for message in stream:
        if message.topic == MODEL_TOPIC:
            model_message = message.json(stream.name)
        else:
            images[message.topic] = read_compressed_image(message.data, stream.name).data
    info = read_metadata(stream, "hbvs")
    kind = info.get("file_kind")
    if kind not in (None, FILE_KIND):
        raise RecordingError(f"{stream.name}: this is a {kind!r} file; hbvs repeat reads the output of hbvs fit")
    if model_message is None:
        raise RecordingError(f"{stream.name}: no fit model in it (is it the output of hbvs fit, and complete?)")
    return FitFile(
        model=model_from_message(model_message, stream.name), reference_image=images.get(REFERENCE_IMAGE_TOPIC),
        template_image=images.get(TEMPLATE_IMAGE_TOPIC), info=info, truncated=stream.truncated,
    )


def write_desired_signals(writer: Any, t: np.ndarray, log_time: np.ndarray, fit: DesiredFit) -> None:
    """Write ``/desired/raw`` (every used frame's measurement) and ``/desired/smooth`` (the splines
    and derivatives over the used span); ``t`` (F,) in s, ``log_time`` (F,) in ns."""

    schemas = TOPICS[FILE_KIND]
    uncertainty = fit.uncertainty
    for k in np.flatnonzero(fit.used):
        raw = {
            "timestamp": time_message(int(log_time[k])), "t": float(t[k]),
            "theta_d": float(fit.theta[k]), "x_hd1": float(fit.x_h[k, 0]), "x_hd2": float(fit.x_h[k, 1]),
            "residual": float(fit.residual[k]),
        }
        if uncertainty is not None:
            raw |= {"theta_d_sigma": float(uncertainty.theta_sigma[k]), "x_hd1_sigma": float(uncertainty.x_h1_sigma[k])}
        writer.write(RAW_DESIRED_TOPIC, schemas[RAW_DESIRED_TOPIC], int(log_time[k]), raw)
    span = fit.span
    desired = fit.trajectory.evaluate(t[span])
    for j, k in enumerate(range(span.start, span.stop)):
        smooth = {
            "timestamp": time_message(int(log_time[k])), "t": float(t[k]),
            "theta_d": float(desired.theta_d[j]), "x_hd1": float(desired.x_hd1[j]), "x_hd2": float(desired.x_hd2[j]),
            "theta_d_dot": float(desired.theta_d_dot[j]), "x_hd1_dot": float(desired.x_hd1_dot[j]), "x_hd2_dot": float(desired.x_hd2_dot[j]),
        }
        if uncertainty is not None:
            smooth |= {"theta_d_sigma": float(uncertainty.smooth_theta_sigma[j]), "x_hd1_sigma": float(uncertainty.smooth_x_h1_sigma[j])}
        writer.write(SMOOTH_DESIRED_TOPIC, schemas[SMOOTH_DESIRED_TOPIC], int(log_time[k]), smooth)
