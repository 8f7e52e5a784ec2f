"""JSON schemas of hbvs's own ``hbvs.*`` messages (``foxglove.*`` ones are protobuf)."""

from __future__ import annotations

from typing import Any

from .topics import CONTROLLER_STATE_SCHEMA, DESIRED_SIGNAL_SCHEMA, FIT_MODEL_SCHEMA, LOOP_TIMING_SCHEMA, ROUTE_SCHEMA, VELOCITY_COMMAND_SCHEMA

_TIME = {
    "type": "object",
    "title": "time",
    "properties": {
        "sec": {"type": "integer", "minimum": 0},
        "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999},
    },
    "required": ["sec", "nsec"],
}
_NUMBER = {"type": "number"}
_NUMBER_OR_NULL = {"type": ["number", "null"]}


def _message(name: str, description: str, properties: dict[str, Any], required: list[str]) -> dict[str, Any]:
    """The schema of an ``hbvs.*`` message ``name``: an object, its ``timestamp`` first."""
    return {"title": name, "description": description, "type": "object", "properties": {"timestamp": _TIME, **properties},
            "required": required}


HBVS_SCHEMAS: dict[str, dict[str, Any]] = {schema["title"]: schema for schema in (
    _message(VELOCITY_COMMAND_SCHEMA, "A unicycle velocity command: v along the robot's x axis, w about z", {
        "v": {**_NUMBER, "description": "linear velocity (m/s)"},
        "w": {**_NUMBER, "description": "angular velocity (rad/s)"},
        "saturated": {"type": "boolean", "description": "clipped by the actuator limits"},
    }, ["timestamp", "v", "w"]),
    _message(DESIRED_SIGNAL_SCHEMA, "Desired signals of Remark 1: decomposed (raw) or smoothed by splines", {
        "t": {**_NUMBER, "description": "time from the start of the taught run (s)"},
        "theta_d": {**_NUMBER, "description": "desired rotation (rad)"},
        "x_hd1": {**_NUMBER, "description": "desired scaled translation x_f1 / d* (-)"},
        "x_hd2": {**_NUMBER, "description": "desired scaled translation x_f2 / d* (-)"},
        "theta_d_dot": {**_NUMBER_OR_NULL, "description": "rad/s (smooth only)"},
        "x_hd1_dot": {**_NUMBER_OR_NULL, "description": "1/s (smooth only)"},
        "x_hd2_dot": {**_NUMBER_OR_NULL, "description": "1/s (smooth only)"},
        "residual": {**_NUMBER_OR_NULL, "description": "RMS equation residual of the frame (raw only)"},
        "theta_d_sigma": {**_NUMBER_OR_NULL, "description": "one standard deviation of theta_d (rad): the frame's own noise and what it inherits from n* and the reference points (raw), carried through the spline (smooth)"},
        "x_hd1_sigma": {**_NUMBER_OR_NULL, "description": "one standard deviation of x_hd1 (-), as theta_d_sigma"},
    }, ["timestamp", "t", "theta_d", "x_hd1", "x_hd2"]),
    {
        "title": FIT_MODEL_SCHEMA,
        "description": "The fitted desired trajectory and everything repeat needs to track it",
        "type": "object",
        "properties": {
            "format_version": {"type": "integer", "const": 1},
            "timestamp": _TIME,
            "target_kind": {"type": "string", "minLength": 1},
            "camera": {"type": "object"},
            "reference": {"type": "object"},
            "normal": {"type": "array", "items": _NUMBER, "minItems": 3, "maxItems": 3},
            "normal_margin": _NUMBER,
            "trajectory": {"type": "object"},
            "dhat0": {**_NUMBER, "exclusiveMinimum": 0, "description": "suggested initial depth estimate (m)"},
            "dhat0_source": {"type": "string"},
            "depth": {"type": "object"},
            "frames": {"type": "object"},
            "condition35": {"type": "object"},
            "world": {"type": ["object", "null"]},
            "taught_path": {"type": ["object", "null"]},
            "detector": {"type": "object"},
            "residual_px": {"type": "object"},
            "render": {"type": ["object", "null"], "description": "sensor model of a simulated teach"},
            "gains": {"type": ["object", "null"], "description": "gains suggested from x_hd1_dot and the detector's noise (k_v, k_w, gamma, k_2 and the rule's inputs)"},
            "uncertainty": {"type": ["object", "null"], "description": "the joint estimate's uncertainty: normal_sigma_deg (n*, 1 sigma), calibration_normal_sigma_deg (its part from the intrinsics; for an unstated calibration what 1 px would add, not counted) and calibration (stated, unstated or exact; assumed in older files), point_noise_px, theta_d_sigma_deg and x_hd1_sigma (median and max of the splines' sigma)"},
        },
        "required": [
            "format_version", "timestamp", "target_kind", "camera", "reference", "normal",
            "trajectory", "dhat0", "dhat0_source", "frames", "condition35",
        ],
    },
    _message(CONTROLLER_STATE_SCHEMA, "One control step of the adaptive tracking controller (29)-(31)", {
        "t": _NUMBER,
        "x_h1": _NUMBER_OR_NULL, "x_h2": _NUMBER_OR_NULL, "theta": _NUMBER_OR_NULL,
        "x_hd1": _NUMBER, "x_hd2": _NUMBER, "theta_d": _NUMBER,
        "x_hd1_dot": _NUMBER, "x_hd2_dot": _NUMBER, "theta_d_dot": _NUMBER,
        "e1": _NUMBER_OR_NULL, "e2": _NUMBER_OR_NULL, "ebar2": _NUMBER_OR_NULL, "e3": _NUMBER_OR_NULL,
        "v_c": _NUMBER, "w_c": _NUMBER,
        "v_law": _NUMBER_OR_NULL, "w_law": _NUMBER_OR_NULL,
        "saturated": {"type": "boolean"},
        "dhat": _NUMBER,
        "target_lost": {"type": "boolean"},
        "lost_reason": {"type": "string"},
        "frame_dropped": {"type": "boolean"},
        "residual": _NUMBER_OR_NULL,
        "V": _NUMBER_OR_NULL,
        "theta_est": _NUMBER_OR_NULL, "x_h1_est": _NUMBER_OR_NULL, "x_h2_est": _NUMBER_OR_NULL,
        "theta_std": _NUMBER_OR_NULL, "x_h1_std": _NUMBER_OR_NULL, "x_h2_std": _NUMBER_OR_NULL,
        "noise_px": _NUMBER_OR_NULL,
        "filter": {"type": "string", "description": "what the state filter did: fused, gated, started, predicted, or empty without a filter"},
    }, [
        "timestamp", "t", "x_h1", "x_h2", "theta", "x_hd1", "x_hd2", "theta_d",
        "x_hd1_dot", "x_hd2_dot", "theta_d_dot", "e1", "e2", "ebar2", "e3",
        "v_c", "w_c", "saturated", "dhat", "target_lost", "V",
    ]),
    _message(LOOP_TIMING_SCHEMA,
             "Timing of one step of a live run (repeat --live): the frame, the latency, the frames dropped", {
        "t": {**_NUMBER, "description": "run time of the step (s): the frame's stamp from the run's first frame"},
        "frame_stamp": {**_NUMBER, "description": "the frame's header stamp, or its capture time for a camera (s)"},
        "latency_s": {**_NUMBER, "description": "from the frame's arrival to the command's publication (s)"},
        "frame_interval_s": {**_NUMBER_OR_NULL, "description": "stamp difference to the previous frame measured (s)"},
        "dropped": {"type": "integer", "description": "frames that arrived while the previous one was processed, dropped for this one"},
        "late": {"type": "boolean", "description": "the frame interval exceeded 1.5 control periods"},
        "dry_run": {"type": "boolean", "description": "zero was published instead of the command (--dry-run)"},
    }, ["timestamp", "t", "frame_stamp", "latency_s", "dropped"]),
    _message(ROUTE_SCHEMA,
             "A route's segments (one hbvs.FitModel each on /fit/model, in order) and the transition from each to the next (issue 47)", {
        "segments": {"type": "array", "items": {"type": "object", "description": "target (index in the route), first and last frame of the drive, overlap_last (the previous segment's last frame; null for the first), reference (F*_i's frame), template (the index of its detector's template among the file's /detector/template images; null: none)"}},
        "transitions": {"type": "array", "items": {"type": "object", "description": "F*_{i+1} in F*_i: depth_ratio rho = d*_{i+1}/d*_i, heading (rad), origin_over_depth (-), their standard deviations and covariance of (u_1, u_2, rho)"}},
    }, ["timestamp", "segments", "transitions"]),
)}
