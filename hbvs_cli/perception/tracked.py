"""The target detector as ``fit`` and ``repeat`` use it: ``fit`` records in the model what
to detect, ``repeat`` re-creates the same detector from it, so the live camera is measured
the way the taught images were."""

from __future__ import annotations

import cv2
import numpy as np

from ..core.camera import CameraIntrinsics, distort_pixels, undistort_pixels
from ..core.estimation import PlanarPoseEstimator
from ..core.fit_model import DetectorSpec, FitModel
from ..errors import RecordingError
from .autodetect import target_candidates
from .base import Detection, TargetDetector, match_identity
from .dot_windows import Window, WindowedDotDetector
from .target_kinds import TARGET_KINDS, target_kind
from .texture import texture_points_for_template

# DetectorSpec: core's, and target_candidates: autodetect's, where the stages take them.
__all__ = ["DetectorSpec", "TrackedDetector", "target_candidates", "texture_points_for_template"]


class TrackedDetector:
    """Images in, target pixels out, in a fixed identity order (NaN rows when not found).

    ``seed``: of texture's robust fits; ``template_image``: texture's reference (default the
    first image detected); ``initial_prediction`` (N, 2): where the points are expected in
    the first image (repeat: the taught first frame), which also fixes their identity;
    ``windowed``: dots followed each in its own window, as the simulated camera does.
    """

    def __init__(
        self,
        spec: DetectorSpec,
        camera: CameraIntrinsics,
        seed: int = 0,
        template_image: np.ndarray | None = None,
        initial_prediction: np.ndarray | None = None,
        windowed: bool = False,
    ) -> None:
        self.spec = spec
        self.kind = target_kind(spec.kind)
        self.windowed = windowed
        self.camera = camera
        self.seed = seed
        self.template_image = template_image
        self.initial_prediction = None if initial_prediction is None else np.asarray(initial_prediction, dtype=float)
        self._detector: TargetDetector | None = None
        # A lens's distortion bends texture's homographies: it is tracked on undistorted images
        # (same K), its points distorted back (its template box as found, in the undistorted image).
        self._undistort_maps = _undistort_maps(camera) if self.kind.uses_template and camera.has_distortion else None

    def detect(self, image: np.ndarray) -> np.ndarray:
        """Pixels (N, 2) of the target points in ``image``; NaN rows for points not found."""
        first = self._detector is None
        if first:  # the detector, its spec completed with what the first image tells (TargetKind.complete)
            self.spec = self.kind.complete(self.spec, image)
            if self.kind.uses_template and self.template_image is None:
                self.template_image = image
            template = self._undistorted(self.template_image) if self.kind.uses_template else None
            self._detector = self.kind.make(self.spec, template, self.seed, self.windowed)
        image = self._undistorted(image)
        if first and self.initial_prediction is not None:
            prediction = self.initial_prediction
            if self._undistort_maps is not None:
                prediction = undistort_pixels(self.camera, prediction)
            detection = self._acquire(image, prediction)
        else:
            detection = self._detector.detect(image, None)
        if not detection.found:
            return np.full((int(self.spec.n_points), 2), np.nan)
        pixels = np.asarray(detection.pixels, dtype=float)
        return pixels if self._undistort_maps is None else distort_pixels(self.camera, pixels)

    def lose_track(self) -> None:
        """Forget where the target was (it left the view), keeping what names its points: the
        next detection searches the whole image."""
        if self._detector is not None:
            getattr(self._detector, "forget_position", self._detector.reset)()

    def _undistorted(self, image: np.ndarray | None) -> np.ndarray | None:
        """``image`` as the pinhole camera of the same K would see it (texture with distortion)."""
        if image is None or self._undistort_maps is None:
            return image
        return cv2.remap(image, *self._undistort_maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def search_windows(self) -> list[Window] | None:
        """:meth:`.WindowedDotDetector.search_windows` in this camera's frames; None for another kind (or none yet)."""
        if not isinstance(self._detector, WindowedDotDetector):
            return None
        return self._detector.search_windows((int(self.camera.height), int(self.camera.width)))

    def detect_in_windows(self, image: np.ndarray, windows: list[Window]) -> np.ndarray | None:
        """The pixels (N, 2) of :meth:`.WindowedDotDetector.detect_in_windows`'s detection, or None."""
        detection = self._detector.detect_in_windows(image, windows)
        return None if detection is None else np.asarray(detection.pixels, dtype=float)

    def _acquire(self, image: np.ndarray, prediction: np.ndarray) -> Detection:
        """First detection against a prediction that may be far off (a robot put down by
        hand): near the prediction if it is close, else anywhere in the image with the
        identities matched to the prediction's layout."""
        detection = self._detector.detect(image, prediction)
        if detection.found:
            return detection
        self._detector.reset()
        acquired = self._detector.detect(image, None)
        if not acquired.found or acquired.pixels.shape != prediction.shape:
            return acquired
        ordered = acquired.pixels[match_identity(acquired.pixels, prediction)]
        self._detector.reset()
        return self._detector.detect(image, ordered)


def _undistort_maps(camera: CameraIntrinsics) -> tuple[np.ndarray, np.ndarray]:
    """``cv2.remap``'s maps from a distorted image to the pinhole image of the same K."""
    size, distortion = (int(camera.width), int(camera.height)), np.asarray(camera.distortion, dtype=float)
    if camera.distortion_model == "equidistant":
        return cv2.fisheye.initUndistortRectifyMap(camera.K, distortion, np.eye(3), camera.K, size, cv2.CV_32FC1)
    return cv2.initUndistortRectifyMap(camera.K, distortion, None, camera.K, size, cv2.CV_32FC1)


#: The outlier gate is this many times the largest residual of the taught frames, and never
#: tighter than MIN_RESIDUAL_GATE_PX (px): one frame's noise can exceed the taught fit's.
RESIDUAL_GATE_FACTOR = 10.0
MIN_RESIDUAL_GATE_PX = 0.25


def estimator_from_model(model: FitModel, converge: bool = False) -> PlanarPoseEstimator:
    """The per-frame estimator of repeat, its outlier gate from the taught residuals (clean
    frames: hundredths of a pixel; a wrong point: tenths); ``converge``: the known-normal
    solve iterated to its minimum (a route's targets are seen small near a switch)."""
    taught = model.residual_px.max
    gate_px = max(RESIDUAL_GATE_FACTOR * taught, MIN_RESIDUAL_GATE_PX) if np.isfinite(taught) else 2.0
    return PlanarPoseEstimator(model.camera, model.m_ref, model.normal, residual_gate=gate_px / model.camera.mean_focal,
                              converge=converge)


def detector_from_model(model: FitModel, template_image: np.ndarray | None, seed: int = 0, windowed: bool = False) -> TrackedDetector:
    """The fit's detector, re-created for repeat (same kind, identity and ``template_image``,
    the fit's decoded template, texture only); ``windowed``: see :class:`TrackedDetector`."""
    spec = model.detector
    if spec.kind not in TARGET_KINDS:
        raise RecordingError(f"the fit's target kind {spec.kind!r} is none this hbvs knows ({', '.join(TARGET_KINDS)})")
    if target_kind(spec.kind).uses_template and template_image is None:
        raise RecordingError(f"the fit file lacks the {spec.kind} template image (/detector/template)")
    return TrackedDetector(spec, model.camera, seed=seed, template_image=template_image, initial_prediction=spec.initial_pixels,
                           windowed=windowed)
