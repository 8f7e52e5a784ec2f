"""The metrics of one run: :func:`build_report` computes the :class:`~.result.RunReport`
that ``hbvs report`` prints. docs/report.md documents every field and unit, and the
convergence rule of :func:`verdict` ("Convergence rule"), whose bounds are
:data:`DEFAULT_TOLERANCES` (which also band the settling times), :data:`V_RATIO_BOUND` and
:data:`SMOOTHNESS_FACTOR`.
"""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from ..core.frames import wrap_angle
from ..core.metrics import (
    command_smoothness, error_summary, longest_true_run_s, lyapunov_summary, min_abs, peak_abs, rms, sample_rate_hz,
    settling_time, taught_commands,
)
from ..errors import UsageError
from ..io.messages import LOG_ERROR
from ..io.run_file import RunData
from .result import (
    Commands, Condition35, Depth, ErrorSummary, Limits, Lyapunov, RouteSegment, RunReport, RunSummary, Source, TaughtSmoothness,
    Target, Timing, Verdict,
)

#: Final-error and settling tolerances: image errors in x_h units (fractions of d*),
#: e3 and heading in degrees, position in metres.
DEFAULT_TOLERANCES: dict[str, float] = {"position_m": 0.01, "heading_deg": 0.2, "e1": 0.0025, "e2": 0.0025, "ebar2": 0.0025, "e3": 0.2}
#: V must end below this fraction of V(0) for a run to count as converged.
V_RATIO_BOUND = 0.5
#: Command smoothness (rule 5): factor on the taught commands' RMS rate, floors in m/s^2, rad/s^2.
SMOOTHNESS_FACTOR = 10.0
SMOOTHNESS_FLOOR_V = 1.0
SMOOTHNESS_FLOOR_W = 1.0
#: The image errors of (19) and (27), in report order; e3 is reported in degrees.
IMAGE_ERRORS = ("e1", "e2", "ebar2", "e3")
#: The pose errors (ground truth only), in report order.
POSE_ERRORS = ("position_m", "heading_deg")

#: Each final error's check name, label, scale to the shown unit, and unit.
_FINAL_CHECKS: dict[str, tuple[str, str, float, str]] = {
    "position_m": ("final_position", "final position error", 100.0, "cm"),
    "heading_deg": ("final_heading", "final |heading error|", 1.0, "deg"),
    "e1": ("final_e1", "final |e1|", 1.0, ""),
    "e2": ("final_e2", "final |e2|", 1.0, ""),
    "e3": ("final_e3", "final |e3|", 1.0, "deg"),
}
#: Names of the verdict's checks (``verdict.checks``), in order; a run has those that apply.
CHECK_NAMES = ("closed_loop", "finished", *(check for check, *_ in _FINAL_CHECKS.values()), "lyapunov", "smoothness")


def resolve_tolerances(overrides: Mapping[str, float] | None = None) -> dict[str, float]:
    """:data:`DEFAULT_TOLERANCES` with ``overrides``; UsageError for an unknown name or a bad value."""
    tolerances = dict(DEFAULT_TOLERANCES)
    for name, value in (overrides or {}).items():
        if name not in tolerances:
            raise UsageError(f"--tolerance: unknown name {name!r}; use one of {', '.join(DEFAULT_TOLERANCES)}")
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise UsageError(f"--tolerance {name}: the value must be a positive number, got {value!r}")
        tolerances[name] = float(value)
    return tolerances


def image_error_signal(run: RunData, name: str) -> np.ndarray:
    """An image error per step: e1, e2, ebar2 (x_h units) or e3 (degrees); NaN when lost."""
    values = run.state[name]
    return np.degrees(values) if name == "e3" else values


def pose_error_signals(run: RunData) -> dict[str, np.ndarray] | None:
    """Per step, ``position_m`` and ``heading_deg`` (in [-180, 180)) from the taught pose; None without ground truth."""
    if not run.has_poses():
        return None
    difference = run.true_pose - run.desired_pose
    return {
        "position_m": np.hypot(difference[:, 0], difference[:, 1]),
        "heading_deg": np.degrees(wrap_angle(difference[:, 2])),
    }


def _run_summary(run: RunData, label: str | None) -> RunSummary:
    settings = run.info.get("settings") or {}
    if label is None:  # no --label: the run's law ("replay" for an open-loop replay)
        label = "replay" if run.info.get("mode") == "replay" else str(run.info.get("law") or run.info.get("mode") or "run")
    return RunSummary(
        name=run.name, label=label, duration_s=run.duration_s,
        steps=run.steps, rate_hz=sample_rate_hz(run.state["t"]), law=run.info.get("law"),
        gains=dict(run.info.get("gains") or {}), source=Source(mode=run.info.get("mode"), fit_file=settings.get("input")),
        truncated=bool(run.truncated),
    )


def _error_summaries(run: RunData, signals: Mapping[str, np.ndarray] | None, tolerances: Mapping[str, float]) -> dict[str, ErrorSummary] | None:
    if signals is None:
        return None
    return {name: ErrorSummary(**error_summary(run.state["t"], signal, tolerances[name])) for name, signal in signals.items()}


#: dhat has learnt the depth once it stays within this fraction of d* (else of its final value).
DEPTH_LEARNT_BAND = 0.10
#: The end window (fraction of the run) over which dhat's drift is measured.
DEPTH_END_WINDOW = 0.10
#: dhat is still moving when it drifts faster than this (fraction of its reference per second).
DEPTH_MOVING_RATE = 0.005
#: ... unless it ends within this fraction of d*: under pixel noise it wanders about d* while (31) holds it.
DEPTH_SETTLED_BAND = 0.02


def depth_learning(t: np.ndarray, dhat: np.ndarray, reference: float) -> tuple[float | None, float | None]:
    """How dhat (m, NaN where not logged) learnt ``reference`` (d*, or dhat's final value).

    Returns the time (s) after which dhat stays within :data:`DEPTH_LEARNT_BAND` of it and
    dhat's slope over :data:`DEPTH_END_WINDOW` as a fraction of ``reference`` per second
    (each None when unknown).
    """
    keep = np.isfinite(dhat)
    t, dhat = t[keep], dhat[keep]
    if t.size == 0 or not (math.isfinite(reference) and reference > 0.0):
        return None, None
    learning = settling_time(t, dhat - reference, DEPTH_LEARNT_BAND * reference)
    end = t >= t[-1] - DEPTH_END_WINDOW * (t[-1] - t[0])
    rate = None
    if np.count_nonzero(end) >= 3 and np.ptp(t[end]) > 0.0:
        rate = float(np.polyfit(t[end], dhat[end], 1)[0]) / reference
    return learning, rate


def true_depth(run: RunData) -> float | None:
    """The true d* (m) a simulated run records; None otherwise."""
    d_true = run.info.get("d_true")
    return float(d_true) if isinstance(d_true, (int, float)) and d_true > 0 else None


def _route_steps(run: RunData) -> tuple[dict[str, Any], np.ndarray] | None:
    """A route run's ``route`` record and the segment in force at each step (as :func:`_route`
    splits it: a step at a switch's time is the new segment's); None for one target's run."""
    route = run.info.get("route")
    if not isinstance(route, dict):
        return None
    return route, np.searchsorted(np.asarray(route["switch_times"], dtype=float), run.state["t"], side="right")


def true_depth_along(run: RunData) -> np.ndarray | None:
    """The true d* (m) at each step: a route's d*_i of the segment in force; None if not simulated."""
    steps = _route_steps(run)
    if steps is not None:
        depths = steps[0]["d_true"]
        return None if any(depth is None for depth in depths) else np.asarray(depths, dtype=float)[steps[1]]
    d_true = true_depth(run)
    return None if d_true is None else np.full(run.state["t"].size, d_true)


def taught_commands_along(run: RunData) -> tuple[np.ndarray, np.ndarray]:
    """The taught commands (25) at each step (m/s, rad/s), at the true d* (a route's: its
    segment's); else at the fit's dhat(0) for a replay (open loop: its dhat adapted on errors
    no command corrected, no estimate of d*; a route's carried to each segment by its rho);
    else at the final dhat."""
    depth: Any = true_depth_along(run)
    if depth is None:
        dhat = run.state["dhat"][np.isfinite(run.state["dhat"])]
        depth = float(dhat[-1]) if dhat.size else float("nan")
        if run.info.get("mode") == "replay" and isinstance(run.info.get("dhat0"), (int, float)):
            depth = float(run.info["dhat0"])
            steps = _route_steps(run)
            if steps is not None:
                depth = depth * np.cumprod([1.0, *steps[0]["depth_ratios"]])[steps[1]]
    return taught_commands(run.state["x_hd2"], run.state["x_hd1_dot"], run.state["theta_d_dot"], depth)


def _depth(run: RunData) -> Depth:
    dhat = run.state["dhat"]
    finite = dhat[np.isfinite(dhat)]
    d_true = true_depth(run)
    dhat_final = float(finite[-1]) if finite.size else None
    relative = abs(dhat_final - d_true) / d_true if d_true is not None and dhat_final is not None else None
    reference = d_true if d_true is not None else dhat_final
    learning, rate = depth_learning(run.state["t"], dhat, reference) if reference is not None else (None, None)
    moving = (rate is not None and abs(rate) > DEPTH_MOVING_RATE
              and not (relative is not None and relative <= DEPTH_SETTLED_BAND))
    return Depth(
        dhat0=float(finite[0]) if finite.size else None, dhat_final=dhat_final, d_true=d_true, relative_error=relative,
        learning_reference=None if reference is None else ("d_true" if d_true is not None else "dhat_final"),
        learning_time_s=learning, end_rate_per_s=rate, still_moving=moving,
        warning=(f"dhat is still moving at the end of the run ({100.0 * rate:+.2g} % per second): "
                 "the depth is not learnt yet; a longer run, a better --dhat0 or a larger --gamma would help")
        if moving else None,
    )


def run_limits(run: RunData) -> Limits:
    """The run's actuator limits (``settings.limits``); None where unlimited."""
    limits = ((run.info.get("settings") or {}).get("limits")) or {}
    return Limits(**{name: (float(limits[name]) if isinstance(limits.get(name), (int, float)) and limits[name] > 0 else None)
                     for name in Limits.__dataclass_fields__})


def _commands(run: RunData) -> Commands:
    v, w, t = run.state["v_c"], run.state["w_c"], run.state["t"]
    limits = run_limits(run)
    taught = command_smoothness(t, *taught_commands_along(run))
    del taught["at_limit_fraction"]
    return Commands(
        v_peak_mps=peak_abs(v), v_rms_mps=rms(v), w_peak_radps=peak_abs(w), w_rms_radps=rms(w),
        saturated_fraction=float(np.mean(run.saturated)),
        **command_smoothness(t, v, w, limits.max_v, limits.max_w, limits.max_accel),
        limits=limits, taught=TaughtSmoothness(**taught),
    )


def _target(run: RunData) -> Target:
    # run.lost holds through drops, so the longest loss spans them.
    dropped = run.dropped if run.dropped is not None else np.zeros(run.steps, dtype=bool)
    return Target(
        lost_frames=int(np.count_nonzero(run.lost)), lost_fraction=float(np.mean(run.lost)),
        longest_loss_s=longest_true_run_s(run.state["t"], run.lost),
        dropped_frames=int(np.count_nonzero(dropped)), dropped_fraction=float(np.mean(dropped)),
    )


def _timing(run: RunData) -> Timing | None:
    """A live run's loop timing (None for other runs): frame-to-command latency and frame interval (ms), frames dropped or late."""
    timing = run.timing
    if timing is None or timing["t"].size == 0:
        return None
    latency_ms = 1e3 * timing["latency_s"]
    intervals = timing["frame_interval_s"][np.isfinite(timing["frame_interval_s"])]
    return Timing(
        latency_p50_ms=float(np.percentile(latency_ms, 50)), latency_p95_ms=float(np.percentile(latency_ms, 95)),
        latency_p99_ms=float(np.percentile(latency_ms, 99)), latency_max_ms=float(np.max(latency_ms)),
        frame_interval_p50_ms=float(1e3 * np.median(intervals)) if intervals.size else None,
        frame_interval_max_ms=float(1e3 * np.max(intervals)) if intervals.size else None,
        frames_dropped=int(np.nansum(timing["dropped"])), frames_late=int(np.nansum(timing["late"])),
    )


def _condition35(run: RunData) -> Condition35:
    fitted = (run.info.get("condition35") or {}).get("min_abs_xhd1_dot")
    return Condition35(
        min_abs_xhd1_dot=min_abs(run.state["x_hd1_dot"]),
        fit_min_abs_xhd1_dot=float(fitted) if isinstance(fitted, (int, float)) else None,
    )


def _check(passed: bool | None, text: str) -> tuple[bool | None, str]:
    """A verdict line: ``pass: ...``, ``fail: ...`` or, for a check not made, ``skip: ...``."""
    prefix = {True: "pass", False: "fail", None: "skip"}[passed]
    return passed, f"{prefix}: {text}"


def _quantity(value: float, scale: float, unit: str) -> str:
    return f"{value * scale:.3g}" + (f" {unit}" if unit else "")


def _final_error_check(name: str, final: float | None, tolerance: float) -> tuple[bool | None, str]:
    _, label, scale, unit = _FINAL_CHECKS[name]
    bound = _quantity(tolerance, scale, unit)
    if final is None:
        return _check(False, f"{label} unknown (target not seen at the end), tolerance {bound}")
    within = final <= tolerance
    return _check(within, f"{label} {_quantity(final, scale, unit)} {'<=' if within else '>'} {bound}")


def _finished_check(run: RunData) -> tuple[bool | None, str]:
    # The error event (time in s, text) with which hbvs repeat stopped the run, if any.
    stop = next(((t, text) for t, level, text in run.events if level >= LOG_ERROR), None)
    if stop is not None:
        return _check(False, f"run stopped at t = {stop[0]:.2f} s ({stop[1]})")
    if run.truncated:
        return _check(False, "the file is truncated: the run did not finish")
    return _check(True, f"run finished ({run.duration_s:.2f} s, {run.steps} steps)")


def _lyapunov_check(lyapunov: Lyapunov) -> tuple[bool | None, str]:
    if lyapunov.ratio is None:
        return _check(None, "V unknown (it needs the true depth d*): not checked")
    fell = lyapunov.ratio < V_RATIO_BOUND
    return _check(fell, f"V final / V(0) = {lyapunov.ratio:.3g} {'<' if fell else '>='} {V_RATIO_BOUND:g}")


def _smoothness_check(commands: Commands) -> tuple[bool | None, str]:
    parts, passed = [], True
    for name, value, taught, floor, unit in (
        ("v", commands.dv_dt_rms_mps2, commands.taught.dv_dt_rms_mps2, SMOOTHNESS_FLOOR_V, "m/s^2"),
        ("w", commands.dw_dt_rms_radps2, commands.taught.dw_dt_rms_radps2, SMOOTHNESS_FLOOR_W, "rad/s^2"),
    ):
        if value is None:
            return _check(None, "command smoothness unknown (fewer than two steps): not checked")
        bound = SMOOTHNESS_FACTOR * (taught or 0.0) + floor  # the most that is not chatter (floor: the start's correction)
        within = value <= bound
        passed = passed and within
        parts.append(f"RMS d{name}/dt {value:.3g} {'<=' if within else '>'} {bound:.3g} {unit}")
    return _check(passed, "commands smooth: " + ", ".join(parts) if passed else "commands chatter: " + ", ".join(parts))


def verdict(run: RunData, errors: Mapping[str, ErrorSummary], pose_error: Mapping[str, ErrorSummary] | None,
            lyapunov: Lyapunov, commands: Commands, tolerances: Mapping[str, float]) -> Verdict:
    """Whether the run converged (docs/report.md's rule), with a ``pass``, ``fail`` or ``skip`` line per check."""
    checks: dict[str, tuple[bool | None, str]] = {}
    if run.info.get("mode") == "replay":
        checks["closed_loop"] = _check(False, "open-loop replay: the commands were computed on the recorded frames, not "
                                       "executed (nothing moved), so it cannot have converged; dhat adapted on errors no "
                                       "command corrected and is no estimate of d*")
    else:
        checks["closed_loop"] = _check(True, f"closed loop ({run.info.get('mode') or 'unknown mode'})")
    checks["finished"] = _finished_check(run)
    final_errors, names = (pose_error, POSE_ERRORS) if pose_error is not None else (errors, ("e1", "e2", "e3"))
    for name in names:
        checks[_FINAL_CHECKS[name][0]] = _final_error_check(name, final_errors[name].final, tolerances[name])
    checks["lyapunov"] = _lyapunov_check(lyapunov)
    checks["smoothness"] = _smoothness_check(commands)
    return Verdict(
        converged=all(passed is not False for passed, _ in checks.values()),
        checks={name: text for name, (_, text) in checks.items()},
        reasons=[text for _, text in checks.values()],
    )


def build_report(run: RunData, tolerances: Mapping[str, float] | None = None, label: str | None = None) -> RunReport:
    """Every metric of one run (docs/report.md); ``tolerances`` override :data:`DEFAULT_TOLERANCES`."""
    tolerances = resolve_tolerances(tolerances)
    errors = _error_summaries(run, {name: image_error_signal(run, name) for name in IMAGE_ERRORS}, tolerances)
    pose_error = _error_summaries(run, pose_error_signals(run), tolerances)
    lyapunov, commands = Lyapunov(**lyapunov_summary(run.state["V"])), _commands(run)
    return RunReport(
        run=_run_summary(run, label), errors=errors, pose_error=pose_error, lyapunov=lyapunov, depth=_depth(run),
        commands=commands, target=_target(run), condition35=_condition35(run), timing=_timing(run),
        verdict=verdict(run, errors, pose_error, lyapunov, commands, tolerances), route=_route(run),
    )


def _route(run: RunData) -> list[RouteSegment] | None:
    """A route's segments (the run's ``route`` metadata, :mod:`~hbvs_cli.stages.repeat_route`):
    each from its switch (the first step at or after it) to the next, V (36) and dhat there."""
    route = run.info.get("route")
    if not isinstance(route, dict):
        return None
    t, V, dhat = run.state["t"], run.state["V"], run.state["dhat"]
    starts = np.searchsorted(t, [t[0], *route["switch_times"]])
    ends = [*(starts[1:] - 1), t.size - 1]
    segments = []
    for number, (first, last) in enumerate(zip(starts, ends)):
        d_true = None if route["d_true"][number] is None else float(route["d_true"][number])  # None: no simulated route
        last = max(min(int(last), t.size - 1), int(first))
        finite = V[first:last + 1][np.isfinite(V[first:last + 1])] if first < t.size else np.array([])
        dhat_end = float(dhat[last]) if first < t.size and np.isfinite(dhat[last]) else None
        segments.append(RouteSegment(
            target=int(route["targets"][number]) + 1, target_kind=str(route["target_kinds"][number]),
            t_start=float(t[min(first, t.size - 1)]), V_start=float(finite[0]) if finite.size else None,
            V_end=float(finite[-1]) if finite.size else None, d_true=d_true, dhat_end=dhat_end,
            relative_error=None if dhat_end is None or d_true is None else abs(dhat_end - d_true) / d_true))
    return segments
