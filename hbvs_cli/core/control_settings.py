"""What a user sets of the method, by name: the control laws and their gains (29)-(31),
the state filters, the default taught path. Plain Python, no numpy: ``--help`` shows these
defaults without loading the numerical stack.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

from ..errors import InvalidValueError

#: The two variants of the law (29)-(31) hbvs implements.
LAW_PAPER = "paper"
LAW_LATERAL_GAIN = "lateral-gain"
#: The baselines ``--law`` also offers (docs/method.md, "Baselines"; :mod:`.laws`).
LAW_NON_ADAPTIVE = "non-adaptive"
LAW_KANAYAMA = "kanayama"
#: The laws hbvs ships, the default first: core/laws.py registers each (LAW_REGISTRY, where another
#: can be added); their names here serve --help and the figures' colours without numpy.
ALL_LAWS = (LAW_LATERAL_GAIN, LAW_PAPER, LAW_NON_ADAPTIVE, LAW_KANAYAMA)


#: Names of the filters ``repeat --filter`` offers: none is the paper exactly.
FILTER_NONE = "none"
FILTER_EKF = "ekf"
FILTERS = (FILTER_NONE, FILTER_EKF)

#: The default taught path (one of :data:`~hbvs_cli.core.path.PRESETS`).
DEFAULT_PRESET = "s-curve"


@dataclass(frozen=True)
class ControllerGains:
    """Gains of (29)-(31) (units: :data:`GAIN_UNITS`); the defaults, used when a fit suggests
    none, are :mod:`.gains`' rules for the default scenario. ``gamma`` = 0 is the non-adaptive
    baseline, ``k_2 = 1`` the paper's law."""

    k_v: float = 4.0
    k_w: float = 1.0
    gamma: float = 2500.0
    k_2: float = 400.0

    def __post_init__(self) -> None:
        for name in GAIN_NAMES:
            value = getattr(self, name)
            if not math.isfinite(value) or value < 0.0 or (value == 0.0 and name != "gamma"):
                raise InvalidValueError(f"gain {name} must be a positive number, got {value}")

    def as_dict(self) -> dict[str, float]:
        """The gains as a plain dictionary (for files and reports)."""
        return {k: float(v) for k, v in asdict(self).items()}


#: The gains' names, as files, reports and ``--config`` spell them.
GAIN_NAMES = tuple(field.name for field in fields(ControllerGains))
#: Their units: e1, ebar2 and e3 are dimensionless in (29)-(31), so gamma_1 is in m.
GAIN_UNITS = {"k_v": "m/s", "k_w": "1/s", "gamma": "m", "k_2": "-"}
