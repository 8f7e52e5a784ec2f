"""What ``hbvs robot-sim``'s stand-in robot adds to the simulated robot of ``repeat --sim``: the dynamics of
its base (``--base``) and the faults of its camera driver's clock (``--stamp-fault``), parsed from their
option's text; the world it shows (a toy robot of the tests shows the same)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from ..core.fit_model import FitModel
from ..core.unicycle import DynamicBase
from ..errors import UsageError
from .render import SceneRenderer
from .scene import Scene, renderer_for, simulation_world


#: ``--base`` presets: (max_v m/s, max_w rad/s, max_accel m/s^2, max_alpha rad/s^2, motor lag s).
BASES: dict[str, tuple[float, float, float, float, float]] = {
    "kinematic": (math.inf, math.inf, math.inf, math.inf, 0.0),
    # A small differential-drive base (a TurtleBot-class robot) with a firmware ramp and motor lag.
    "small": (0.26, 1.8, 0.6, 3.0, 0.12),
}
#: A command beyond these (m/s, rad/s) is no command a wheeled base could follow: ignored.
MAX_PLAUSIBLE_V = 100.0
MAX_PLAUSIBLE_W = 100.0


def parse_base(text: str) -> DynamicBase:
    """``--base``: a preset of :data:`BASES` or ``V,W,ACCEL,ALPHA,LAG`` (``inf`` for no limit)."""
    if text in BASES:
        return DynamicBase(*BASES[text])
    try:
        values = [float(part) for part in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 5 or not all(v > 0 for v in values[:4]) or not (math.isfinite(values[4]) and values[4] >= 0):
        raise UsageError(f"--base must be {', '.join(BASES)} or V,W,ACCEL,ALPHA,LAG (positive limits, inf for none; "
                         f"a lag >= 0 s), got {text!r}")
    return DynamicBase(*values)


def stand_in_world(model: FitModel, reference_image: NDArray | None, depth: float | None,
                   source: str) -> tuple[Scene, SceneRenderer, np.ndarray]:
    """A single-target fit's world as a stand-in robot shows it: ``repeat --sim``'s scene, rendered with
    the teach's sensor, and the taught start pose (x m, y m, phi rad)."""
    scene = simulation_world(model, reference_image, depth, source=source)
    return scene, renderer_for(scene, model), scene.taught_pose_at_run_time(0.0)


class StampFault:
    """``--stamp-fault KIND[:S]@T``: what a faulty camera driver does to its header stamps from T s after the
    robot first moved on."""

    KINDS = ("freeze", "back", "jump", "second-clock", "max", "stall")
    #: The largest stamp a ROS 2 time's int32 seconds can hold.
    MAX_STAMP_S = 2.0 ** 31 - 1

    def __init__(self, text: str) -> None:
        kind, _, at = text.partition("@")
        kind, _, size = kind.partition(":")
        try:
            self.at = float(at)
            self.size = float(size) if size else 0.0
        except ValueError:
            self.at = self.size = math.nan
        needs_size = kind in ("back", "jump", "second-clock", "stall")
        if kind not in self.KINDS or not (math.isfinite(self.at) and self.at >= 0) or needs_size != bool(size) or not (
                math.isfinite(self.size) and self.size >= 0):
            raise UsageError(f"--stamp-fault must be KIND@T or KIND:S@T with KIND one of {', '.join(self.KINDS)} (S needed "
                             f"by back, jump, second-clock and stall), T and S seconds; got {text!r}")
        self.kind = kind
        self._frozen: float | None = None
        self._once_done = False

    def stamp(self, stamp: float, t: float, frame: int) -> float | None:
        """The stamp the driver puts on frame number ``frame`` taken at ``stamp`` (s), ``t`` s into the drive; None: no frame."""
        if t < self.at:
            return stamp
        if self.kind == "freeze":
            self._frozen = stamp if self._frozen is None else self._frozen
            return self._frozen
        if self.kind == "back":
            return stamp - self.size
        if self.kind == "second-clock":
            return stamp + self.size if frame % 2 else stamp
        if self.kind == "stall":
            return None if t < self.at + self.size else stamp
        if self._once_done:
            return stamp
        self._once_done = True
        return stamp + self.size if self.kind == "jump" else self.MAX_STAMP_S
