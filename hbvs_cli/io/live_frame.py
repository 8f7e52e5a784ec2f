"""One camera frame of a live loop, as it arrived (``repeat --live``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class LiveFrame:
    """One camera frame as it arrived.

    Attributes
    ----------
    image : ndarray, shape (H, W) or (H, W, 3), uint8
        Gray or BGR.
    stamp : float
        The frame's header stamp (s), or its arrival time when the stamp is zero.
    arrival : float
        When it arrived, on ``time.monotonic()``'s clock (s): a ROS 2 frame's DDS publication
        time when the camera is on this host's clock, else when hbvs took it; a camera
        frame's capture.
    skipped : int
        Frames that arrived since the previous one handed out and were dropped for this one.
    """

    image: np.ndarray
    stamp: float
    arrival: float
    skipped: int
