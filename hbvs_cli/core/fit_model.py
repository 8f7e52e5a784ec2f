"""What a fit hands to repeat: the model of the taught run (its fields; io/fit_file.py
stores and reads it)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .camera import CameraIntrinsics
from .control_settings import GAIN_NAMES, ControllerGains
from .trajectory import SplineTrajectory

#: Most target points a file may describe (dot posters have up to 10, the others 4).
MAX_TARGET_POINTS = 64


@dataclass
class TaughtPath:
    """Ground truth of a simulated teach: per-frame commands, held between frames, the start
    pose and F*'s pose."""

    t: np.ndarray
    v: np.ndarray
    w: np.ndarray
    start_pose: np.ndarray
    reference_pose: np.ndarray


@dataclass
class FitModel:
    """Everything ``repeat`` needs to track the taught trajectory (and report on it)."""

    target_kind: str
    camera: CameraIntrinsics
    reference_index: int
    reference_t: float
    reference_pixels: np.ndarray
    m_ref: np.ndarray
    normal: np.ndarray
    normal_margin: float
    trajectory: SplineTrajectory
    dhat0: float
    dhat0_source: str
    depth: dict[str, Any]
    frames: dict[str, Any]
    condition35: dict[str, Any]
    residual_px: dict[str, Any]
    detector: dict[str, Any]
    #: A simulated teach's world, as recorded (``hbvs_cli.sim.world.World.to_dict``); None for real footage.
    world_description: dict[str, Any] | None = None
    taught_path: TaughtPath | None = None
    render: dict[str, Any] | None = None
    gains: dict[str, Any] | None = None
    #: The joint estimate's uncertainty (sigma of n*, theta_d, x_hd1; docs/uncertainty.md), or None in an older fit file.
    uncertainty: dict[str, Any] | None = None

    def taught_frame_interval(self) -> float:
        """Seconds between taught frames (:func:`~.desired.taught_frame_interval`)."""
        from .desired import taught_frame_interval

        return taught_frame_interval(self.taught_path.t if self.taught_path is not None else None, self.frames.get("frame_interval_s"))

    def suggested_gains(self) -> ControllerGains | None:
        """The gains ``fit`` suggested (core/gains.py), or None in an older fit file."""
        if not self.gains:
            return None
        return ControllerGains(**{k: float(self.gains[k]) for k in GAIN_NAMES})
