"""From measured target pixels to the controller's measurement (theta, x_h1, x_h2): undistort,
normalise (11), solve with the fitted n*, and reject a frame whose points do not fit one plane."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .camera import CameraIntrinsics, pixels_to_normalized_floats, undistort_pixels
from .controller import Measurement
from .known_normal import KnownNormalSolver
from .labels import Label

#: Default gate on the known-normal residual (normalised units): 0.004 is 2 px at f = 500,
#: far above what 0.5 px of noise gives, far below what one swapped or spurious point gives.
DEFAULT_RESIDUAL_GATE = 0.004


class ObservationStatus(Label):
    """What a camera frame gave: a measurement, nothing, or why the target was lost (run files' ``lost_reason``)."""

    OK = "ok"
    #: No frame arrived: the last command is held; the target is not lost.
    DROPPED = "dropped"
    #: The target was not detected.
    MISSING = "missing"
    #: No physical solution (a depth ratio that is not positive).
    INVALID = "invalid"
    #: Inconsistent with one plane under planar motion (beyond the residual gate).
    OUTLIER = "outlier"
    #: Something stood between the camera and the target.
    OCCLUDED = "occluded"


@dataclass(frozen=True)
class Observation:
    """What one camera frame gave: ``measurement`` when ``status`` is OK, the known-normal
    ``residual`` (normalised units, NaN if not solved) and the detected ``pixels`` (N, 2)."""

    measurement: Measurement | None
    residual: float = float("nan")
    status: ObservationStatus = ObservationStatus.OK
    pixels: NDArray[np.float64] | None = None

    @property
    def lost(self) -> bool:
        """True when the target was not seen (a dropped frame is not a lost target)."""
        return self.status not in (ObservationStatus.OK, ObservationStatus.DROPPED)


def dropped() -> Observation:
    """A frame that never arrived."""
    return Observation(None, status=ObservationStatus.DROPPED)


class PlanarPoseEstimator:
    """(theta, x_h) from one frame's target pixels, for m*_i ``m_ref`` (N, 3) and n* ``normal``."""

    def __init__(self, camera: CameraIntrinsics, m_ref: ArrayLike, normal: ArrayLike, residual_gate: float = DEFAULT_RESIDUAL_GATE,
                 converge: bool = False) -> None:
        self.camera = camera
        self.solver = KnownNormalSolver(m_ref, normal, converge=converge)
        self.residual_gate = float(residual_gate)

    def from_pixels(self, pixels: ArrayLike | None) -> Observation:
        """Estimate from pixels of shape (N, 2) in the reference order (NaN = not seen; None, a 0-d NaN: none)."""
        pixels = np.asarray(pixels, dtype=float)
        if pixels.shape != (self.solver.m_ref.shape[0], 2) or not np.all(np.isfinite(pixels)):
            return Observation(None, status=ObservationStatus.MISSING, pixels=pixels if pixels.ndim == 2 else None)
        pixels = undistort_pixels(self.camera, pixels)  # the same pixels without distortion
        return self._observe(self.solver.solve_one(*pixels_to_normalized_floats(self.camera, pixels)), pixels)

    def _observe(self, solution: tuple[float, float, float, float] | None, pixels: NDArray[np.float64] | None) -> Observation:
        if solution is None:
            return Observation(None, status=ObservationStatus.INVALID, pixels=pixels)
        theta, x_h1, x_h2, residual = solution
        if not residual <= self.residual_gate:  # NaN never passes the gate
            return Observation(None, residual, ObservationStatus.OUTLIER, pixels)
        return Observation(Measurement(theta=theta, x_h1=x_h1, x_h2=x_h2), residual, ObservationStatus.OK, pixels)
