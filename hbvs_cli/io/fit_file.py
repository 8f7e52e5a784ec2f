"""The fit file: what ``hbvs fit`` writes and ``hbvs repeat`` reads (topics in
:data:`~.topics.TOPICS` ``["fit"]`` and docs/files.md)."""

from __future__ import annotations

import base64
import binascii
import json
import math
from dataclasses import MISSING, asdict, dataclass, field, fields
from typing import Any

import numpy as np

from .. import __version__
from ..core.camera import CameraIntrinsics, camera_description
from ..core.control_settings import GAIN_NAMES, ControllerGains
from ..core.depth import DepthEstimate
from ..core.desired import DesiredFit, FrameStats, PixelResidual, Spread, UncertaintySummary
from ..core.fit_model import MAX_TARGET_POINTS, DepthEstimates, DetectorSpec, FitModel, SensorSettings, TaughtPath
from ..core.gains import GainSuggestion
from ..core.trajectory import FeedforwardCondition, SplineTrajectory
from ..errors import HbvsError, RecordingError
from .calibration import intrinsics_from_values
from .images import read_compressed_image
from .mcap import McapStream, encode_json, json_ready, read_metadata, time_message
from .topics import MODEL_TOPIC, RAW_DESIRED_TOPIC, ROUTE_TOPIC, REFERENCE_IMAGE_TOPIC, SMOOTH_DESIRED_TOPIC, TEMPLATE_IMAGE_TOPIC, TOPICS
from .teach_file import PARSE_ERRORS, RENDER_SETTINGS, render_settings_problem, world_description

FILE_KIND = "fit"
FORMAT_VERSION = 1


def camera_from_dict(data: dict[str, Any]) -> CameraIntrinsics:
    """The inverse of :func:`~hbvs_cli.core.camera.camera_description`, checked as a calibration file."""
    K = [data["fx"], 0.0, data["cx"], 0.0, data["fy"], data["cy"], 0.0, 0.0, 1.0]
    return intrinsics_from_values(
        K, data["width"], data["height"], str(data.get("distortion_model", "none")), data.get("distortion", ()), "camera",
    )


def _positive_number(value: Any, what: str) -> float:
    """``value`` as a finite positive float; ValueError otherwise."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 < value < math.inf:
        raise ValueError(f"{what} must be a positive number, got {value!r}")
    return float(value)


def _checked(convert: Any, ok: Any, what: str) -> Any:
    """A record value's converter: None stays None, else ``convert(value)`` when ``ok(value)``, ValueError saying ``what`` otherwise."""
    def checked(value: Any) -> Any:
        if value is not None and not ok(value):
            raise ValueError(f"must be {what}, got {str(value)[:40]!r}")
        return None if value is None else convert(value)
    return checked


def _small_wholes(value: Any, most: int = MAX_TARGET_POINTS // 4) -> bool:
    return isinstance(value, list) and len(value) <= most and all(isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= 1100 for v in value)


#: How a record's value becomes a field of the annotated type (JSON's null is a float's NaN),
#: checked for what repeat reads from it (ValueError).
_FIELD_TYPES: dict[str, Any] = {
    "float": lambda v: float("nan") if v is None else float(v), "float | None": _checked(float, lambda v: True, "a number"),
    "int": int, "bool": bool, "str": str, "dict[str, float]": lambda v: {str(k): float(x) for k, x in v.items()},
    "list[tuple[float, float]]": lambda v: [(float(a), float(b)) for a, b in v],
    "Spread | None": _checked(lambda v: _typed(Spread, v, "spread"), lambda v: True, "an object"),
    "int | None": _checked(int, lambda v: _small_wholes([v], 1), "a small whole number"),
    "str | None": _checked(str, lambda v: isinstance(v, str), "text"),
    "tuple[int, ...] | None": _checked(tuple, _small_wholes, "a list of small whole numbers"),
    "tuple[int, int] | None": _checked(tuple, lambda v: _small_wholes(v) and len(v) == 2, "two small whole numbers"),
    "np.ndarray | None": _checked(lambda v: np.asarray(v, dtype=float).reshape(-1, 2), lambda v: isinstance(v, list) and len(v) <= MAX_TARGET_POINTS
                                  and all(isinstance(row, list) and len(row) == 2 for row in v), "rows of (u, v) pixels"),
}


def _typed(cls: Any, record: Any, what: str) -> Any:
    """The frozen dataclass ``cls`` of a fit file's record (its fields by name; a field with a
    default may be missing from an older file); ValueError when malformed."""
    if not isinstance(record, dict):
        raise ValueError(f"{what} must be an object")
    values = {}
    for field in fields(cls):
        if field.name in record:
            try:
                values[field.name] = _FIELD_TYPES[field.type](record[field.name])
            except ValueError as exc:
                raise ValueError(f"{what} {field.name} {exc}") from None
        elif field.default is MISSING:
            raise ValueError(f"{what} lacks {field.name}")
    return cls(**values)


def _detector_from_record(record: Any, kind: str, points: int) -> DetectorSpec:
    """The recorded detector, of the target's kind and points (a kind's own options, e.g. a
    board's size against the points, are checked by its detector)."""
    spec = _typed(DetectorSpec, {"kind": kind} | record if isinstance(record, dict) else record, "detector")
    if spec.kind != kind:
        raise ValueError(f"detector kind {spec.kind!r} differs from the target kind {kind!r}")
    if spec.initial_pixels is not None and spec.initial_pixels.shape[0] != points:
        raise ValueError(f"detector initial_pixels has {spec.initial_pixels.shape[0]} points, the reference {points}")
    return spec


def _detector_record(spec: DetectorSpec) -> dict[str, Any]:
    """The ``detector`` object of a fit model; ``contrast`` (when not gray), ``board`` and
    ``initial_pixels`` only when set: a gray dots fit keeps its bytes."""
    record = {field.name: json_ready(getattr(spec, field.name)) for field in fields(DetectorSpec)}
    return {k: v for k, v in record.items() if k not in ("contrast", "board", "initial_pixels") or v not in (None, "gray")}


def _depth_record(depth: DepthEstimates) -> dict[str, Any]:
    target_size = depth.target_size and asdict(depth.target_size) | {"pair": list(depth.target_size_pair or ())}
    return {"commands": depth.commands and asdict(depth.commands), "target_size": target_size}


def _depth_from_record(record: Any) -> DepthEstimates:
    estimate = lambda key: _typed(DepthEstimate, record[key], f"depth.{key}") if record.get(key) else None  # noqa: E731
    pair = (record.get("target_size") or {}).get("pair")
    return DepthEstimates(estimate("commands"), estimate("target_size"), None if pair is None else (int(pair[0]), int(pair[1])))


def _gains_record(suggestion: GainSuggestion) -> dict[str, Any]:
    extra = {"heading_tolerance_deg": suggestion.heading_tolerance_deg} if math.isfinite(suggestion.heading_tolerance_deg) else {}
    return suggestion.gains.as_dict() | {k: getattr(suggestion, k) for k in ("x_hd1_dot", "noise_px", "design_noise_px", "sigma_e1")} | extra


def _gains_from_record(record: Any) -> GainSuggestion:
    if not isinstance(record, dict):
        raise ValueError("gains must be an object")
    gains = ControllerGains(**{k: _positive_number(record.get(k), f"gains.{k}") for k in GAIN_NAMES})
    number = lambda key: float("nan") if record.get(key) is None else float(record[key])  # noqa: E731
    return GainSuggestion(gains, *(number(k) for k in ("x_hd1_dot", "noise_px", "design_noise_px", "sigma_e1", "heading_tolerance_deg")))


def fit_summary_records(model: FitModel) -> dict[str, Any]:
    """What a run file keeps of its fit: condition (35) and the frames used, as the fit file records them."""
    return {"condition35": asdict(model.condition35), "fit_frames": asdict(model.frames)}


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
        "depth": _depth_record(model.depth),
        "frames": asdict(model.frames),
        "condition35": asdict(model.condition35),
        "residual_px": asdict(model.residual_px),
        "detector": _detector_record(model.detector),
        "world": model.world_description,
        "taught_path": taught_path_to_dict(model.taught_path) if model.taught_path is not None else None,
        "render": asdict(model.render) if model.render is not None else None,
        "gains": _gains_record(model.gains) if model.gains is not None else None,
        "uncertainty": _uncertainty_record(model.uncertainty) if model.uncertainty is not None else None,
    }


def _uncertainty_record(summary: UncertaintySummary) -> dict[str, Any]:
    """The ``uncertainty`` object; the calibration's part only when it was judged (a model read
    from a file written before keeps its bytes)."""
    record = asdict(summary)
    if summary.calibration is None:
        del record["calibration"], record["calibration_normal_sigma_deg"]
    return record


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
        kind = message["target_kind"]
        if not isinstance(kind, str) or not kind:
            raise ValueError(f"target_kind must be a name, got {kind!r}")
        world = world_description(message["world"], source) if message.get("world") else None
        taught = taught_path_from_dict(message["taught_path"]) if message.get("taught_path") else None
        frames = _typed(FrameStats, message["frames"], "frames")
        if frames.frame_interval_s is not None:  # None: not known
            _positive_number(frames.frame_interval_s, "frames.frame_interval_s")
        render = message.get("render")
        if render is not None and render_settings_problem(render) is not None:
            raise ValueError(f"render: {render_settings_problem(render)}")
        uncertainty = message.get("uncertainty")
        return FitModel(
            target_kind=kind, camera=camera_from_dict(message["camera"]), reference_index=int(reference["index"]),
            reference_t=float(reference["t"]), reference_pixels=pixels, m_ref=m_ref, normal=normal,
            normal_margin=_FIELD_TYPES["float"](message.get("normal_margin")),  # JSON null: NaN
            trajectory=SplineTrajectory.from_dict(message["trajectory"]), dhat0=dhat0,
            dhat0_source=str(message.get("dhat0_source", "")), depth=_depth_from_record(message.get("depth") or {}), frames=frames,
            condition35=_typed(FeedforwardCondition, message["condition35"], "condition35"),
            residual_px=_typed(PixelResidual, message.get("residual_px") or {}, "residual_px"),
            detector=_detector_from_record(message.get("detector") or {}, kind, m_ref.shape[0]), world_description=world,
            taught_path=taught, render=None if render is None else SensorSettings(**{k: float(v) for k, v in render.items() if k in RENDER_SETTINGS}),
            gains=None if message.get("gains") is None else _gains_from_record(message["gains"]),
            uncertainty=_typed(UncertaintySummary, uncertainty, "uncertainty") if isinstance(uncertainty, dict) else None,
        )
    except (HbvsError, *PARSE_ERRORS) as exc:
        raise RecordingError(f"{source}: the fit model is malformed: {exc}") from None


def checked_model_message(model: FitModel, log_time_ns: int, source: str) -> dict[str, Any]:
    """The model's message, once :func:`model_from_message` accepts it as it will be stored
    (JSON: NaN and infinity become null); :class:`RecordingError` otherwise."""
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
    info: dict[str, Any]
    truncated: bool = False
    #: A route's fit (:mod:`.route_file`): every segment's model (``model`` is the first's) and its route record.
    segment_models: list[FitModel] = field(default_factory=list)
    route_record: dict[str, Any] | None = None
    #: Every ``/detector/template`` image in the file's order (a route's: one per segment using one); a fit's is the last.
    templates: list[bytes] = field(default_factory=list)


def read_fit_file(source: Any, name: str = "") -> FitFile:
    """Read the model and images of a fit file or stream; :class:`RecordingError` if it has none."""
    topics = {MODEL_TOPIC, ROUTE_TOPIC, REFERENCE_IMAGE_TOPIC, TEMPLATE_IMAGE_TOPIC}
    stream = McapStream(source, topics=topics, schemas=TOPICS[FILE_KIND], name=name)
    model_messages: list[dict[str, Any]] = []
    route_record: dict[str, Any] | None = None
    reference_image: bytes | None = None
    templates: list[bytes] = []
    for message in stream:
        if message.topic == MODEL_TOPIC:
            model_messages.append(message.json(stream.name))
        elif message.topic == ROUTE_TOPIC:
            route_record = message.json(stream.name)
        elif message.topic == REFERENCE_IMAGE_TOPIC:
            reference_image = read_compressed_image(message.data, stream.name).data
        else:
            templates.append(read_compressed_image(message.data, stream.name).data)
    info = read_metadata(stream, "hbvs")
    kind = info.get("file_kind")
    if kind not in (None, FILE_KIND):
        raise RecordingError(f"{stream.name}: this is a {kind!r} file; hbvs repeat reads the output of hbvs fit")
    if not model_messages:
        raise RecordingError(f"{stream.name}: no fit model in it (is it the output of hbvs fit, and complete?)")
    if len(model_messages) > 1 and route_record is None:
        raise RecordingError(f"{stream.name}: {len(model_messages)} fit models but no route record (a route fit cut short?)")
    models = [model_from_message(message, stream.name) for message in model_messages]
    return FitFile(
        model=models[0], reference_image=reference_image, info=info,
        truncated=stream.truncated,
        segment_models=models, route_record=route_record, templates=templates,
    )


def write_desired_signals(writer: Any, t: np.ndarray, log_time: np.ndarray, fit: DesiredFit) -> None:
    """Write ``/desired/raw`` (every used frame's measurement) and ``/desired/smooth`` (the splines
    and derivatives over the used span); ``t`` (F,) in s, ``log_time`` (F,) in ns."""
    uncertainty, span = fit.uncertainty, fit.span
    desired = fit.trajectory.evaluate(t[span])
    raw = {"theta_d": fit.theta, "x_hd1": fit.x_h[:, 0], "x_hd2": fit.x_h[:, 1], "residual": fit.residual}
    smooth = {name: getattr(desired, name) for name in ("theta_d", "x_hd1", "x_hd2", "theta_d_dot", "x_hd1_dot", "x_hd2_dot")}
    if uncertainty is not None:
        raw |= {"theta_d_sigma": uncertainty.theta_sigma, "x_hd1_sigma": uncertainty.x_h1_sigma}
        smooth |= {"theta_d_sigma": uncertainty.smooth_theta_sigma, "x_hd1_sigma": uncertainty.smooth_x_h1_sigma}
    # Raw columns hold every frame, smooth ones the used span only (from its start).
    for topic, columns, frames, first in ((RAW_DESIRED_TOPIC, raw, np.flatnonzero(fit.used), 0),
                                          (SMOOTH_DESIRED_TOPIC, smooth, range(span.start, span.stop), span.start)):
        for k in frames:
            values = {name: float(column[k - first]) for name, column in columns.items()}
            message = {"timestamp": time_message(int(log_time[k])), "t": float(t[k]), **values}
            writer.write(topic, TOPICS[FILE_KIND][topic], int(log_time[k]), message)
