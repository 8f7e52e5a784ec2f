"""The parameters a sweep can vary or fix, with their units and the ``hbvs repeat`` option
each sets, whose declaration gives its type, choices and bounds. No numpy: ``hbvs sweep --help``
lists them without loading the numerical stack."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

from ..core.control_settings import GAIN_NAMES, GAIN_UNITS
from ..settings.commands import REPEAT


@dataclass(frozen=True)
class Parameter:
    """A parameter a sweep can vary or fix: ``kind`` float, int or choice; ``setting`` the
    ``hbvs repeat`` option whose choices and bounds it shares, else ``own_bounds`` (min, max)."""

    name: str
    kind: str
    unit: str
    setting: str | None = None
    own_bounds: Mapping[str, float] = field(default_factory=dict)

    @property
    def choices(self) -> tuple[str, ...]:
        return REPEAT[self.setting].allowed() if self.setting is not None else ()

    @property
    def bounds(self) -> Mapping[str, float]:
        return REPEAT[self.setting].bounds if self.setting is not None else self.own_bounds

    def bound_violation(self, value: float) -> str | None:
        """Why ``value`` is out of bounds (``repeat``'s words for its options), or None."""
        if self.setting is not None:
            return REPEAT[self.setting].violation(value)
        low, high = self.own_bounds.get("min", -math.inf), self.own_bounds.get("max", math.inf)
        if not low <= value <= high:
            return f"{self.name} must be within [{low:g}, {high:g}], got {value!r}"
        return None


def _repeat_parameter(name: str, unit: str) -> Parameter:
    """The parameter that sets ``repeat``'s option ``name``: a choice if the option has choices, else a number of its type."""
    setting = REPEAT[name]
    return Parameter(name, "choice" if setting.choices else setting.type.__name__, unit, setting=name)


#: Every parameter a sweep knows, with the ``hbvs repeat`` option it sets.
PARAMETERS: dict[str, Parameter] = {
    p.name: p
    for p in (
        Parameter("offset_x", "float", "m"),  # --offset DX, along the taught start heading
        Parameter("offset_y", "float", "m"),  # --offset DY, to the left
        Parameter("offset_theta", "float", "deg"),  # --offset DTHETA
        _repeat_parameter("dhat0", "m"),
        Parameter("dhat0_factor", "float", "x d*", own_bounds={"min": 0.0}),  # --dhat0 as a multiple of the true d*
        _repeat_parameter("pixel_noise", "px"),
        # The gains (29)-(31); a dimensionless one has no unit.
        *(_repeat_parameter(name, GAIN_UNITS[name].replace("-", "")) for name in GAIN_NAMES),
        _repeat_parameter("law", ""),
        _repeat_parameter("drop_rate", ""),
        _repeat_parameter("outlier_rate", ""),
        Parameter("occlusion_start", "float", "s", own_bounds={"min": 0.0}),  # --occlude START:END
        Parameter("occlusion_length", "float", "s", own_bounds={"min": 0.0}),  # 0: no occlusion
        _repeat_parameter("latency", "frames"),
        _repeat_parameter("perception", ""),
        _repeat_parameter("rate", "Hz"),
        _repeat_parameter("speed", ""),
        _repeat_parameter("lost_timeout", "s"),
    )
}


def parameter_names_text() -> str:
    """The parameters as help text: ``offset_x (m), ..., law (lateral-gain, paper, ...)``."""
    return ", ".join(
        f"{p.name} ({'|'.join(p.choices) if p.choices else p.unit or '-'})" for p in PARAMETERS.values()
    )
