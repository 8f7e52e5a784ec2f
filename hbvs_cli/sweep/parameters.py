"""The parameters a sweep can vary or fix, with their units and the ``hbvs repeat`` option
each sets, whose declaration gives its type, choices and bounds. No numpy: ``hbvs sweep --help``
lists them without loading the numerical stack."""

from __future__ import annotations

from dataclasses import dataclass

from ..core.control_settings import GAIN_NAMES, GAIN_UNITS
from ..settings.commands import REPEAT
from ..settings.option import Setting


@dataclass(frozen=True)
class Parameter:
    """A parameter a sweep can vary or fix, in ``unit``: the ``hbvs repeat`` option it sets (``setting``, whose
    type, choices and bounds it shares), or one of its own (``own``) that sets repeat's options its way."""

    setting: Setting
    unit: str
    own: bool = False

    @property
    def name(self) -> str:
        return self.setting.name

    @property
    def kind(self) -> str:
        """float, int or choice."""
        return "choice" if self.setting.choices else self.setting.type.__name__

    @property
    def choices(self) -> tuple[str, ...]:
        return self.setting.allowed()

    def bound_violation(self, value: float) -> str | None:
        """Why ``value`` is out of bounds (``repeat``'s words for its options), or None."""
        return self.setting.violation(value, self.name if self.own else None)


def _own_parameter(name: str, unit: str, **bounds: float) -> Parameter:
    """A parameter of the sweep's own, a float (m, deg, s or a factor) within ``bounds`` (min, max)."""
    return Parameter(Setting(name, float, "", bounds=bounds), unit, own=True)


#: Every parameter a sweep knows, with the ``hbvs repeat`` option it sets.
PARAMETERS: dict[str, Parameter] = {
    p.name: p
    for p in (
        _own_parameter("offset_x", "m"),  # --offset DX, along the taught start heading
        _own_parameter("offset_y", "m"),  # --offset DY, to the left
        _own_parameter("offset_theta", "deg"),  # --offset DTHETA
        Parameter(REPEAT["dhat0"], "m"),
        _own_parameter("dhat0_factor", "x d*", min=0.0),  # --dhat0 as a multiple of the true d*
        Parameter(REPEAT["pixel_noise"], "px"),
        # The gains (29)-(31); a dimensionless one has no unit.
        *(Parameter(REPEAT[name], GAIN_UNITS[name].replace("-", "")) for name in GAIN_NAMES),
        Parameter(REPEAT["law"], ""),
        Parameter(REPEAT["drop_rate"], ""),
        Parameter(REPEAT["outlier_rate"], ""),
        _own_parameter("occlusion_start", "s", min=0.0),  # --occlude START:END
        _own_parameter("occlusion_length", "s", min=0.0),  # 0: no occlusion
        Parameter(REPEAT["latency"], "frames"),
        Parameter(REPEAT["perception"], ""),
        Parameter(REPEAT["rate"], "Hz"),
        Parameter(REPEAT["speed"], ""),
        Parameter(REPEAT["lost_timeout"], "s"),
    )
}


def parameter_names_text() -> str:
    """The parameters as help text: ``offset_x (m), ..., law (lateral-gain, paper, ...)``."""
    return ", ".join(
        f"{p.name} ({'|'.join(p.choices) if p.choices else p.unit or '-'})" for p in PARAMETERS.values()
    )
