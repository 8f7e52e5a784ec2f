"""A textured poster: natural features matched to a reference view, then a homography.

Acquired by ORB matching, followed from the prediction (ECC, else Lucas-Kanade on the
reference's corners: relative to the reference, it does not drift), then aligned on the
whole target region (ECC, invariant to gain and offset). At the few hundredths of a pixel that decide yaw and the
plane normal, smoothing, the lens's vignetting and unequal blur each read as a shift or a
tilt, so the alignment models all three.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..core.camera import CameraIntrinsics
from ..core.desired import DetectorErrors
from ..core.fit_model import DetectorSpec
from ..errors import InputError, UsageError
from .base import Detection, PointTrack, TargetDetector, as_gray, check_prediction, padded_box, search_window, signed_polygon_area
from .target_kinds import SpecRequest, TargetKind, register_target_kind

#: ORB features per searched frame (the reference gets three times as many), Lowe's
#: ratio-test bound, fewest inliers of a found target, inlier threshold (px) of the robust fit.
N_FEATURES = 500
MATCH_RATIO = 0.8
MIN_INLIERS = 15
REPROJECTION_PX = 2.0
#: Gaussian sigma (px) both images are smoothed with before the alignment (ECC's own 3x3 filter).
ALIGN_BLUR_SIGMA = 0.8
#: The camera's own blur (px, optics and pixel together), assumed when matching resolutions.
CAMERA_BLUR_SIGMA = 0.5
#: The pooled vignetting fall-off ``a`` (per squared half-diagonal) is kept within this range.
VIGNETTING_RANGE = (-0.5, 0.9)
#: Fewer template pixels in the frame than this tell nothing about the vignetting.
MIN_SHADING_PIXELS = 64
#: Following by the alignment alone is accepted at this correlation; below, Lucas-Kanade first.
FOLLOW_CORRELATION = 0.9
#: An alignment that moved the points farther than this (px) from where the shading was
#: placed is aligned again with the shading placed where it ended.
SHADING_PLACEMENT_PX = 0.5
#: A followed frame's alignment stops after one ECC step that moves no point farther (px).
SETTLE_PX = 0.05
#: Each of the first POOL_FRAMES aligned frames reads the vignetting (two alignments), then
#: one in POOL_INTERVAL; the others are aligned once, with the pooled value.
POOL_FRAMES = 32
POOL_INTERVAL = 32
#: ECC iterations and the step (template pixels) at which it stops.
ECC_ITERATIONS = 15
ECC_EPSILON = 1e-3
#: An alignment that moves the target's points farther than this (px) from the start is rejected.
MAX_CORRECTION_PX = 3.0


@dataclass(frozen=True)
class TextureDetection(Detection):
    """A :class:`Detection` with the fitted ``homography`` (3, 3), reference -> frame pixels
    (None when nothing was fitted), its ``inliers`` (matches or Lucas-Kanade points; 0 when
    followed by the alignment alone) and ECC's ``correlation`` (NaN when not aligned)."""

    homography: NDArray[np.float64] | None = None
    inliers: int = 0
    correlation: float = float("nan")


class TextureDetector(TargetDetector):
    """Find a textured target by matching features against ``reference_image`` (a gray or BGR uint8
    view of it, where its points are ``reference_pixels`` (N, 2) px); ``seed``: OpenCV's RNG's for the robust fits."""

    kind = "texture"

    def __init__(self, reference_image: NDArray[np.uint8], reference_pixels: ArrayLike, seed: int = 0) -> None:
        self.reference = as_gray(reference_image)
        points = np.asarray(reference_pixels, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 2 or len(points) < 4 or not np.all(np.isfinite(points)):
            raise UsageError("a texture target needs at least 4 finite reference pixels, shape (N, 2)")
        self.reference_pixels = points
        self.n_points = len(points)
        self.seed = int(seed)
        self._orb = cv2.ORB_create(nfeatures=N_FEATURES)
        keypoints, descriptors = cv2.ORB_create(nfeatures=3 * N_FEATURES).detectAndCompute(self.reference, None)
        if descriptors is None or len(keypoints) < MIN_INLIERS:
            raise InputError(
                f"the texture reference image has too few features ({len(keypoints)}); "
                "the target needs a richly textured picture"
            )
        self._reference_points = np.array([k.pt for k in keypoints], dtype=np.float32)
        self._reference_descriptors = descriptors
        self._matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
        # Reference corners to follow with (LK measures displacements, not corner positions).
        corners = cv2.goodFeaturesToTrack(self.reference, maxCorners=250, qualityLevel=0.01, minDistance=8)
        self._polish_points = np.empty((0, 2), np.float32) if corners is None else corners.reshape(-1, 2)
        self._track = PointTrack(self.n_points, max_coast=5)
        # The reference's region of the target (its points' box) is what ECC aligns.
        self._align_box = padded_box(points, 0, self.reference.shape)
        self._align_template = (*self._align_box[:2], self._template(ALIGN_BLUR_SIGMA))
        self._vignetting = Vignetting(self.reference.shape, self._align_template)

    def _template(self, sigma: float) -> NDArray[np.float32]:
        """The reference's target region smoothed by ``sigma`` px (smoothed with a margin,
        then cut: its border is the picture's, not a reflection of the cut)."""
        x0, y0, x1, y1 = self._align_box
        margin = int(np.ceil(4 * sigma)) + 1
        cx0, cy0, cx1, cy1 = padded_box(self.reference_pixels, margin, self.reference.shape)
        smoothed = _smoothed(self.reference[cy0:cy1, cx0:cx1], sigma)
        return np.ascontiguousarray(smoothed[y0 - cy0:y1 - cy0, x0 - cx0:x1 - cx0])

    def detect(self, image: NDArray[np.uint8], predicted: NDArray[np.float64] | None = None) -> TextureDetection:
        """Find the target points (:class:`~.base.TargetDetector`), followed from a prediction (given,
        or the track's) by the alignment alone when it correlates well, else by Lucas-Kanade, else
        by the alignment without that bound (a picture with little texture); failing those,
        acquired around the prediction (its box grown by 60 %), then in the whole frame."""
        gray = as_gray(image)
        prediction = check_prediction(predicted, self.n_points, self._track)
        result = None
        if prediction is not None:
            guess = self._homography_from(prediction)
            if guess is not None:
                result = (self._aligned_from(gray, guess, min_correlation=FOLLOW_CORRELATION) or self._follow(gray, guess)
                          or self._aligned_from(gray, guess))
            if result is None:
                window = search_window(gray.shape, prediction, 0.6, 32, per_axis=True)
                if window is not None:
                    result = self._acquire(gray, window)
        if result is None or not result.found:
            result = self._acquire(gray, None)
        if result.found and result.homography is not None and result.inliers > 0:  # not aligned yet: on the whole target region
            homography, correlation = self._aligned_homography(gray, result.homography)
            if homography is not None:
                result = replace(result, pixels=transfer(homography, self.reference_pixels), homography=homography,
                                 correlation=correlation)
        self._track.update(result.pixels)
        return result

    def _aligned_from(self, gray: NDArray[np.uint8], guess: NDArray[np.float64],
                      min_correlation: float | None = None) -> TextureDetection | None:
        """The target found by aligning the reference region from ``guess`` alone; None when
        the alignment does not converge near it (or matches worse than ``min_correlation``),
        or the result folds the target."""
        homography, correlation = self._aligned_homography(gray, guess, min_correlation)
        if homography is None or not _plausible(homography, self.reference_pixels, gray.shape):
            return None
        return TextureDetection(transfer(homography, self.reference_pixels), True, 0, 0, homography, 0, correlation)

    def _aligned_homography(self, gray: NDArray[np.uint8], homography: NDArray[np.float64],
                            min_correlation: float | None = None) -> tuple[NDArray[np.float64] | None, float]:
        """``homography`` (reference -> frame) refined by ECC on the target's region (None
        when that fails, or correlates below ``min_correlation``), and the correlation.

        Both images are smoothed alike (:func:`_matched_blur`). A frame that reads the
        vignetting (:meth:`Vignetting.wants`) is aligned, pooled, and aligned again against
        the shaded template; the others once, against the template shaded by the pooled value.
        """
        x0, y0, template = self._align_template
        points = self.reference_pixels - (x0, y0)
        template_sigma, frame_sigma = _matched_blur(homography, self.reference_pixels)
        if template_sigma > ALIGN_BLUR_SIGMA:  # the frame sees the target smaller than the reference
            template = self._template(template_sigma)
        region = _smoothed_region(gray, transfer(homography, self.reference_pixels), frame_sigma)
        if region is None:
            return None, float("nan")
        (fx0, fy0), frame = region
        to_whole = homography @ _shift(x0, y0)
        start = _shift(-fx0, -fy0) @ to_whole
        pooling = self._vignetting.wants()
        shaded = None if pooling else self._vignetting.shaded(template, to_whole)
        refined, correlation = align_homography(template if shaded is None else shaded, frame, start, points, min_correlation,
                                                settle_px=None if pooling else SETTLE_PX)
        if refined is None:
            return None, correlation
        if pooling:
            self._vignetting.pool(template, frame, refined, (fx0, fy0))
        # Aligned again, shaded, after pooling, or when the shaded alignment moved a point far (px) from the start.
        moved = np.max(np.linalg.norm(transfer(refined, points) - transfer(start, points), axis=1)) if shaded is not None else 0.0
        if pooling or moved > SHADING_PLACEMENT_PX:
            refined, correlation = self._aligned_shaded(template, frame, refined, correlation, (fx0, fy0), points)
        aligned = _shift(fx0, fy0) @ refined @ _shift(-x0, -y0)
        return aligned / aligned[2, 2], correlation

    def _aligned_shaded(self, template: NDArray[np.float32], frame: NDArray[np.float32], refined: NDArray[np.float64],
                        correlation: float, offset: tuple[int, int], points: NDArray[np.float64]
                        ) -> tuple[NDArray[np.float64], float]:
        """``refined`` (template -> ``frame`` pixels, ``frame`` cut out of the whole at ``offset``) aligned again
        against the template shaded by the pooled vignetting where ``refined`` places it, with its correlation;
        the given pair when there is no fall-off yet or that alignment fails."""
        shaded = self._vignetting.shaded(template, _shift(*offset) @ refined)
        if shaded is None:
            return refined, correlation
        again, again_correlation = align_homography(shaded, frame, refined, points)
        return (refined, correlation) if again is None else (again, again_correlation)

    def _homography_from(self, prediction: NDArray[np.float64]) -> NDArray[np.float64] | None:
        """The homography that sends the reference pixels onto the predicted ones."""
        known = np.all(np.isfinite(prediction), axis=1)
        if np.count_nonzero(known) < 4:
            return None
        if np.count_nonzero(known) == 4:  # the direct solve, several times cheaper
            guess = cv2.getPerspectiveTransform(self.reference_pixels[known].astype(np.float32), prediction[known].astype(np.float32))
        else:
            guess, _ = cv2.findHomography(self.reference_pixels[known], prediction[known], 0)
        if guess is None or not _plausible(guess, self.reference_pixels, (10**4, 10**4)):
            return None
        return guess

    def _acquire(self, gray: NDArray[np.uint8], window: tuple[int, int, int, int] | None) -> TextureDetection:
        """ORB matching (in ``window`` if given), robust fit, then one polishing step."""
        missing = np.full((self.n_points, 2), np.nan)
        height, width = gray.shape
        x0, y0, x1, y1 = window if window is not None else (0, 0, width, height)
        keypoints, descriptors = self._orb.detectAndCompute(np.ascontiguousarray(gray[y0:y1, x0:x1]), None)
        if descriptors is None or len(keypoints) < 2:
            return TextureDetection(missing, False, 0, 0)
        pairs = self._matcher.knnMatch(descriptors, self._reference_descriptors, k=2)
        good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < MATCH_RATIO * p[1].distance]
        candidates = len(good)
        if candidates < MIN_INLIERS:
            return TextureDetection(missing, False, candidates, candidates)
        frame_points = np.array([keypoints[m.queryIdx].pt for m in good], dtype=np.float32) + np.float32([x0, y0])
        reference_points = self._reference_points[[m.trainIdx for m in good]]
        homography, inliers = self._robust_homography(reference_points, frame_points, REPROJECTION_PX)
        if homography is None or inliers < MIN_INLIERS or not _plausible(homography, self.reference_pixels, gray.shape):
            return TextureDetection(missing, False, candidates, candidates - inliers, None, inliers)
        polished = self._follow(gray, homography, levels=1)
        if polished is not None:
            homography = polished.homography
        pixels = transfer(homography, self.reference_pixels)
        return TextureDetection(pixels, True, candidates, candidates - inliers, homography, inliers)

    def _follow(self, gray: NDArray[np.uint8], homography: NDArray[np.float64], levels: int = 2) -> TextureDetection | None:
        """An approximate ``homography`` refined by Lucas-Kanade: warped by it, the reference nearly
        coincides with the frame, so small-window LK gives sub-pixel displacements and a correction
        homography (seeded robust fit); None when too few reference corners are in view or agree.
        Two pyramid ``levels`` reach about 20 px from a tracked prediction."""
        height, width = gray.shape
        projected = transfer(homography, self._polish_points.astype(np.float64))
        inside = (projected[:, 0] > 8) & (projected[:, 1] > 8) & (projected[:, 0] < width - 9) & (projected[:, 1] < height - 9)
        if np.count_nonzero(inside) < MIN_INLIERS:
            return None
        start = projected[inside].astype(np.float32)
        margin = 8 * 2**levels
        x0, y0 = np.maximum(np.floor(start.min(axis=0)).astype(int) - margin, 0).tolist()
        x1, y1 = np.minimum(np.ceil(start.max(axis=0)).astype(int) + margin + 1, (width, height)).tolist()
        shift = _shift(-x0, -y0)
        warped = cv2.warpPerspective(self.reference, shift @ homography, (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR)
        frame = np.ascontiguousarray(gray[y0:y1, x0:x1])
        local = start - np.array([x0, y0], dtype=np.float32)
        moved, status, _ = cv2.calcOpticalFlowPyrLK(
            warped, frame, local.reshape(-1, 1, 2), None, winSize=(11, 11), maxLevel=levels,
            criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.001),
        )
        ok = status.ravel() == 1
        tracked = int(np.count_nonzero(ok))
        if tracked < MIN_INLIERS:
            return None
        correction, inliers = self._robust_homography(local[ok], moved.reshape(-1, 2)[ok], 0.5)
        # Most reference corners must agree: a wrong warp leaves LK points scattered.
        if correction is None or inliers < max(MIN_INLIERS, tracked // 2):
            return None
        refined = np.linalg.inv(shift) @ correction @ shift @ homography
        refined /= refined[2, 2]
        if not _plausible(refined, self.reference_pixels, gray.shape):
            return None
        pixels = transfer(refined, self.reference_pixels)
        return TextureDetection(pixels, True, tracked, tracked - inliers, refined, inliers)

    def _robust_homography(self, source: NDArray, target: NDArray, threshold_px: float) -> tuple[NDArray[np.float64] | None, int]:
        """The seeded robust fit (MAGSAC) of a homography from ``source`` to ``target`` points, and its inliers."""
        cv2.setRNGSeed(self.seed)
        homography, mask = cv2.findHomography(source, target, cv2.USAC_MAGSAC, threshold_px, maxIters=2000, confidence=0.9999)
        return homography, 0 if mask is None else int(mask.sum())


class Vignetting:
    """The lens's fall-off of brightness, ``1 - a r^2`` about the image centre, pooled over frames.

    A frame sees the target ``V(x_frame) / V(x_reference)`` times as bright as the reference
    (a frame of the same camera): ``a`` by linear least squares a frame at a time (frame ~
    gain * template + gain * a * (r_ref^2 - r_frame^2) * template + offset), pooled by each
    frame's information. ``r`` is in units of the image's half-diagonal. ``shape``: the images'
    (height, width); ``template``: ``(x0, y0, image)``, the template and its place in the reference.
    """

    def __init__(self, shape: tuple[int, int], template: tuple[int, int, NDArray[np.float32]]) -> None:
        height, width = shape
        self.centre = np.array([(width - 1) / 2.0, (height - 1) / 2.0])
        self.scale = 0.25 * (width**2 + height**2)
        x0, y0, image = template
        self._cols = np.arange(image.shape[1], dtype=np.float32)[None, :]
        self._rows = np.arange(image.shape[0], dtype=np.float32)[:, None]
        self._r2_reference = self._r2_frame(_shift(x0, y0))
        self._reference_shading: tuple[float, NDArray[np.float32]] = (0.0, np.ones_like(self._r2_reference))
        self._weighted_sum = 0.0
        self._weight = 0.0
        self._frames = 0

    @property
    def falloff(self) -> float:
        """The pooled ``a`` (0 before any frame told it)."""
        return self._weighted_sum / self._weight if self._weight > 0 else 0.0

    def wants(self) -> bool:
        """Whether the frame being aligned should add its estimate to the pool (:meth:`pool` counts it): each of
        the first :data:`POOL_FRAMES`, then one in :data:`POOL_INTERVAL`. One that should not is counted here."""
        if self._frames < POOL_FRAMES or (self._frames - POOL_FRAMES) % POOL_INTERVAL == 0:
            return True
        self._frames += 1
        return False

    def _r2_frame(self, homography: NDArray[np.float64]) -> NDArray[np.float32]:
        """``r^2``, in the frame, of every template pixel (``homography``: template pixels ->
        whole-frame pixels), shape (h, w), float32: (x^2 + y^2) / (w^2 scale) about the centre."""
        h = (_shift(-self.centre[0], -self.centre[1]) @ homography).astype(np.float32)
        cols, rows = self._cols, self._rows
        x = h[0, 0] * cols + (h[0, 1] * rows + h[0, 2])
        y = h[1, 0] * cols + (h[1, 1] * rows + h[1, 2])
        w = h[2, 0] * cols + (h[2, 1] * rows + h[2, 2])
        x *= x
        y *= y
        x += y
        w *= w
        w *= np.float32(self.scale)
        x /= w
        return x

    def shaded(self, template: NDArray[np.float32], homography: NDArray[np.float64]) -> NDArray[np.float32] | None:
        """The template as a frame's vignetting shades it, with the pooled fall-off; None
        while no frame has told it. ``homography``: template -> whole-frame pixels, to a pixel or so."""
        a = self.falloff
        if a == 0.0:
            return None
        if self._reference_shading[0] != a:
            self._reference_shading = (a, (1.0 / (1.0 - a * self._r2_reference)).astype(np.float32))
        shading = self._r2_frame(homography)
        shading *= np.float32(-a)
        shading += np.float32(1.0)
        shading *= self._reference_shading[1]
        shading *= template
        return shading

    def pool(self, template: NDArray[np.float32], frame: NDArray[np.float32], homography: NDArray[np.float64],
             offset: tuple[int, int]) -> None:
        """Add a frame's estimate of the fall-off to the pool: ``template`` (unshaded) aligned
        with ``frame`` (cut out of the whole frame at ``offset``) by ``homography``."""
        self._frames += 1
        height, width = template.shape
        warped = cv2.warpPerspective(frame, homography, (width, height), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                     borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
        ok = np.isfinite(warped)
        if np.count_nonzero(ok) <= MIN_SHADING_PIXELS:
            return
        to_whole = _shift(*offset) @ homography
        brightness = template[ok].astype(np.float64)
        shading = (self._r2_reference - self._r2_frame(to_whole))[ok] * brightness
        design = np.stack([brightness, np.ones_like(brightness), shading])
        gram = design @ design.T
        try:
            coefficients = np.linalg.solve(gram, design @ warped[ok].astype(np.float64))
            # The information on a: the part of the shading term that gain and offset do not explain.
            unexplained = 1.0 / np.linalg.inv(gram)[2, 2]
        except np.linalg.LinAlgError:
            return
        gain, slope = coefficients[0], coefficients[2]
        weight = float(unexplained) * gain**2
        if gain > 0 and np.isfinite(slope) and np.isfinite(weight) and weight > 0:
            self._weighted_sum += weight * float(np.clip(slope / gain, *VIGNETTING_RANGE))
            self._weight += weight


def _smoothed(image: NDArray[np.uint8], sigma: float = ALIGN_BLUR_SIGMA) -> NDArray[np.float32]:
    """The image as the alignment sees it (float32, smoothed by ``sigma`` px)."""
    return cv2.GaussianBlur(image.astype(np.float32), (0, 0), sigma)


def _matched_blur(homography: NDArray[np.float64], reference_pixels: NDArray[np.float64]) -> tuple[float, float]:
    """Smoothing (px) of the template and of the frame that give both the same blur in the
    template's pixels, the frame seeing the target ``s`` times larger (the homography's local
    scale at the target's centre): unequal blur biases the fitted scale."""
    points = reference_pixels.tolist()
    cx, cy = sum(p[0] for p in points) / len(points), sum(p[1] for p in points) / len(points)
    (h00, h01, h02), (h10, h11, h12), (h20, h21, h22) = (homography / homography[2, 2]).tolist()
    w = h20 * cx + h21 * cy + 1.0
    u = (h00 * cx + h01 * cy + h02) / w
    v = (h10 * cx + h11 * cy + h12) / w
    # The determinant of the 2x2 Jacobian of the mapping at the centre.
    determinant = ((h00 - u * h20) * (h11 - v * h21) - (h01 - u * h21) * (h10 - v * h20)) / (w * w)
    scale = math.sqrt(abs(determinant))
    total = CAMERA_BLUR_SIGMA**2 + ALIGN_BLUR_SIGMA**2  # the template's blur (its own pixels), squared
    if scale >= 1.0:
        return ALIGN_BLUR_SIGMA, math.sqrt(max(scale**2 * total - CAMERA_BLUR_SIGMA**2, ALIGN_BLUR_SIGMA**2))
    return math.sqrt(max(total / scale**2 - CAMERA_BLUR_SIGMA**2, ALIGN_BLUR_SIGMA**2)), ALIGN_BLUR_SIGMA


def _smoothed_region(gray: NDArray[np.uint8], points: NDArray[np.float64], sigma: float = ALIGN_BLUR_SIGMA,
                     margin: int = 16) -> tuple[tuple[int, int], NDArray[np.float32]] | None:
    """The frame around ``points`` (their box and ``margin`` px, wider than the filter, so that
    ECC sees no cut edge), smoothed; None when empty."""
    x0, y0, x1, y1 = padded_box(points, margin, gray.shape)
    if x1 - x0 < 2 * margin or y1 - y0 < 2 * margin:
        return None
    return (x0, y0), _smoothed(gray[y0:y1, x0:x1], sigma)


def _shift(x: float, y: float) -> NDArray[np.float64]:
    """The homography that moves pixels by ``(x, y)``."""
    return np.array([[1.0, 0.0, x], [0.0, 1.0, y], [0.0, 0.0, 1.0]])


def _plausible(homography: NDArray[np.float64], reference_pixels: NDArray[np.float64], shape: tuple[int, int]) -> bool:
    """Reject fits that fold, mirror or blow up the target (in plain floats: a few points,
    twice a frame, where numpy's per-call cost would dominate)."""
    (h00, h01, h02), (h10, h11, h12), (h20, h21, h22) = homography.tolist()
    height, width = shape
    bound = 10.0 * math.hypot(width, height)
    mapped = []
    for x, y in reference_pixels.tolist():
        w = h20 * x + h21 * y + h22
        if not w > 0:
            return False
        u, v = (h00 * x + h01 * y + h02) / w, (h10 * x + h11 * y + h12) / w
        if not (abs(u) < bound and abs(v) < bound):  # also false for NaN
            return False
        mapped.append((u, v))
    before = signed_polygon_area(reference_pixels)
    after = signed_polygon_area(mapped)
    if before == 0 or np.sign(after) != np.sign(before):
        return False
    return 1e-3 < abs(after / before) < 1e3


def align_homography(template: NDArray[np.float32], frame: NDArray[np.float32], homography: NDArray[np.float64],
                     check_points: NDArray[np.float64], min_correlation: float | None = None,
                     settle_px: float | None = None) -> tuple[NDArray[np.float64] | None, float]:
    """The template -> frame ``homography`` (3, 3, to a pixel or so) refined by ECC, and ECC's
    correlation coefficient (1 for images equal up to gain and offset; NaN when ECC failed).

    None instead of the homography when ECC fails, moves a ``check_points`` (N, 2, template px)
    farther than :data:`MAX_CORRECTION_PX`, or correlates below ``min_correlation``. With
    ``settle_px``, one ECC step first, and the full run only when it moved a point farther (px).
    """
    height, width = frame.shape
    start = transfer(homography, check_points)
    # Work on the frame's region around the target: ECC warps the whole input each step.
    x0, y0 = np.maximum(np.floor(start.min(axis=0) - 8).astype(int), 0).tolist()
    x1, y1 = np.minimum(np.ceil(start.max(axis=0) + 8).astype(int), (width, height)).tolist()
    if x1 - x0 < 8 or y1 - y0 < 8:
        return None, float("nan")
    warp = (_shift(-x0, -y0) @ homography).astype(np.float32)
    warp /= warp[2, 2]
    crop = np.ascontiguousarray(frame[y0:y1, x0:x1])
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, ECC_ITERATIONS, ECC_EPSILON)
    settled = False
    try:
        if settle_px is not None:
            first = warp
            correlation, warp = cv2.findTransformECC(template, crop, first.copy(), cv2.MOTION_HOMOGRAPHY, (cv2.TERM_CRITERIA_COUNT, 1, 0.0),
                                                     None, 1)
            step = transfer(warp.astype(np.float64), check_points) - transfer(first.astype(np.float64), check_points)
            settled = bool(np.max(np.abs(step)) <= settle_px)
        if not settled:
            correlation, warp = cv2.findTransformECC(template, crop, warp, cv2.MOTION_HOMOGRAPHY, criteria, None, 1)
    except cv2.error:
        return None, float("nan")
    correlation = float(correlation)
    if min_correlation is not None and not correlation >= min_correlation:
        return None, correlation
    refined = warp.astype(np.float64)
    refined[0] += x0 * refined[2]
    refined[1] += y0 * refined[2]  # the shift undone: inv(shift) @ warp
    if not np.all(np.isfinite(refined)) or abs(refined[2, 2]) < 1e-12:
        return None, correlation
    refined /= refined[2, 2]
    moved = transfer(refined, check_points)
    if not np.all(np.isfinite(moved)) or np.max(np.linalg.norm(moved - start, axis=1)) > MAX_CORRECTION_PX:
        return None, correlation
    return refined, correlation


def transfer(homography: NDArray[np.float64], points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Points (N, 2) mapped by a homography."""
    return cv2.perspectiveTransform(points.reshape(-1, 1, 2).astype(np.float64), homography).reshape(-1, 2)


#: A texture target's box leaves out this percentile of the features on each side.
TEXTURE_BOX_PERCENTILE = 3.0


def texture_points_for_template(image: NDArray[np.uint8], camera: CameraIntrinsics) -> NDArray[np.float64]:
    """Four target points (TL, TR, BR, BL) for a natural-feature target seen in ``image``: the
    box of the central 94 % of its features, its rows pushed away from the principal point's
    row (m_z ~ 0, where (18) breaks down)."""
    keypoints = cv2.ORB_create(nfeatures=1000).detect(as_gray(image), None)
    if len(keypoints) < 20:
        raise InputError("too few natural features in the first image for a texture target")
    points = np.array([k.pt for k in keypoints])
    low, high = np.percentile(points, (TEXTURE_BOX_PERCENTILE, 100 - TEXTURE_BOX_PERCENTILE), axis=0)
    margin = 0.05 * camera.height
    rows = [camera.cy + (margin if row >= camera.cy else -margin) if abs(row - camera.cy) < margin else row
            for row in (low[1], high[1])]
    top, bottom = min(rows), max(rows)
    return np.array([[low[0], top], [high[0], top], [high[0], bottom], [low[0], bottom]])


def _texture_spec(request: SpecRequest) -> DetectorSpec:
    """A simulated poster's own four points as its first frame sees them, else the box of the
    first image's features."""
    pixels = request.seen_pixels if request.seen_pixels is not None else texture_points_for_template(request.images[0], request.camera)
    return DetectorSpec(kind="texture", n_points=4, template_pixels=pixels)


def _texture(spec: DetectorSpec, template: NDArray[np.uint8] | None, seed: int, windowed: bool) -> TextureDetector:
    if template is None or spec.template_pixels is None:
        raise UsageError("a texture detector needs a reference image and the target's pixels in it")
    detector = TextureDetector(template, spec.template_pixels, seed=seed)
    if detector.n_points != spec.n_points:
        raise UsageError(f"{detector.n_points} reference pixels given for a {spec.n_points}-point target")
    return detector


# One tracked homography's corners: a bias of half the point noise, grown where a frame sees part
# of the target (bench/CALIBRATION.md), not correlated over frames; theta_d 0.1 deg and x_hd1
# 2e-3. Its points are not printed anywhere: no metric size.
register_target_kind(TargetKind(
    name="texture", spec=_texture_spec, make=_texture,
    errors=DetectorErrors("texture", bias_fraction=0.5, beyond_view=True, correlated=False, expected_precision=(0.1, 2e-3)),
    precision_scale=23.8, size_pair=None, uses_template=True,
))
