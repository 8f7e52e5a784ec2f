"""One camera frame of a live loop, as it arrived (``repeat --live``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class LiveFrame:
    """One camera frame as it arrived: ``image`` (H, W) or (H, W, 3) uint8; ``stamp`` its header stamp
    (s) or arrival; ``arrival`` (s, ``time.monotonic()``): its publication when on this host's clock,
    else when hbvs took it; ``skipped`` frames dropped since the previous one."""

    image: np.ndarray
    stamp: float
    arrival: float
    skipped: int
