"""The metrics of one run as a JSON-ready dictionary: what ``hbvs report`` prints.

:func:`build_report` returns exactly these top-level keys (docs/report.md documents every
key and unit): ``run``, ``errors``, ``pose_error`` (only with ground truth), ``lyapunov``,
``depth``, ``commands``, ``target``, ``condition35``, ``verdict``.

Convergence rule (:func:`verdict`; docs/report.md and docs/commands.md cite it here). A run has
converged when every one of these holds:

1. it was a closed-loop run: an open-loop replay (``mode = replay``) never converged,
   because nothing moved;
2. it finished: the file is complete and the run was not stopped for a lost target;
3. every final error (mean of |error| over the last 5 % of the run) is within its
   tolerance: the pose errors ``position_m`` and ``heading_deg`` when the run has ground
   truth, otherwise the image errors ``e1``, ``e2`` and ``e3``;
4. the Lyapunov function fell, ``V_final / V(0) <`` :data:`V_RATIO_BOUND`, when V is known
   (it needs the true d*, so a real or replayed run skips this check);
5. the commands are smooth: the RMS of dv/dt is at most :data:`SMOOTHNESS_FACTOR` times
   that of the taught commands (25) plus :data:`SMOOTHNESS_FLOOR_V` m/s^2, and the same
   for w with :data:`SMOOTHNESS_FLOOR_W` rad/s^2 (a chattering robot has not converged,
   whatever its mean error).

The same tolerances (:data:`DEFAULT_TOLERANCES`, overridable with ``--tolerance``) are
the bands of the settling times.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Mapping

import numpy as np

from ..core.frames import wrap_angle
from ..core.metrics import (
    command_smoothness,
    error_summary,
    round_significant,
    longest_true_run_s,
    lyapunov_summary,
    min_abs,
    peak_abs,
    rms,
    sample_rate_hz,
    taught_commands,
)
from ..errors import UsageError
from ..io.messages import LOG_ERROR
from ..io.run_file import RunData

#: Final-error and settling tolerances: image errors in x_h units (fractions of d*),
#: e3 and heading in degrees, position in metres.
DEFAULT_TOLERANCES: dict[str, float] = {
    "position_m": 0.01,
    "heading_deg": 0.2,
    "e1": 0.0025,
    "e2": 0.0025,
    "ebar2": 0.0025,
    "e3": 0.2,
}
#: Significant digits of every number in a report: float noise such as a rate of
#: 30.0000003 Hz (1 / a median step of float times) is not a measurement.
REPORT_DIGITS = 7
#: V must end below this fraction of V(0) for a run to count as converged.
V_RATIO_BOUND = 0.5
#: Command smoothness (rule 5): the RMS of dv/dt (dw/dt) may be at most this many times
#: the taught commands' plus a floor, in m/s^2 (rad/s^2), for the start's correction.
SMOOTHNESS_FACTOR = 10.0
SMOOTHNESS_FLOOR_V = 1.0
SMOOTHNESS_FLOOR_W = 1.0
#: The image errors of (19) and (27), in report order; e3 is reported in degrees.
IMAGE_ERRORS = ("e1", "e2", "ebar2", "e3")
#: The pose errors (ground truth only), in report order.
POSE_ERRORS = ("position_m", "heading_deg")
#: Top-level keys of a report, in order.
REPORT_KEYS = ("run", "errors", "pose_error", "lyapunov", "depth", "commands", "target", "condition35", "verdict")

#: Names of the verdict's checks (``verdict.checks``), in order; a run has those that apply.
CHECK_NAMES = (
    "closed_loop", "finished", "final_position", "final_heading", "final_e1", "final_e2", "final_e3", "lyapunov",
    "smoothness",
)
#: The check of each final error.
_FINAL_CHECK_NAMES = {
    "position_m": "final_position", "heading_deg": "final_heading", "e1": "final_e1", "e2": "final_e2", "e3": "final_e3",
}

#: How a verdict line names each final error: (label, scale to the shown unit, unit).
_FINAL_CHECKS: dict[str, tuple[str, float, str]] = {
    "position_m": ("final position error", 100.0, "cm"),
    "heading_deg": ("final |heading error|", 1.0, "deg"),
    "e1": ("final |e1|", 1.0, ""),
    "e2": ("final |e2|", 1.0, ""),
    "ebar2": ("final |ebar2|", 1.0, ""),
    "e3": ("final |e3|", 1.0, "deg"),
}


def resolve_tolerances(overrides: Mapping[str, float] | None = None) -> dict[str, float]:
    """:data:`DEFAULT_TOLERANCES` with ``overrides`` applied, checked.

    Raises
    ------
    UsageError
        An unknown name, or a value that is not a positive finite number.
    """
    tolerances = dict(DEFAULT_TOLERANCES)
    for name, value in (overrides or {}).items():
        if name not in tolerances:
            raise UsageError(f"--tolerance: unknown name {name!r}; use one of {', '.join(DEFAULT_TOLERANCES)}")
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise UsageError(f"--tolerance {name}: the value must be a positive number, got {value!r}")
        tolerances[name] = float(value)
    return tolerances


class MissingKey(KeyError):
    """A dotted report key with a part that does not exist: ``where`` lacks ``part``."""

    def __init__(self, where: str, part: str, choices: list[str]) -> None:
        super().__init__(part)
        self.where, self.part, self.choices = where, part, choices


def resolve_key(report: Mapping[str, Any], key: str) -> Any:
    """The value at a dotted key of a report, e.g. ``"pose_error.position_m.final"``.

    Raises
    ------
    MissingKey
        A part of the key is not in the report (``where`` is the dotted prefix that lacks it).
    """
    value: Any = report
    walked: list[str] = []
    for part in key.split("."):
        if not isinstance(value, Mapping) or part not in value:
            choices = list(value) if isinstance(value, Mapping) else []
            raise MissingKey(".".join(walked) or "the report", part, choices)
        value = value[part]
        walked.append(part)
    return value


# ----------------------------------------------------------------------------- signals
def image_error_signal(run: RunData, name: str) -> np.ndarray:
    """An image error per step: e1, e2, ebar2 (x_h units) or e3 (degrees); NaN when lost."""
    values = run.state[name]
    return np.degrees(values) if name == "e3" else values


def pose_error_signals(run: RunData) -> dict[str, np.ndarray] | None:
    """Ground-truth errors per step, or ``None`` without ground truth.

    Returns
    -------
    dict
        ``position_m``: distance (m) between the true and the taught position at the same
        time; ``heading_deg``: true minus taught heading, wrapped to [-180, 180) degrees.
    """
    if run.true_pose is None or run.desired_pose is None:
        return None
    difference = run.true_pose - run.desired_pose
    return {
        "position_m": np.hypot(difference[:, 0], difference[:, 1]),
        "heading_deg": np.degrees(wrap_angle(difference[:, 2])),
    }


def stop_event(run: RunData) -> tuple[float, str] | None:
    """The error event (time in s, text) with which ``hbvs repeat`` stopped the run, if any."""
    for t, level, text in run.events:
        if level >= LOG_ERROR:
            return t, text
    return None


def _duration_s(run: RunData) -> float:
    t = run.state["t"]
    return float(t[-1] - t[0])


# ----------------------------------------------------------------------------- sections
def default_label(run: RunData) -> str:
    """How a run is named without ``--label``: its law (``replay`` for an open-loop replay)."""
    if run.info.get("mode") == "replay":
        return "replay"
    return str(run.info.get("law") or run.info.get("mode") or "run")


def _run_section(run: RunData, label: str | None) -> dict[str, Any]:
    settings = run.info.get("settings") or {}
    return {
        "name": run.name,
        "label": label if label is not None else default_label(run),
        "duration_s": _duration_s(run),
        "steps": run.steps,
        "rate_hz": sample_rate_hz(run.state["t"]),
        "law": run.info.get("law"),
        "gains": dict(run.info.get("gains") or {}),
        "source": {"mode": run.info.get("mode"), "fit_file": settings.get("input")},
        "truncated": bool(run.truncated),
    }


def _error_section(run: RunData, tolerances: Mapping[str, float]) -> dict[str, Any]:
    t = run.state["t"]
    return {name: error_summary(t, image_error_signal(run, name), tolerances[name]) for name in IMAGE_ERRORS}


def _pose_section(run: RunData, tolerances: Mapping[str, float]) -> dict[str, Any] | None:
    signals = pose_error_signals(run)
    if signals is None:
        return None
    t = run.state["t"]
    return {name: error_summary(t, signals[name], tolerances[name]) for name in POSE_ERRORS}


def _depth_section(run: RunData) -> dict[str, Any]:
    dhat = run.state["dhat"]
    finite = dhat[np.isfinite(dhat)]
    d_true = run.info.get("d_true")
    d_true = float(d_true) if isinstance(d_true, (int, float)) and d_true > 0 else None
    dhat_final = float(finite[-1]) if finite.size else None
    relative = abs(dhat_final - d_true) / d_true if d_true is not None and dhat_final is not None else None
    return {
        "dhat_initial": float(finite[0]) if finite.size else None,
        "dhat_final": dhat_final,
        "d_true": d_true,
        "relative_error": relative,
    }


def _limits(run: RunData) -> dict[str, float | None]:
    limits = ((run.info.get("settings") or {}).get("limits")) or {}
    return {name: (float(limits[name]) if isinstance(limits.get(name), (int, float)) and limits[name] > 0 else None)
            for name in ("max_v", "max_w", "max_accel")}


def _command_section(run: RunData) -> dict[str, Any]:
    v, w, t = run.state["v_c"], run.state["w_c"], run.state["t"]
    limits = _limits(run)
    d_true = run.info.get("d_true")
    dhat = run.state["dhat"][np.isfinite(run.state["dhat"])]
    depth = float(d_true) if isinstance(d_true, (int, float)) and d_true > 0 else (float(dhat[-1]) if dhat.size else float("nan"))
    v_d, w_d = taught_commands(run.state["x_hd2"], run.state["x_hd1_dot"], run.state["theta_d_dot"], depth)
    taught = command_smoothness(t, v_d, w_d)
    return {
        "v_peak_mps": peak_abs(v),
        "v_rms_mps": rms(v),
        "w_peak_radps": peak_abs(w),
        "w_rms_radps": rms(w),
        "saturated_fraction": float(np.mean(run.saturated)),
        **command_smoothness(t, v, w, **limits),
        "limits": limits,
        "taught": {key: taught[key] for key in ("v_tv_per_s", "w_tv_per_s", "dv_dt_rms_mps2", "dw_dt_rms_radps2")},
    }


def _target_section(run: RunData) -> dict[str, Any]:
    # A dropped frame inside a loss is still lost time (run.lost holds through drops),
    # so the longest loss spans drops; dropped frames are also counted on their own.
    dropped = run.dropped if run.dropped is not None else np.zeros(run.steps, dtype=bool)
    return {
        "lost_frames": int(np.count_nonzero(run.lost)),
        "lost_fraction": float(np.mean(run.lost)),
        "longest_loss_s": longest_true_run_s(run.state["t"], run.lost),
        "dropped_frames": int(np.count_nonzero(dropped)),
        "dropped_fraction": float(np.mean(dropped)),
    }


#: Percentiles of the frame-to-command latency in a live run's report.
LATENCY_PERCENTILES = (50, 95, 99)


def timing_section(run: RunData) -> dict[str, Any] | None:
    """A live run's loop timing (``repeat --live``; None for other runs): the latency from a
    frame's arrival to its command's publication (ms), the frame interval, and the frames
    dropped (arrived while another was processed) or late (interval over 1.5 periods)."""
    timing = run.timing
    if timing is None or timing["t"].size == 0:
        return None
    latency_ms = 1e3 * timing["latency_s"]
    intervals = timing["frame_interval_s"][np.isfinite(timing["frame_interval_s"])]
    section: dict[str, Any] = {f"latency_p{q}_ms": float(np.percentile(latency_ms, q)) for q in LATENCY_PERCENTILES}
    section["latency_max_ms"] = float(np.max(latency_ms))
    section["frame_interval_p50_ms"] = float(1e3 * np.median(intervals)) if intervals.size else None
    section["frame_interval_max_ms"] = float(1e3 * np.max(intervals)) if intervals.size else None
    section["frames_dropped"] = int(np.nansum(timing["dropped"]))
    section["frames_late"] = int(np.nansum(timing["late"]))
    return section


def _condition35_section(run: RunData) -> dict[str, Any]:
    fitted = (run.info.get("condition35") or {}).get("min_abs_xhd1_dot")
    return {
        "min_abs_xhd1_dot": min_abs(run.state["x_hd1_dot"]),
        "fit_min_abs_xhd1_dot": float(fitted) if isinstance(fitted, (int, float)) else None,
    }


# ----------------------------------------------------------------------------- verdict
def _check(passed: bool | None, text: str) -> tuple[bool | None, str]:
    """A verdict line: ``pass: ...``, ``fail: ...`` or, for a check not made, ``skip: ...``."""
    prefix = {True: "pass", False: "fail", None: "skip"}[passed]
    return passed, f"{prefix}: {text}"


def _quantity(value: float, scale: float, unit: str) -> str:
    return f"{value * scale:.3g}" + (f" {unit}" if unit else "")


def _final_error_check(name: str, final: float | None, tolerance: float) -> tuple[bool | None, str]:
    label, scale, unit = _FINAL_CHECKS[name]
    bound = _quantity(tolerance, scale, unit)
    if final is None:
        return _check(False, f"{label} unknown (target not seen at the end), tolerance {bound}")
    within = final <= tolerance
    return _check(within, f"{label} {_quantity(final, scale, unit)} {'<=' if within else '>'} {bound}")


def _finished_check(run: RunData) -> tuple[bool | None, str]:
    stop = stop_event(run)
    if stop is not None:
        return _check(False, f"run stopped at t = {stop[0]:.2f} s ({stop[1]})")
    if run.truncated:
        return _check(False, "the file is truncated: the run did not finish")
    return _check(True, f"run finished ({_duration_s(run):.2f} s, {run.steps} steps)")


def _lyapunov_check(lyapunov: Mapping[str, Any]) -> tuple[bool | None, str]:
    ratio = lyapunov.get("ratio")
    if ratio is None:
        return _check(None, "V unknown (it needs the true depth d*): not checked")
    fell = ratio < V_RATIO_BOUND
    return _check(fell, f"V final / V(0) = {ratio:.3g} {'<' if fell else '>='} {V_RATIO_BOUND:g}")


def smoothness_bound(taught_rms: float | None, floor: float) -> float:
    """The largest RMS rate of change of a command that is not chatter (docs/report.md):
    :data:`SMOOTHNESS_FACTOR` times the taught commands' plus an allowance ``floor`` for
    correcting the start offset."""
    return SMOOTHNESS_FACTOR * (taught_rms or 0.0) + floor


def _smoothness_check(commands: Mapping[str, Any]) -> tuple[bool | None, str]:
    taught = commands.get("taught") or {}
    parts, passed = [], True
    for key, floor, unit in (("dv_dt_rms_mps2", SMOOTHNESS_FLOOR_V, "m/s^2"), ("dw_dt_rms_radps2", SMOOTHNESS_FLOOR_W, "rad/s^2")):
        value = commands.get(key)
        if value is None:
            return _check(None, "command smoothness unknown (fewer than two steps): not checked")
        bound = smoothness_bound(taught.get(key), floor)
        within = value <= bound
        passed = passed and within
        parts.append(f"RMS d{key[1]}/dt {value:.3g} {'<=' if within else '>'} {bound:.3g} {unit}")
    return _check(passed, "commands smooth: " + ", ".join(parts) if passed else "commands chatter: " + ", ".join(parts))


def verdict(run: RunData, report: Mapping[str, Any], tolerances: Mapping[str, float]) -> dict[str, Any]:
    """Whether the run converged, by the rule of this module's docstring, and why.

    Parameters
    ----------
    run : RunData
    report : dict
        The other sections of the report (``errors``, ``pose_error``, ``lyapunov``).
    tolerances : dict
        Final-error tolerances (:data:`DEFAULT_TOLERANCES` units).

    Returns
    -------
    dict
        ``converged`` (bool); ``checks``: check name (:data:`CHECK_NAMES`) -> its line,
        ``pass: ...``, ``fail: ...`` or ``skip: ...``; ``reasons``: the same lines as a list.
    """
    checks: dict[str, tuple[bool | None, str]] = {}
    if run.info.get("mode") == "replay":
        checks["closed_loop"] = _check(False, "open-loop replay: nothing moved, so it cannot have converged")
    else:
        checks["closed_loop"] = _check(True, f"closed loop ({run.info.get('mode') or 'unknown mode'})")
    checks["finished"] = _finished_check(run)
    errors, names = (report["pose_error"], POSE_ERRORS) if "pose_error" in report else (report["errors"], ("e1", "e2", "e3"))
    for name in names:
        checks[_FINAL_CHECK_NAMES[name]] = _final_error_check(name, errors[name]["final"], tolerances[name])
    checks["lyapunov"] = _lyapunov_check(report["lyapunov"])
    checks["smoothness"] = _smoothness_check(report["commands"])
    return {
        "converged": all(passed is not False for passed, _ in checks.values()),
        "checks": {name: text for name, (_, text) in checks.items()},
        "reasons": [text for _, text in checks.values()],
    }


# ----------------------------------------------------------------------------- report
def build_report(run: RunData, tolerances: Mapping[str, float] | None = None, label: str | None = None) -> dict[str, Any]:
    """Every metric of one run, as JSON-ready values (see docs/report.md for units).

    Parameters
    ----------
    run : RunData
        A run read by :func:`hbvs_cli.io.run_file.read_run`.
    tolerances : dict, optional
        Overrides of :data:`DEFAULT_TOLERANCES` (names ``e1, e2, ebar2, e3, position_m,
        heading_deg``).
    label : str, optional
        The run's name in tables and legends (``--label``); default :func:`default_label`.

    Returns
    -------
    dict
        Keys :data:`REPORT_KEYS` in that order; ``pose_error`` only when the run has
        ground truth; ``timing`` (before ``verdict``) only for a live run. Unknown values are ``None``; every number is rounded to
        :data:`REPORT_DIGITS` significant digits, so JSON, table and ``--fail-above`` see
        one value.
    """
    tolerances = resolve_tolerances(tolerances)
    sections: dict[str, Callable[[], Any]] = {
        "run": lambda: _run_section(run, label),
        "errors": lambda: _error_section(run, tolerances),
        "pose_error": lambda: _pose_section(run, tolerances),
        "lyapunov": lambda: lyapunov_summary(run.state["V"]),
        "depth": lambda: _depth_section(run),
        "commands": lambda: _command_section(run),
        "target": lambda: _target_section(run),
        "condition35": lambda: _condition35_section(run),
        "timing": lambda: timing_section(run),
    }
    report: dict[str, Any] = {}
    for key, section in sections.items():
        value = section()
        if value is not None:
            report[key] = value
    report = round_significant(report, REPORT_DIGITS)
    report["verdict"] = verdict(run, report, tolerances)
    return report
