"""What every ``hbvs repeat`` run shares, one target's (:mod:`.repeat`) or a route's (:mod:`.repeat_route`): its
settings, state filter, step log, tally and summary, and ``--sim``'s writer loop."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import IO, Any, Callable, Iterable

import numpy as np

from .. import __version__
from ..core.controller import ControllerGains, lyapunov
from ..core.control_settings import FILTER_EKF
from ..core.estimation import PlanarPoseEstimator
from ..core.fit_model import FitModel
from ..core.gains import noise_from_residual
from ..core.metrics import final_value
from ..core.simulator import ActuatorLimits, StepRecord
from ..core.state_filter import ServoStateFilter
from ..errors import TargetLostError, UsageError
from ..io.fit_file import FitFile, fit_summary_records
from ..io.limits import step_count
from ..io.messages import LOG_INFO, LOG_WARNING
from ..io.run_file import RunWriter
from ..settings.commands import RepeatOptions
from ..sim.world import World
from . import live
from .console import Console


@dataclass(frozen=True)
class Settings:
    """The resolved settings of a run: defaults, then the TOML config, then the options."""

    gains: ControllerGains
    law: str
    dhat0: float
    speed: float
    limits: ActuatorLimits
    latency: int
    rate: float
    perception: str
    pixel_noise: float
    offset: tuple[float, float, float]
    lost_timeout: float
    state_filter: str = FILTER_EKF

    def as_dict(self) -> dict[str, Any]:
        offset = {"dx_m": self.offset[0], "dy_m": self.offset[1], "dtheta_deg": math.degrees(self.offset[2])}
        return asdict(self) | {"gains": self.gains.as_dict(), "offset": offset}


@dataclass
class RepeatSummary:
    steps: int
    output: str
    final_errors: dict[str, float]
    dhat: float
    stopped: bool


def check_simulation_settings(settings: Settings, model: FitModel, taught_s: float | None = None) -> None:
    """The checks of a closed-loop run's settings that need the fit; ``taught_s``: the taught duration (s) of a route."""
    if not (math.isfinite(settings.speed) and settings.speed > 0):
        raise UsageError(f"--speed must be a finite positive multiple of the taught pace, got {settings.speed}")
    step_count(
        (model.trajectory.t_end - model.trajectory.t_start if taught_s is None else taught_s) / settings.speed, settings.rate,
        "the run (the taught duration over --speed, times --rate)",
    )


#: With the state filter on, the fixed residual gate only catches gross errors (px).
COARSE_RESIDUAL_GATE_PX = 3.0


def make_state_filter(settings: Settings, model: FitModel, estimator: PlanarPoseEstimator) -> ServoStateFilter | None:
    """The state filter ``--filter`` asks for (None for ``none``), its noise from the fit's residual (docs/method.md, "State filter")."""
    if settings.state_filter != FILTER_EKF:
        return None
    estimator.residual_gate = max(estimator.residual_gate, COARSE_RESIDUAL_GATE_PX / model.camera.mean_focal)
    return ServoStateFilter(model.m_ref, model.normal, detector_noise(model))


def detector_noise(model: FitModel) -> float:
    """Per-coordinate noise of the fit's detector on the taught images (normalised units)."""
    if not math.isfinite(model.residual_px.rms):
        return 0.0
    return noise_from_residual(model.residual_px.rms, model.m_ref.shape[0]) / model.camera.mean_focal


class StepLog:
    """Each step record as run file messages and a command; events when the target is lost or back, etc."""

    def __init__(self, run: RunWriter, settings: Settings, model: FitModel, d_true: float | None, cmd_stream: IO[str] | None) -> None:
        self.run, self.settings, self.model, self.d_true, self.cmd_stream = run, settings, model, d_true, cmd_stream
        self.event = run.event
        self.was_saturated = self.was_lost = self.was_dropped = False
        self.lost_reason = ""

    def step(self, record: StepRecord) -> None:
        t, output, measurement = record.t, record.output, record.measurement
        errors = output.errors if output is not None else None
        V = None
        if errors is not None and self.d_true is not None:
            V = lyapunov(errors, record.dhat, self.d_true, self.settings.gains)
        # A dropped frame keeps the lost state and reason of the last frame that arrived.
        if not record.dropped:
            self.lost_reason = record.observation.status if record.lost else ""
        if record.lost and not self.was_lost:
            action = "driving on the state filter's prediction" if output is not None else "stopping"
            self.event(t, LOG_WARNING, f"target lost ({self.lost_reason}): {action}, adaptation frozen")
        elif not record.lost and self.was_lost:
            self.event(t, LOG_INFO, "target back: tracking resumed")
        self.was_lost = record.lost
        if record.dropped and not self.was_dropped:
            self.event(t, LOG_INFO, "camera frame dropped: " + ("target still lost" if record.lost else "holding the last command"))
        self.was_dropped = record.dropped
        if record.saturated and not self.was_saturated:
            self.event(t, LOG_INFO, "command saturated by the actuator limits")
        self.was_saturated = record.saturated
        # The run file's state, in its order of fields (the bytes depend on it).
        values = {
            **{name: getattr(measurement, name) if measurement else None for name in ("x_h1", "x_h2", "theta")},
            **{name: getattr(record.desired, name) for name in ("x_hd1", "x_hd2", "theta_d", "x_hd1_dot", "x_hd2_dot", "theta_d_dot")},
            **{name: getattr(errors, name) if errors else None for name in ("e1", "e2", "ebar2", "e3")},
            "v_c": record.v_c, "w_c": record.w_c,
            "v_law": float(output.v_c) if output is not None else None,
            "w_law": float(output.w_c) if output is not None else None,
            "saturated": bool(record.saturated),
            "dhat": float(record.dhat),
            "target_lost": bool(record.lost),
            "lost_reason": self.lost_reason if record.lost else "",
            "frame_dropped": bool(record.dropped),
            "residual": float(record.observation.residual),
            "V": V,
        }
        estimate = record.estimate
        if estimate is None:
            values |= {"filter": "", "theta_est": None, "x_h1_est": None, "x_h2_est": None,
                       "theta_std": None, "x_h1_std": None, "x_h2_std": None, "noise_px": None}
        else:
            state, std = estimate.measurement, estimate.std.tolist()
            values |= {
                "filter": estimate.outcome,
                "theta_est": float(state.theta), "x_h1_est": float(state.x_h1), "x_h2_est": float(state.x_h2),
                "theta_std": std[0], "x_h1_std": std[1], "x_h2_std": std[2],
                "noise_px": estimate.noise * self.model.camera.mean_focal,
            }
        self.run.state(t, values)
        self.run.command(t, record.v_c, record.w_c, record.saturated)
        live.write_command(self.cmd_stream, t, record.v_c, record.w_c)


class Tally:
    """What the one-line summary needs, per step; its "final" errors are the report's (:func:`hbvs_cli.core.metrics.final_value`)."""

    def __init__(self) -> None:
        self.series: dict[str, list[float]] = {name: [] for name in ("t", "e1", "e2", "e3_deg", "position_m", "heading_deg")}

    def add(self, record: StepRecord, taught: list[float] | None = None) -> None:
        errors = record.output.errors if record.output is not None else None
        values = dict.fromkeys(self.series, math.nan) | {"t": record.t}
        if errors is not None:
            values.update(e1=float(errors.e1), e2=float(errors.e2), e3_deg=math.degrees(float(errors.e3)))
        if taught is not None:
            values["position_m"] = math.hypot(record.pose[0] - taught[0], record.pose[1] - taught[1])
            values["heading_deg"] = math.degrees(float(np.angle(np.exp(1j * (record.pose[2] - taught[2])))))
        for name, value in values.items():
            self.series[name].append(float(value))


def run_metadata(mode: str, options: RepeatOptions, settings: Settings, fit: FitFile, d_true: float | None,
                 world: World | None = None) -> dict[str, Any]:
    """The run file's metadata; ``world``: the simulated one, whose wall and target the report's top view draws."""
    model = fit.model
    return {
        "file_kind": "run", "hbvs_version": __version__, "mode": mode, "law": settings.law, "gains": settings.gains.as_dict(),
        "settings": settings.as_dict() | {
            "seed": options.seed, "input": str(options.input), "replay": str(options.replay) if options.replay else None,
            "faults": {
                "occlude": options.occlude, "drop_rate": options.drop_rate,
                "outlier_rate": options.outlier_rate, "exposure_step": options.exposure_step,
            },
            "record_images": options.record_images,
        },
        "d_true": d_true, "dhat0": settings.dhat0, "target_kind": model.target_kind,
    } | fit_summary_records(model) | ({"top_view": _top_view(world)} if world is not None else {})


def _top_view(world: World) -> dict[str, Any]:
    """The wall and the target from above (m, world frame), for the report's top view."""
    poster = world.target.poster
    ends = [poster.center + side * 0.5 * poster.width * poster.right for side in (-1.0, 1.0)]
    return {
        "wall_x": float(world.wall_x),
        "poster_y": [float(end[1]) for end in ends],
        "target_xy": [[float(x), float(y)] for x, y in world.target.points_world[:, :2]],
    }


def finish(console: Console, tally: Tally, dhat: float, output: str, settings: Settings, d_true: float | None,
           stopped: str | None) -> RepeatSummary:
    """The run's summary (``dhat``: the controller's last, m), printed; TargetLostError when the run was ``stopped`` (why)."""
    t = tally.series["t"]
    finals = {name: final_value(t, series) for name, series in tally.series.items() if t and name != "t"}
    e = {name: final for name, final in finals.items() if final is not None}
    summary = RepeatSummary(steps=len(t), output=output, final_errors=e, dhat=dhat, stopped=stopped is not None)
    parts = [f"repeat: {summary.steps} steps ({settings.law})"]
    final = []
    if "e1" in e:
        final.append(f"|e1| {e['e1']:.3g}, |e2| {e['e2']:.3g}, |e3| {e['e3_deg']:.3g} deg")
    if "position_m" in e:
        final.append(f"position {100 * e['position_m']:.3g} cm, |heading| {e['heading_deg']:.3g} deg")
    if final:
        parts.append("final (mean over the last 5 %, as in hbvs report): " + ", ".join(final))
    parts.append(f"dhat {summary.dhat:.3f} m" + (f" (d* {d_true:.3f} m)" if d_true is not None else ""))
    console.info("; ".join(parts) + f" -> {summary.output}")
    if stopped is not None:
        raise TargetLostError(f"{stopped}; the run up to then is in {output}")
    return summary


def drive_simulation(console: Console, label: str, total: int, records: Iterable[StepRecord], log: StepLog, dt: float, taught: list,
                     height: float, each: Callable[[int, StepRecord], None] = lambda k, record: None) -> tuple[Tally, str | None]:
    """``--sim``'s writer loop (one target's or a route's): per step, its record, true and ``taught`` pose (x, y, phi;
    camera ``height``, m), then ``each(k, record)``. The tally, and why --lost-timeout stopped the run (None: it did not)."""
    tally = Tally()
    lost = live.LostWatch(log.settings.lost_timeout, log)
    with console.progress(label, total) as bar:
        for k, record in enumerate(records):
            log.step(record)
            log.run.poses(record.t, record.pose, taught[k], height)
            each(k, record)
            tally.add(record, taught[k])
            bar.advance()
            if lost.stops(record, dt):
                break
    return tally, lost.stopped
