"""What a sweep runs: the parameters, the design (grid or scipy.stats.qmc samples), the seeds.

Run ``i`` is point ``i // repeats``, seeded from ``SeedSequence([sweep seed, i])``, so the
command :func:`repeat_command` prints makes it again, byte-identical.
"""

from __future__ import annotations

import hashlib
import math
import shlex
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Mapping, Sequence

import numpy as np

from ..errors import InputError, UsageError
from ..io.limits import check as check_limit
from ..settings.commands import REPEAT, SAMPLING_METHODS, SWEEP
from .parameters import PARAMETERS

#: The start offset ``hbvs repeat`` uses when none is given (m, m, deg).
DEFAULT_OFFSET = tuple(float(v) for v in REPEAT["offset"].fallback.split(","))
#: The occlusion window starts here when only its length is swept.
DEFAULT_OCCLUSION_START = 8.0


@dataclass(frozen=True)
class Axis:

    name: str
    values: tuple[Any, ...] = ()
    low: float | None = None
    high: float | None = None

    @property
    def is_range(self) -> bool:
        return not self.values

    def as_dict(self) -> dict[str, Any]:
        return {"values": list(self.values)} if self.values else {"range": [self.low, self.high]}


@dataclass(frozen=True)
class SweepSpec:

    axes: tuple[Axis, ...]
    fixed: Mapping[str, Any] = field(default_factory=dict)
    sampling: str = SWEEP["sampling"].fallback
    samples: int = SWEEP["samples"].fallback
    repeats: int = SWEEP["repeats"].fallback
    seed: int = SWEEP["seed"].fallback

    def as_dict(self) -> dict[str, Any]:
        return {
            "vary": {axis.name: axis.as_dict() for axis in self.axes}, "fixed": dict(self.fixed), "sampling": self.sampling,
            "samples": self.samples if self.sampling != "grid" else None, "repeats": self.repeats, "seed": self.seed,
        }


def _check_value(name: str, value: Any, where: str) -> Any:
    """A parameter value of the right type and range."""
    _known(name, where)
    parameter = PARAMETERS[name]
    if parameter.kind == "choice":
        choices = parameter.choices  # the laws: those registered (core/laws.py), any added since too
        if not isinstance(value, str) or value not in choices:
            raise UsageError(f"{where}: {name} must be one of {', '.join(choices)}, got {value!r}")
        return value
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            raise UsageError(f"{where}: {name} must be a number ({parameter.unit or 'dimensionless'}), got {value!r}") from None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise UsageError(f"{where}: {name} must be a finite number, got {value!r}")
    violation = parameter.bound_violation(value)
    if violation is not None:
        raise UsageError(f"{where}: {violation}")
    if parameter.kind == "int":
        if float(value) != int(value):
            raise UsageError(f"{where}: {name} must be a whole number, got {value!r}")
        return int(value)
    return float(value)


def _known(name: str, where: str) -> None:
    if name not in PARAMETERS:
        raise UsageError(f"{where}: unknown parameter {name!r}; choose from {', '.join(PARAMETERS)}")


def parse_vary(text: str) -> Axis:
    """``--vary NAME=LO:HI:N`` (a grid, ends included), ``NAME=LO:HI`` (sampled) or ``NAME=A,B,C``."""
    name, sep, rest = text.partition("=")
    name = name.strip()
    where = f"--vary {text}"
    if not sep or not rest.strip():
        raise UsageError(f"--vary must be NAME=LO:HI:N, NAME=LO:HI or NAME=A,B,C, got {text!r}")
    _known(name, where)
    if ":" in rest:
        parts = rest.split(":")
        if len(parts) not in (2, 3) or PARAMETERS[name].kind == "choice":
            raise UsageError(f"{where}: a range is LO:HI:N (a grid) or LO:HI (sampled), for a number")
        low, high = (_check_value(name, p, where) for p in parts[:2])
        try:
            count = None if len(parts) == 2 else int(parts[2])
        except ValueError:
            count = 0
        if count is not None and count < 1:
            raise UsageError(f"{where}: N must be a whole number >= 1, got {parts[2]!r}")
        return _span_axis(name, low, high, count, where)
    return _list_axis(name, [p.strip() for p in rest.split(",")], where)


def _list_axis(name: str, values: Sequence[Any], where: str) -> Axis:
    checked = tuple(_check_value(name, v, where) for v in values)
    if not checked:
        raise UsageError(f"{where}: no values")
    if len(set(checked)) != len(checked):
        raise UsageError(f"{where}: a value is listed twice")
    return Axis(name, values=checked)


def _span_axis(name: str, low: float, high: float, count: int | None, where: str) -> Axis:
    """LO to HI: sampled (``count`` None) or a grid of ``count`` values, ends included."""
    if count is None:
        if not high > low:
            raise UsageError(f"{where}: a range needs LO < HI")
        return Axis(name, low=float(low), high=float(high))
    check_limit("sweep-runs", count, f"{where}: the grid's values")
    values = np.linspace(low, high, count) if count > 1 else np.array([low])
    if PARAMETERS[name].kind == "int":
        return _list_axis(name, sorted({int(round(v)) for v in values}), where)
    # 12 significant digits: 0.05, not linspace's 0.05000000000000002, in tables and commands.
    return _list_axis(name, [float(f"{v:.12g}") for v in values], where)


def _axis_from_toml(name: str, value: Any) -> Axis:
    where = f"spec [vary] {name}"
    _known(name, where)
    if isinstance(value, list):
        return _list_axis(name, value, where)
    if isinstance(value, dict):
        unknown = set(value) - {"from", "to", "steps"}
        if unknown or "from" not in value or "to" not in value:
            raise UsageError(f"{where}: write a list of values, or {{from = LO, to = HI}} (sampled) with steps = N for a grid")
        low, high = _check_value(name, value["from"], where), _check_value(name, value["to"], where)
        steps = value.get("steps")
        if "steps" in value and (isinstance(steps, bool) or not isinstance(steps, int) or steps < 1):
            raise UsageError(f"{where}: steps must be a whole number >= 1")
        return _span_axis(name, low, high, steps, where)
    return _list_axis(name, [value], where)


def load_spec_file(path: Path) -> dict[str, Any]:
    """The TOML spec as a dictionary (:func:`build_spec`)."""
    from ..settings.config import MAX_CONFIG_BYTES, tomllib
    from ..io.text_files import read_small_text

    try:
        data = tomllib.loads(read_small_text(path, MAX_CONFIG_BYTES, "a TOML sweep spec"))
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: not a valid TOML sweep spec ({exc})") from None
    unknown = set(data) - {"seed", "repeats", "sampling", "samples", "vary", "fixed"}
    if unknown:
        raise UsageError(f"{path}: unknown keys {', '.join(sorted(unknown))}; a spec has seed, repeats, sampling, samples, [vary], [fixed]")
    return data


def build_spec(
    file_data: Mapping[str, Any] | None,
    vary: Sequence[str] = (),
    fixed: Sequence[str] = (),
    repeats: int | None = None,
    seed: int | None = None,
    sampling: str | None = None,
    samples: int | None = None,
) -> SweepSpec:
    """The spec file's contents overridden by ``--vary`` (an axis) and ``--set`` (a fixed value)."""
    data = dict(file_data or {})
    vary_table = data.get("vary", {})
    if not isinstance(vary_table, dict):
        raise UsageError("spec: [vary] must be a table")
    axes = {name: _axis_from_toml(name, value) for name, value in vary_table.items()}
    for text in vary:
        axis = parse_vary(text)
        axes[axis.name] = axis
    fixed_table = data.get("fixed", {})
    if not isinstance(fixed_table, dict):
        raise UsageError("spec: [fixed] must be a table")
    fixed_values = {name: _check_value(name, value, "spec [fixed]") for name, value in fixed_table.items()}
    for text in fixed:
        name, sep, value = text.partition("=")
        name = name.strip()
        if not sep:
            raise UsageError(f"--set must be NAME=VALUE, got {text!r}")
        fixed_values[name] = _check_value(name, value.strip(), f"--set {text}")
        axes.pop(name, None)
    for name in list(fixed_values):
        if name in axes:
            raise UsageError(f"{name} is both varied and fixed; keep one")
    if "dhat0" in axes and "dhat0_factor" in axes or ("dhat0" in fixed_values and "dhat0_factor" in fixed_values):
        raise UsageError("give dhat0 or dhat0_factor, not both")
    method, count, repeat_count, sweep_seed = (SWEEP[name].resolve(given, data) for name, given in (
        ("sampling", sampling), ("samples", samples), ("repeats", repeats), ("seed", seed)))
    if method not in SAMPLING_METHODS:
        raise UsageError(f"sampling must be one of {', '.join(SAMPLING_METHODS)}, got {method!r}")
    for label, value in (("samples", count), ("repeats", repeat_count), ("seed", sweep_seed)):
        if isinstance(value, bool) or not isinstance(value, int) or value < SWEEP[label].bounds["min"]:
            raise UsageError(f"{label} must be a whole number >= {SWEEP[label].bounds['min']}, got {value!r}")
    ordered = tuple(axes.values())
    _check_size(ordered, method, count, repeat_count)
    if method == "grid":
        ranged = [a.name for a in ordered if a.is_range]
        if ranged:
            raise UsageError(
                f"a grid needs values for {', '.join(ranged)}: give LO:HI:N (or steps = N), or sample the range with --sampling sobol"
            )
    if not ordered:
        raise UsageError("nothing varies: give --vary NAME=... or a spec with a [vary] table (--repeats alone: --vary law=lateral-gain)")
    return SweepSpec(axes=ordered, fixed=fixed_values, sampling=method, samples=count, repeats=repeat_count, seed=sweep_seed)


def _check_size(axes: Sequence[Axis], method: str, samples: int, repeats: int) -> None:
    """Refuse more runs than the ``sweep-runs`` limit before the design matrix is allocated."""
    sampled = method != "grid" and any(axis.is_range for axis in axes)
    if sampled:
        check_limit("sweep-runs", samples, "--samples")
    check_limit("sweep-runs", repeats, "--repeats")
    runs = repeats * (samples if sampled else 1) * math.prod(max(1, len(axis.values)) for axis in axes)
    check_limit("sweep-runs", runs, "the sweep (points x samples x repeats)")


def _qmc_unit_samples(method: str, dimensions: int, count: int, seed: int) -> np.ndarray:
    """``count`` points in [0, 1)^dimensions, seeded."""
    rng = np.random.default_rng(seed)
    if method == "random":
        return rng.random((count, dimensions))
    from scipy.stats import qmc

    engine_class = {"sobol": qmc.Sobol, "halton": qmc.Halton, "lhs": qmc.LatinHypercube}[method]
    try:
        engine = engine_class(dimensions, rng=rng)
    except TypeError:  # scipy < 1.15 calls it seed
        engine = engine_class(dimensions, seed=rng)
    with warnings.catch_warnings():
        # Sobol's balance wants a power of two; any count is still a valid sample.
        warnings.simplefilter("ignore", UserWarning)
        return engine.random(count)


@dataclass(frozen=True)
class RunSettings:

    index: int
    point: int
    repeat: int
    seed: int
    values: dict[str, Any]


def run_seed(sweep_seed: int, index: int) -> int:
    """The seed of run ``index`` (a 32-bit integer ``hbvs repeat --seed`` takes)."""
    return int(np.random.SeedSequence([sweep_seed, index]).generate_state(1, dtype=np.uint32)[0])


class SweepPlan:
    """The runs of a spec, made one at a time from their index."""

    def __init__(self, spec: SweepSpec) -> None:
        self.spec = spec
        self.listed = [a for a in spec.axes if not a.is_range]
        self.ranged = [a for a in spec.axes if a.is_range]
        self._list_sizes = [len(a.values) for a in self.listed]
        self._samples = np.zeros((1, 0))  # one point of no ranged value, without ranges
        if self.ranged:
            unit = _qmc_unit_samples(spec.sampling, len(self.ranged), spec.samples, spec.seed)
            low = np.array([a.low for a in self.ranged])
            high = np.array([a.high for a in self.ranged])
            self._samples = low + unit * (high - low)

    @property
    def points(self) -> int:
        return int(np.prod(self._list_sizes)) * len(self._samples)

    @property
    def runs(self) -> int:
        return self.points * self.spec.repeats

    @property
    def swept(self) -> list[str]:
        return [a.name for a in self.spec.axes]

    def point_values(self, point: int) -> dict[str, Any]:
        """The swept values of a point: listed values vary slowest, samples fastest (so every law meets the same sampled points)."""
        combination, sample = divmod(point, len(self._samples))
        values = {axis.name: axis.values[int(position)]
                  for axis, position in zip(self.listed, np.unravel_index(combination, self._list_sizes))}
        for axis, value in zip(self.ranged, self._samples[sample]):
            values[axis.name] = int(round(value)) if PARAMETERS[axis.name].kind == "int" else float(value)
        return {name: values[name] for name in self.swept}

    def run(self, index: int) -> RunSettings:
        point, repeat = divmod(index, self.spec.repeats)
        values = dict(self.spec.fixed) | self.point_values(point)
        return RunSettings(index=index, point=point, repeat=repeat, seed=run_seed(self.spec.seed, index), values=values)

    def __iter__(self) -> Iterator[RunSettings]:
        return (self.run(i) for i in range(self.runs))


def repeat_arguments(values: Mapping[str, Any], seed: int, d_true: float | None) -> dict[str, Any]:
    """The ``RepeatOptions`` fields (besides input and output) of a run's values; numbers as
    ``repr`` text, as the printed command gives them, so a re-make reads identical options."""
    options: dict[str, Any] = {"sim": True, "seed": int(seed)}
    if any(k in values for k in ("offset_x", "offset_y", "offset_theta")):
        offset = [values.get(k, d) for k, d in zip(("offset_x", "offset_y", "offset_theta"), DEFAULT_OFFSET)]
        options["offset"] = ",".join(repr(float(v)) for v in offset)
    if "dhat0" in values:
        options["dhat0"] = float(values["dhat0"])
    elif "dhat0_factor" in values:
        if d_true is None:
            raise UsageError("dhat0_factor needs the true d*, which only a fit of a simulated teach has; sweep dhat0 (m) instead")
        options["dhat0"] = float(values["dhat0_factor"]) * d_true
    if values.get("occlusion_length", 0) > 0:
        start = float(values.get("occlusion_start", DEFAULT_OCCLUSION_START))
        options["occlude"] = [f"{start!r}:{start + float(values['occlusion_length'])!r}"]
    for name, parameter in PARAMETERS.items():
        if not parameter.own and name != "dhat0" and name in values:
            options[name] = values[name]
    return options


def repeat_command(fit_path: str, arguments: Mapping[str, Any], output: str = "run.mcap") -> str:
    """The ``hbvs repeat`` command line that makes the same run file, byte for byte."""
    words = ["hbvs", "repeat", fit_path, "--sim"]
    for key, value in arguments.items():
        if key == "sim":
            continue
        option = REPEAT[key].option_names[-1]
        for item in value if isinstance(value, list) else [value]:
            text = repr(item) if isinstance(item, float) else str(item)
            words.append(f"{option}={text}")
    words += ["-o", output]
    return " ".join(shlex.quote(w) for w in words)


def file_digest(path: Path) -> str:
    """SHA-256 of a file (the fit a sweep ran on, to refuse resuming on another)."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()
