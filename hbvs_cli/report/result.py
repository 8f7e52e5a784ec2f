"""The report of one run as typed sections (docs/report.md): what ``hbvs report`` prints and
``--json`` writes, in the order declared here. Floats are rounded to :data:`REPORT_DIGITS`
significant digits when a section is made, so the JSON, the tables and ``--fail-above`` agree.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any, Mapping

from ..core.metrics import round_significant

#: Significant digits of every number in a report (float noise is not a measurement).
REPORT_DIGITS = 7


class MissingKey(KeyError):
    """A dotted report key with a part that does not exist: ``where`` lacks ``part``."""

    def __init__(self, where: str, part: str, choices: list[str]) -> None:
        super().__init__(part)
        self.where, self.part, self.choices = where, part, choices


def resolve_key(document: Mapping[str, Any], key: str) -> Any:
    """The value at a dotted key such as ``"pose_error.position_m.final"``; MissingKey if absent."""
    value: Any = document
    parts = key.split(".")
    for index, part in enumerate(parts):
        if not isinstance(value, Mapping) or part not in value:
            choices = list(value) if isinstance(value, Mapping) else []
            raise MissingKey(".".join(parts[:index]) or "the report", part, choices)
        value = value[part]
    return value


@dataclass(frozen=True)
class Section:
    """A report section: its float fields (also inside dicts and lists) rounded on creation."""

    def __post_init__(self) -> None:
        for field in fields(self):
            object.__setattr__(self, field.name, round_significant(getattr(self, field.name), REPORT_DIGITS))


@dataclass(frozen=True)
class Source(Section):
    """Where a run came from: ``mode`` (sim, replay, live) and the fit file it repeated."""

    mode: str | None
    fit_file: str | None


@dataclass(frozen=True)
class RunSummary(Section):
    """The run itself: file, label, duration (s), steps, rate (Hz), law and gains."""

    name: str
    label: str
    duration_s: float
    steps: int
    rate_hz: float | None
    law: str | None
    gains: dict[str, float]
    source: Source
    truncated: bool


@dataclass(frozen=True)
class ErrorSummary(Section):
    """The statistics of one error signal (:data:`hbvs_cli.core.metrics.STATISTICS`) in its unit; None when unknown."""

    rmse: float | None
    mean: float | None
    median: float | None
    std: float | None
    min: float | None
    max: float | None
    initial: float | None
    final: float | None
    settling_time_s: float | None


@dataclass(frozen=True)
class Lyapunov(Section):
    """The Lyapunov function (36): first and last values, their ratio, the fraction of steps at which it rose; None without the true d*."""

    initial: float | None
    final: float | None
    ratio: float | None
    increase_fraction: float | None


@dataclass(frozen=True)
class Depth(Section):
    """The depth estimate dhat (m) against the true d*: how long it took to learn, whether it still moves."""

    dhat0: float | None
    dhat_final: float | None
    d_true: float | None
    relative_error: float | None
    learning_reference: str | None
    learning_time_s: float | None
    end_rate_per_s: float | None
    still_moving: bool
    warning: str | None


@dataclass(frozen=True)
class Limits(Section):
    """The actuator limits of the run (m/s, rad/s, m/s^2); None when unlimited."""

    max_v: float | None
    max_w: float | None
    max_accel: float | None


@dataclass(frozen=True)
class TaughtSmoothness(Section):
    """How smooth the taught commands (25) are: total variations and RMS rates of change."""

    v_tv_per_s: float | None
    w_tv_per_s: float | None
    dv_dt_rms_mps2: float | None
    dw_dt_rms_radps2: float | None


@dataclass(frozen=True)
class Commands(Section):
    """The commands (29), (30): peaks, RMS, saturation and smoothness against the taught ones."""

    v_peak_mps: float | None
    v_rms_mps: float | None
    w_peak_radps: float | None
    w_rms_radps: float | None
    saturated_fraction: float
    v_tv_per_s: float | None
    w_tv_per_s: float | None
    dv_dt_rms_mps2: float | None
    dw_dt_rms_radps2: float | None
    at_limit_fraction: float | None
    limits: Limits
    taught: TaughtSmoothness


@dataclass(frozen=True)
class Target(Section):
    """How often the target was lost, for how long (s), and how many frames were dropped."""

    lost_frames: int
    lost_fraction: float
    longest_loss_s: float
    dropped_frames: int
    dropped_fraction: float


@dataclass(frozen=True)
class Condition35(Section):
    """Condition (35): the least |x_hd1_dot| (1/s) over the run and over the fit."""

    min_abs_xhd1_dot: float | None
    fit_min_abs_xhd1_dot: float | None


@dataclass(frozen=True)
class Timing(Section):
    """A live run's loop: frame-to-command latency and frame interval (ms), frames dropped and late."""

    latency_p50_ms: float
    latency_p95_ms: float
    latency_p99_ms: float
    latency_max_ms: float
    frame_interval_p50_ms: float | None
    frame_interval_max_ms: float | None
    frames_dropped: int
    frames_late: int


@dataclass(frozen=True)
class Verdict:
    """Whether the run converged (:mod:`.build`): each check's line by name, and as a list."""

    converged: bool
    checks: dict[str, str]
    reasons: list[str]

    def failures(self) -> list[str]:
        """The failed checks' lines, without their ``fail: `` prefix."""
        return [text.removeprefix("fail: ") for text in self.reasons if text.startswith("fail")]


#: Sections a run may lack: ``pose_error`` without ground truth, ``timing`` unless live, ``route`` unless a route's.
OPTIONAL_SECTIONS = ("pose_error", "timing", "route")


@dataclass(frozen=True)
class RouteSegment(Section):
    """One segment of a route's run (issue 47): its target, from when (s), V (36) against its
    own d*_i at its start and end (a switch restarts V), and its true d*_i with dhat at its end (m)."""

    target: int
    target_kind: str
    t_start: float
    V_start: float | None
    V_end: float | None
    d_true: float | None
    dhat_end: float | None
    relative_error: float | None


@dataclass(frozen=True)
class RunReport:
    """Every metric of one run (:func:`~hbvs_cli.report.build.build_report`)."""

    run: RunSummary
    errors: dict[str, ErrorSummary]
    pose_error: dict[str, ErrorSummary] | None
    lyapunov: Lyapunov
    depth: Depth
    commands: Commands
    target: Target
    condition35: Condition35
    timing: Timing | None
    verdict: Verdict
    #: A route's segments, in order (None for one target's run).
    route: list[RouteSegment] | None = None

    def to_dict(self) -> dict[str, Any]:
        """The JSON of ``hbvs report --json`` (an absent optional section left out)."""
        return {
            field.name: asdict(value) if hasattr(value, "__dataclass_fields__") else
            [asdict(item) for item in value] if isinstance(value, list) else {name: asdict(item) for name, item in value.items()}
            for field in fields(self)
            if (value := getattr(self, field.name)) is not None or field.name not in OPTIONAL_SECTIONS
        }

    def value(self, key: str) -> Any:
        """The value at a dotted key of :meth:`to_dict` (``--fail-above``, the sweep's columns)."""
        return resolve_key(self.to_dict(), key)
