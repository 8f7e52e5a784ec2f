"""The parameters a sweep can vary or fix, with their units and the ``hbvs repeat`` option
each sets. No numpy: ``hbvs sweep --help`` lists them without loading the numerical stack."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

from ..core.control_settings import ALL_LAWS, GAIN_NAMES, GAIN_UNITS
from ..io.settings import REPEAT


@dataclass(frozen=True)
class Parameter:
    """A parameter a sweep can vary or fix: ``kind`` float, int or choice; ``setting`` the
    ``hbvs repeat`` option whose bounds it shares, else ``own_bounds`` (min, max)."""

    name: str
    kind: str
    unit: str
    setting: str | None = None
    choices: tuple[str, ...] = ()
    own_bounds: Mapping[str, float] = field(default_factory=dict)

    @property
    def bounds(self) -> Mapping[str, float]:
        return REPEAT[self.setting].bounds if self.setting is not None else self.own_bounds

    def bound_violation(self, value: float) -> str | None:
        """Why ``value`` is out of bounds (``repeat``'s words for its options), or None."""
        if self.setting is not None:
            return REPEAT[self.setting].bound_violation(value)
        low, high = self.own_bounds.get("min", -math.inf), self.own_bounds.get("max", math.inf)
        if not low <= value <= high:
            return f"{self.name} must be within [{low:g}, {high:g}], got {value!r}"
        return None


def _repeat_parameter(name: str, kind: str, unit: str, choices: tuple[str, ...] = ()) -> Parameter:
    return Parameter(name, kind, unit, setting=name, choices=choices)


#: Every parameter a sweep knows, with the ``hbvs repeat`` option it sets.
PARAMETERS: dict[str, Parameter] = {
    p.name: p
    for p in (
        Parameter("offset_x", "float", "m"),  # --offset DX, along the taught start heading
        Parameter("offset_y", "float", "m"),  # --offset DY, to the left
        Parameter("offset_theta", "float", "deg"),  # --offset DTHETA
        _repeat_parameter("dhat0", "float", "m"),
        Parameter("dhat0_factor", "float", "x d*", own_bounds={"min": 0.0}),  # --dhat0 as a multiple of the true d*
        _repeat_parameter("pixel_noise", "float", "px"),
        # The gains (29)-(31); a dimensionless one has no unit.
        *(_repeat_parameter(name, "float", GAIN_UNITS[name].replace("-", "")) for name in GAIN_NAMES),
        _repeat_parameter("law", "choice", "", choices=ALL_LAWS),
        _repeat_parameter("drop_rate", "float", ""),
        _repeat_parameter("outlier_rate", "float", ""),
        Parameter("occlusion_start", "float", "s", own_bounds={"min": 0.0}),  # --occlude START:END
        Parameter("occlusion_length", "float", "s", own_bounds={"min": 0.0}),  # 0: no occlusion
        _repeat_parameter("latency", "int", "frames"),
        _repeat_parameter("perception", "choice", "", choices=("points", "images")),
        _repeat_parameter("rate", "float", "Hz"),
        _repeat_parameter("speed", "float", ""),
        _repeat_parameter("lost_timeout", "float", "s"),
    )
}


def parameter_names_text() -> str:
    """The parameters as help text: ``offset_x (m), ..., law (lateral-gain, paper, ...)``."""
    return ", ".join(
        f"{p.name} ({'|'.join(p.choices) if p.choices else p.unit or '-'})" for p in PARAMETERS.values()
    )
