"""What a fit hands to repeat: the model of the taught run, typed values all through
(io/fit_file.py alone knows their encoding)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .camera import CameraIntrinsics
from .control_settings import ControllerGains
from .depth import DepthEstimate
from .desired import FrameStats, PixelResidual, UncertaintySummary, taught_frame_interval
from .gains import GainSuggestion
from .trajectory import FeedforwardCondition, SplineTrajectory

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


@dataclass(frozen=True)
class DetectorSpec:
    """What to detect (``kind``, a name of perception's target-kind registry) and how to give
    its points an identity; None fields take the kind's defaults (``n_points`` None: count the
    dots in the first image; ``marker_id`` None: the first marker seen). ``template_pixels``
    (N, 2): texture's points in the template image; ``board``: a board's size as its kind
    counts it; ``initial_pixels`` (N, 2): where fit first saw the points (px), which fixes
    their identity in repeat."""

    kind: str
    n_points: int | None = None
    marker_id: int | None = None
    template_pixels: np.ndarray | None = None
    marker_dict: str | None = None
    marker_ids: tuple[int, ...] | None = None
    polarity: str | None = None
    contrast: str | None = None
    board: tuple[int, int] | None = None
    initial_pixels: np.ndarray | None = None


@dataclass(frozen=True)
class DepthEstimates:
    """The estimates of d* a fit made: from the taught commands (25), and from the target's
    known size between its points ``target_size_pair``; None where not made."""

    commands: DepthEstimate | None = None
    target_size: DepthEstimate | None = None
    target_size_pair: tuple[int, int] | None = None


@dataclass(frozen=True)
class SensorSettings:
    """A simulated teach's sensor, for repeat to render the same: noise (gray levels), blur
    (px), exposure gain (-), noise grain (px)."""

    noise: float = 2.0
    blur: float = 0.0
    exposure: float = 1.0
    noise_grain: float = 0.0


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
    depth: DepthEstimates
    frames: FrameStats
    condition35: FeedforwardCondition
    residual_px: PixelResidual
    detector: DetectorSpec
    #: A simulated teach's world, as recorded (``hbvs_cli.sim.world.World.to_dict``); None for real footage.
    world_description: dict[str, Any] | None = None
    taught_path: TaughtPath | None = None
    render: SensorSettings | None = None
    gains: GainSuggestion | None = None
    #: The joint estimate's uncertainty (sigma of n*, theta_d, x_hd1; docs/uncertainty.md), or None in an older fit file.
    uncertainty: UncertaintySummary | None = None

    def taught_frame_interval(self) -> float:
        """Seconds between taught frames (:func:`~.desired.taught_frame_interval`)."""
        return taught_frame_interval(self.taught_path.t if self.taught_path is not None else None, self.frames.frame_interval_s)

    def suggested_gains(self) -> ControllerGains | None:
        """The gains ``fit`` suggested (core/gains.py), or None in an older fit file."""
        return self.gains.gains if self.gains is not None else None
