"""The one loop of ``hbvs repeat``, ``--sim``, ``--live`` and ``--replay`` alike (docs/layout.md, "The loop")."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from .controller import DesiredState
from .estimation import Observation
from .simulator import ServoStep, StepRecord


@dataclass(frozen=True)
class ServoInput:
    """One frame as the loop sees it: its time ``t`` (s), the period ``dt`` (s) its command is held for,
    the ``observation``, the ``desired`` state at ``t`` and the true ``pose`` (x, y, phi) (NaN when unknown)."""

    t: float
    dt: float
    observation: Observation
    desired: DesiredState
    pose: NDArray[np.float64]


class ServoSource(Protocol):
    """Where frames come from and where commands go; a source without ``act`` (a replay's) is an open loop."""

    def __iter__(self) -> Iterator[ServoInput]:
        """The frames, each after the command of the one before was acted on; ends with the run."""

    def act(self, record: StepRecord) -> None:
        """Carry out the command ``record.v_c, record.w_c`` (move or send it)."""


def run_servo(source: ServoSource | Iterable[ServoInput], servo: ServoStep) -> Iterator[StepRecord]:
    """The closed (or, for a source without ``act``, open) loop: a :class:`~.simulator.StepRecord` per frame."""
    act = getattr(source, "act", None)
    for step in source:
        record = servo.decide(step.t, step.pose, step.observation, step.desired, step.dt)
        if act is not None:
            act(record)
        servo.sent(step.dt)
        yield record
