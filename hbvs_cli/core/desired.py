"""The desired trajectory of Remark 1 from the target pixels of a taught run: the fit.

Pixels normalised (9), (11); homographies (16)-(18) of a sample of frames; n* and m*_i
(:mod:`.plane`, :mod:`.bundle`); (theta_d, x_hd) of every frame (:mod:`.known_normal`),
outliers gated; smoothing splines (Remark 1) and condition (35) (docs/method.md, "Desired
trajectory"). What a user should hear is passed to ``warn``, never printed.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import partial
from typing import Callable, Sequence

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import GeometryError, InsufficientDataError
from .camera import CameraIntrinsics, calibration_shifts, measured_pixels_to_normalized, normalized_to_pixels
from .estimation import DEFAULT_RESIDUAL_GATE
from .homography import estimate_euclidean_homography, validate_reference_points
from .known_normal import KnownNormalSolver
from .metrics import rms
from .bundle import (OUTLIER_SPREADS, JointCovariance, JointEstimate, estimate_plane_jointly, joint_covariance, measured_point_noise,
                     projected_points, rolling_shutter_shift, uniform_shift)
from .plane import REFINEMENT_FRAMES, KnownShape, PlaneGeometry, estimate_common_normal, refine_plane_and_reference
from .trajectory import CHANNELS, MIN_SAMPLES, FeedforwardCondition, SplineTrajectory, feedforward_condition, fit_spline_trajectory

#: A frame that shows only part of the target (a board partly out of view) is used when at
#: least this many of its points were found: its pose comes from them alone.
MIN_PARTIAL_POINTS = 4

#: A normal-estimation margin below this means the path did not tell the branches apart.
AMBIGUOUS_NORMAL_MARGIN = 1e-3

#: What :func:`fit_desired_trajectory` says when the margin is below it.
AMBIGUOUS_NORMAL_WARNING = (
    "the taught motion does not tell the two homography branches apart (e.g. a straight drive): "
    "{how}"
)
#: How the ambiguous normal was chosen: the branch whose joint estimate fits the frames better, else the prior.
AMBIGUOUS_NORMAL_CHOICES = {
    True: "n* is the branch whose joint estimate fits the frames better",
    False: "assumed the target faces the reference camera",
}

#: n* uncertain by more than this (deg, one standard deviation) is said in one line.
UNCERTAIN_NORMAL_DEG = 0.5

#: The spans of the drive over which a detector's bias is the same (independent between spans).
BIAS_SEGMENTS = 8


@dataclass(frozen=True)
class DetectorErrors:
    """What the reported uncertainty allows for of a detector's errors (each target kind of
    perception gives its own; bench/CALIBRATION.md measured them; why: docs/uncertainty.md).

    ``bias_fraction``: its point bias in measured point noise, alike over nearby frames;
    ``beyond_view``: its bias grown by :func:`area_beyond_view` (one homography's corners);
    ``correlated``: its errors correlated over frames (:func:`~.bundle.correlation_inflation`);
    ``expected_precision``: the (theta_d deg, x_hd1) RMS error it usually gives, more is said in
    the warning line (None: no check); ``name``: the kind, as that line says it.
    """

    name: str = ""
    bias_fraction: float = 0.0
    beyond_view: bool = False
    correlated: bool = True
    expected_precision: tuple[float, float] | None = None


def area_beyond_view(pixels: NDArray[np.float64], camera: CameraIntrinsics) -> NDArray[np.float64]:
    """Every frame's target quadrilateral (F, 4, 2 px, corners in turn) over its part inside the
    image, by area (1 where it is all in view or not found)."""
    image = np.float32([[0, 0], [camera.width, 0], [camera.width, camera.height], [0, camera.height]])
    quads = np.nan_to_num(pixels).astype(np.float32)  # a frame where it was not found: no area
    return np.array([max(abs(cv2.contourArea(q)) / max(cv2.intersectConvexConvex(q, image)[0], 1e-9), 1.0) for q in quads])

#: What :func:`fit_desired_trajectory` says then (sigmas, and ``{usual}``: the kind's precision).
UNCERTAIN_NORMAL_WARNING = (
    "the drive leaves the plane normal n* uncertain by {normal:.1f} deg, theta_d by {theta:.2f} deg and x_hd1 by {x_h1:.1e} (1 sigma{usual}), "
    "a bias the whole trajectory inherits; what would pin it: the target's known geometry (--target-size, or --target-points FILE for dots, markers or boards), "
    "a drive that curves more or comes closer, or another reference frame (--reference last: the close end of the drive){calibration}"
)

#: ... ended so when most of n*'s uncertainty is the intrinsics' (``{part}`` deg of it).
CALIBRATION_ADVICE = "; and above all a finer calibration ({part:.1f} deg of n*'s sigma is its intrinsics' uncertainty)"

#: Below this branch margin the joint estimate is also run from the other branch's normal,
#: below AMBIGUOUS_NORMAL_MARGIN too: there the facing prior picked one of two normals both
#: nearly facing (the corridor's photograph 3.9 deg off on 4 of 10 teach seeds).
BRANCH_CHECK_MARGIN = 0.05
#: ... on this many frames at most (the branches' costs differ by far more than their noise).
BRANCH_CHECK_FRAMES = 200

#: Frames beyond the residual gate left out of the plane's estimates, one at a time, at most.
OUTLIER_FRAMES = 3

#: A rolling shutter's readout is estimated when its score statistic exceeds this: the
#: chi-square of one degree of freedom does so with probability 1e-6 without a shutter.
READOUT_CHI2 = 23.9

#: Random probes that carry each frame's own noise through the (linear) smoothing spline:
#: the smoothed variance is estimated to about 1/sqrt(32) (18 %), its root to 9 %.
NOISE_PROBES = 64

#: Samples the splines are fitted to at most: longer recordings are averaged in groups of
#: consecutive frames (30 Hz is far above a taught path's bandwidth; GCV's cost grows).
MAX_SPLINE_SAMPLES = 3000
#: Frames whose uncertainty probes are formed and evaluated at once (:func:`_fit_uncertainty`):
#: the fit's peak memory stays flat however long the recording.
UNCERTAINTY_BLOCK = 2048
#: Columns (inherited errors, biases, probes) whose smoothing splines are formed at once.
SPLINE_COLUMNS = 128

#: The frame interval (s) assumed when a recording does not tell it (a single frame, or a
#: fit file older than the interval it records): 30 Hz, the rate ``teach`` records at.
DEFAULT_FRAME_INTERVAL = 1.0 / 30.0


def taught_frame_interval(t: ArrayLike | None = None, recorded: float | None = None) -> float:
    """The taught run's frame interval (s): the median interval of its frame times ``t`` when
    there are two or more, else the ``recorded`` one (a fit file's ``frames.frame_interval_s``),
    else :data:`DEFAULT_FRAME_INTERVAL`."""
    t = np.asarray(() if t is None else t, dtype=float)
    return float(np.median(np.diff(t))) if t.size > 1 else float(recorded or DEFAULT_FRAME_INTERVAL)


@dataclass(frozen=True)
class FrameStats:
    """Which frames of a taught run the fit used.

    ``lost``: not used (not found, or gated out as ``outliers``); ``gaps``: ``(t_before,
    t_after)`` (s) of each unused stretch; ``trimmed_start``/``trimmed_end``: unused frames
    before the first used one and after the last.
    """

    total: int
    used: int
    lost: int
    outliers: int
    lost_fraction: float
    gaps: list[tuple[float, float]]
    longest_gap_s: float
    frame_interval_s: float | None
    trimmed_start: int
    trimmed_end: int
    #: The recording ended before its end record (a crashed recorder); set by the stage.
    truncated_input: bool = False


@dataclass(frozen=True)
class PixelResidual:
    """The known-normal residual of the used frames, in pixels (RMS over frames, and max)."""

    rms: float = float("nan")
    max: float = float("nan")


@dataclass(frozen=True)
class Spread:
    """A per-sample quantity's median and maximum."""

    median: float
    max: float


@dataclass(frozen=True)
class UncertaintySummary:
    """What a fit file keeps of :class:`FitUncertainty`: n*'s sigma (deg), the point noise (px),
    and the spline sigmas' spread (theta_d in degrees; None over an empty span)."""

    normal_sigma_deg: float
    point_noise_px: float
    theta_d_sigma_deg: Spread | None
    x_hd1_sigma: Spread | None
    #: n*'s sigma from the intrinsics' own (deg), and whether they were "stated", "exact" or
    #: "unstated" (then the sigma a 1 px error would add, not counted in normal_sigma_deg;
    #: "assumed" in files of before; None in a file written before either was kept).
    calibration_normal_sigma_deg: float = 0.0
    calibration: str | None = None


@dataclass(frozen=True)
class FitUncertainty:
    """How uncertain the fit is, from the joint estimate's covariance (:mod:`.bundle`).

    ``point_noise_px``: the reprojection errors' noise (px per coordinate); ``theta_sigma``,
    ``x_h1_sigma`` (F,): 1-sigma of each frame's theta_d (rad) and x_hd1 (NaN where not used),
    with what it inherits from n* and m*_i; ``smooth_*`` (S,): the same of the splines over
    the used span (which average a frame's own noise, not the inherited part);
    ``calibration_normal_sigma_deg``: the part of n*'s sigma the intrinsics' errors make;
    ``error_modes(times)`` (T, 3, C): how the splines' (theta_d, x_hd1, x_hd2) at ``times`` (s)
    move with each of C independent unit errors, inherited and own (a route's transition carries
    them, :mod:`.route`).
    """

    normal_sigma_deg: float
    point_noise_px: float
    theta_sigma: NDArray[np.float64]
    x_h1_sigma: NDArray[np.float64]
    smooth_theta_sigma: NDArray[np.float64]
    smooth_x_h1_sigma: NDArray[np.float64]
    calibration_normal_sigma_deg: float = 0.0
    error_modes: Callable[[NDArray[np.float64]], NDArray[np.float64]] | None = field(default=None, compare=False, repr=False)

    def summary(self, calibration: str | None = None) -> UncertaintySummary:
        """The :class:`UncertaintySummary` a fit file keeps, ``calibration`` its own."""
        spread = lambda x: Spread(float(np.median(x)), float(np.max(x))) if x.size else None  # noqa: E731
        return UncertaintySummary(self.normal_sigma_deg, self.point_noise_px,
                                  spread(np.degrees(self.smooth_theta_sigma)), spread(self.smooth_x_h1_sigma),
                                  self.calibration_normal_sigma_deg, calibration)


@dataclass(frozen=True)
class DesiredFit:
    """What the fit of a taught run gives: ``m_ref`` (N, 3), m*_i of F* refined with n*, and
    ``reference_pixels`` (N, 2), the same as ideal pixels; ``initial_pixels`` (N, 2), the first
    used frame's measured pixels; ``normal_margin`` in [0, 1], how clearly the sequence chose n*'s
    branch (:func:`~.plane.estimate_common_normal`); ``used`` (F,), the frames the splines were
    fitted to; ``theta``, ``residual`` (F,) and ``x_h`` (F, 2): theta_d (rad), the known-normal
    residual (normalised units) and x_hd of every frame (NaN where not solved); ``span``, from
    the first used frame to the last, over which ``condition`` (35) is measured."""

    m_ref: NDArray[np.float64]
    reference_pixels: NDArray[np.float64]
    initial_pixels: NDArray[np.float64]
    normal: NDArray[np.float64]
    normal_margin: float
    trajectory: SplineTrajectory
    used: NDArray[np.bool_]
    theta: NDArray[np.float64]
    x_h: NDArray[np.float64]
    residual: NDArray[np.float64]
    frames: FrameStats
    condition: FeedforwardCondition
    residual_px: PixelResidual
    span: slice
    uncertainty: "FitUncertainty | None" = None


def fit_desired_trajectory(
    t: ArrayLike,
    pixels: ArrayLike,
    reference_index: int,
    camera: CameraIntrinsics,
    smoothing: float | None,
    max_lost: float,
    max_gap: float,
    warn: Callable[[str], None] | None = None,
    shapes: Sequence[KnownShape] = (),
    errors: DetectorErrors = DetectorErrors(),
    image_shift_px: float = 0.0,
    calibration_sigma: Sequence[float] = (),
    calibration_counted: bool = True,
) -> DesiredFit:
    """The desired trajectory of a taught run from its per-frame target pixels.

    ``t`` (F,): frame times (s), increasing; ``pixels`` (F, N, 2): the target's pixels in a
    consistent order, NaN where not found; ``smoothing``: the splines' lambda (s^3), None for
    generalised cross-validation; ``max_lost``, ``max_gap``: the largest fraction of unused
    frames, and the longest unused stretch (s) to bridge; ``warn``: told what a user should know
    (ambiguous or uncertain n*), as it happens; ``shapes``: target parts of known shape (each
    marker's square), which pin n* where the motion does not; ``errors``: :class:`DetectorErrors`
    (its bias over each of :data:`BIAS_SEGMENTS` spans); ``image_shift_px``: a detector's error
    shared by every point of every frame (px, 1 sigma in each image direction; e.g. bloom);
    ``calibration_sigma``: the intrinsics' standard deviations
    (:attr:`~.camera.CameraIntrinsics.sigma`), empty when exact; both join
    :func:`~.bundle.joint_covariance`'s ``common_shift``. ``calibration_counted`` False:
    ``calibration_sigma`` is a what-if (a calibration that states none), its part of n*'s sigma
    reported (``calibration_normal_sigma_deg``) but left out of the band.

    Raises InsufficientDataError: too few frames with the target, none in F*, or too many lost;
    ``facts`` holds the numbers.
    """
    t = np.asarray(t, dtype=float)
    pixels = np.asarray(pixels, dtype=float)
    found = np.all(np.isfinite(pixels), axis=(1, 2))
    if not np.any(found):
        raise InsufficientDataError("the target was not found in any frame", reason="not_found")
    if not found[reference_index]:
        raise InsufficientDataError(
            f"the target was not found in the reference frame {reference_index} (t = {t[reference_index]:.2f} s)",
            reason="not_in_reference", index=reference_index, t=float(t[reference_index]),
        )
    m = measured_pixels_to_normalized(camera, pixels)
    m_ref = validate_reference_points(m[reference_index])
    # The normal needs a sample of frames, not all of them: memory stays flat however long
    # the recording (the frames are spread evenly over it).
    sample = np.flatnonzero(found)
    sample = sample[np.linspace(0, sample.size - 1, min(sample.size, REFINEMENT_FRAMES)).astype(int)]
    homographies = estimate_euclidean_homography(m[sample], m_ref)
    valid = homographies.valid
    # A frame beyond the residual gate (a dot taken for another, 90 px off: n* 14 deg off) is
    # left out of the plane's estimates as of the trajectory; the worst first, and only beyond
    # OUTLIER_SPREADS times the frames' median: it bends the plane, so the others' residuals too.
    for _ in range(OUTLIER_FRAMES + 1):
        normal, margin, rival = estimate_common_normal(homographies.H, m_ref, valid=valid)
        usable = np.isin(np.arange(found.size), sample[valid])
        normal, refined = refine_plane_and_reference(m, reference_index, normal, valid=usable, shapes=shapes)
        frame_residual = np.where(valid, KnownNormalSolver(refined, normal).solve(m[sample]).residual, np.nan)
        worst = int(np.nanargmax(frame_residual)) if np.any(np.isfinite(frame_residual)) else 0
        if not frame_residual[worst] > max(DEFAULT_RESIDUAL_GATE, OUTLIER_SPREADS * float(np.nanmedian(frame_residual))):
            break
        valid = valid & (np.arange(valid.size) != worst)
    m_ref = refined
    # The joint estimate of n*, the reference points and every sampled frame's pose, from
    # the variable-projection estimate (robust: a frame with an outlier point counts less).
    others = sample[(sample != reference_index) & usable[sample]]
    start_solver = KnownNormalSolver(m_ref, normal)
    noise = measured_point_noise(start_solver.reprojection_residuals(start_solver.solve(m[others]), m[others])) if others.size else 0.0
    if rival is not None and margin < BRANCH_CHECK_MARGIN:
        # A close vote between the branches, or none: the joint estimate from each on a few
        # frames decides (4 of 60 noisy curving drives had voted for a normal 27 deg off).
        few = others[np.linspace(0, others.size - 1, min(others.size, BRANCH_CHECK_FRAMES)).astype(int)]
        ours = estimate_plane_jointly(m[few], m_ref, normal, m[reference_index], noise, shapes=shapes)
        theirs = estimate_plane_jointly(m[few], m[reference_index], rival, m[reference_index], noise, shapes=shapes)
        if np.isfinite(theirs.cost) and (not np.isfinite(ours.cost) or theirs.cost < ours.cost):
            normal, m_ref = theirs.normal, theirs.m_ref
    if margin < AMBIGUOUS_NORMAL_MARGIN and not shapes and warn is not None:
        # A known shape pins n* in the refinement whatever the vote: how well, the
        # uncertainty (and its warning) says.
        warn(AMBIGUOUS_NORMAL_WARNING.format(how=AMBIGUOUS_NORMAL_CHOICES[rival is not None]))
    joint = estimate_plane_jointly(m[others], m_ref, normal, m[reference_index], noise, shapes=shapes)
    m, normal, m_ref, readout = _without_rolling_shutter(m, t, found, others, reference_index, joint, noise, shapes)
    m, found = _completed_partial_frames(m, found, m_ref, normal)
    solver = KnownNormalSolver(m_ref, normal)
    motion = solver.solve(np.where(found[:, None, None], m, m_ref))
    residual = np.where(found, motion.residual, np.nan)
    used = found & motion.valid & (residual <= DEFAULT_RESIDUAL_GATE)  # NaN never passes
    outliers = int(np.sum(found & ~used))
    frames = frame_stats(t, used, outliers, max_lost, max_gap)
    span = slice(int(np.flatnonzero(used)[0]), int(np.flatnonzero(used)[-1]) + 1)
    # The samples averaged as _binned_columns averages, a signal at a time (one column: the same
    # sums as alone); theta_d unwrapped first, so that a crossing of +-pi does not average to 0.
    binned = [_binned_columns(t[used], lambda rows, x=x: x[rows, None])
              for x in (np.unwrap(motion.theta[used]), motion.x_h[used, 0], motion.x_h[used, 1])]
    trajectory = fit_spline_trajectory(binned[0][0], *(columns[:, 0] for _, columns in binned), smoothing)
    condition = feedforward_condition(trajectory, t[span])
    # The first used frame's measured pixels, a partial frame's points out of view where its pose
    # puts them (undistorted: a prediction for repeat's first search only).
    missing = ~np.all(np.isfinite(pixels[span.start]), axis=1)
    initial_pixels = np.where(missing[:, None], normalized_to_pixels(camera, m[span.start]), pixels[span.start])
    focal = camera.mean_focal
    uncertainty = None
    if others.size:
        shared_shifts = [partial(calibration_shifts, camera, calibration_sigma)]  # last: its columns are n*'s calibration part
        if image_shift_px > 0.0:
            shared_shifts.insert(0, uniform_shift(image_shift_px / focal))
        calibration_columns = sum(size > 0.0 for size in calibration_sigma[:4 + len(camera.distortion)])
        # The globals' covariance (estimated from the frames ``others``) for every used frame: the detector's bias
        # over BIAS_SEGMENTS spans of the used span (grown beyond the view, frame by frame), the rolling shutter's
        # shift from the poses of the frames solved, and the shifts every frame shares (bloom's, the calibration's).
        stacked = lambda rows: np.column_stack([motion.theta[rows], motion.x_h[rows]])  # noqa: E731
        duration = max(t[span][-1] - t[span][0], 1e-9)
        segment = lambda rows: np.clip(((t[rows] - t[span][0]) / duration * BIAS_SEGMENTS).astype(int),  # noqa: E731
                                       0, BIAS_SEGMENTS - 1)
        solved = np.flatnonzero(found & motion.valid)
        shift = _shutter_shifts(normal, m_ref, t, solved, stacked(solved))
        scale = area_beyond_view(pixels, camera) if errors.beyond_view else np.ones(t.size)
        covariance = joint_covariance(
            m[others], m_ref, normal, stacked(others), shapes=shapes,
            frames=m[used], frames_motion=stacked(used),
            estimated_rows=np.where(used[others], np.searchsorted(np.flatnonzero(used), others), -1),
            correlated=errors.correlated, bias_fraction=errors.bias_fraction,
            bias_segments=(segment(reference_index), segment(others), segment(np.flatnonzero(used))),
            bias_scale=(float(scale[reference_index]), scale[others], scale[used]),
            shutter=(shift[reference_index], shift[others], shift[used]), readout_estimated=readout != 0.0,
            common_shift=lambda points: np.concatenate([shifts(points) for shifts in shared_shifts], axis=-1))
        del solved, shift, scale  # frame-long: freed before the uncertainty is carried through the smoothing
        uncertainty = _fit_uncertainty(covariance, t, used, span, trajectory, focal, calibration_columns, calibration_counted)
        counted = uncertainty if calibration_counted else replace(uncertainty, calibration_normal_sigma_deg=0.0)
        if (line := uncertainty_warning(counted, errors)) and warn is not None:
            warn(line)
    return DesiredFit(
        m_ref=m_ref,
        reference_pixels=normalized_to_pixels(camera, m_ref),
        initial_pixels=initial_pixels,
        normal=normal,
        normal_margin=margin,
        trajectory=trajectory,
        used=used,
        theta=motion.theta,
        x_h=motion.x_h,
        residual=residual,
        frames=frames,
        condition=condition,
        residual_px=PixelResidual(
            rms=float(np.sqrt(np.nanmean(residual[used] ** 2)) * focal),
            max=float(np.nanmax(residual[used]) * focal),
        ),
        span=span,
        uncertainty=uncertainty,
    )


def _without_rolling_shutter(m: NDArray[np.float64], t: NDArray[np.float64], found: NDArray[np.bool_], others: NDArray[np.intp],
                             reference_index: int, joint: JointEstimate, noise: float, shapes: Sequence[KnownShape]
                             ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], float]:
    """The points (F, N, 3), n* (3,), the reference points (N, 3) and a rolling shutter's
    readout (s per normalised row), the shutter's shift taken out when the drive shows one;
    else the points and the joint estimate as given, and 0. The skew biases n*: when the
    readout's score statistic exceeds :data:`READOUT_CHI2`, the joint estimate takes one
    Gauss-Newton step from ``joint`` with the readout free, :func:`~.bundle.joint_covariance`'s
    shutter column (docs/uncertainty.md).
    """
    if others.size < 2 or noise <= 0.0:
        return m, joint.normal, joint.m_ref, 0.0
    motion = KnownNormalSolver(joint.m_ref, joint.normal).solve(m[found])
    shift = _shutter_shifts(joint.normal, joint.m_ref, t, np.flatnonzero(found)[motion.valid],
                            np.column_stack([motion.theta, motion.x_h])[motion.valid])
    step = joint_covariance(m[others], joint.m_ref, joint.normal, joint.motion, noise=noise, shapes=shapes, correlated=False,
                            shutter=(shift[reference_index], shift[others], shift[others]))
    if step.readout_sigma <= 0.0 or (step.readout / step.readout_sigma) ** 2 <= READOUT_CHI2:
        return m, joint.normal, joint.m_ref, 0.0
    normal, m_ref = PlaneGeometry.around(joint.normal, joint.m_ref).unpack(step.bias_shared[:, -1])
    deskewed = m.copy()
    deskewed[..., 1:] -= step.readout * shift.reshape(m.shape[0], m.shape[1], 2)
    return deskewed, normal, m_ref, step.readout


def _shutter_shifts(normal: NDArray[np.float64], m_ref: NDArray[np.float64], t: NDArray[np.float64], rows: NDArray[np.intp],
                    poses: NDArray[np.float64]) -> NDArray[np.float64]:
    """Every frame's points' move per unit of a rolling shutter's readout (F, 2N)
    (:func:`~.bundle.rolling_shutter_shift`), from the ``poses`` (K, 3) of the frames ``rows``
    (K,); 0 in the others."""
    shift = np.zeros((t.size, 2 * m_ref.shape[0]))
    shift[rows] = rolling_shutter_shift(projected_points(normal, m_ref, poses), t[rows])
    return shift


def uncertainty_warning(uncertainty: FitUncertainty, errors: DetectorErrors = DetectorErrors()) -> str | None:
    """The warning line when n* is uncertain by more than :data:`UNCERTAIN_NORMAL_DEG`, or the
    splines' RMS sigma of theta_d or x_hd1 exceeds the detector's ``expected_precision``;
    else None."""
    theta, x_h1 = np.degrees(rms(uncertainty.smooth_theta_sigma)), rms(uncertainty.smooth_x_h1_sigma)
    expected = errors.expected_precision
    if uncertainty.normal_sigma_deg > UNCERTAIN_NORMAL_DEG or (expected is not None and (theta > expected[0] or x_h1 > expected[1])):
        usual = f"; {errors.name} targets usually give {expected[0]:g} deg and {expected[1]:g}" if expected is not None else ""
        part = uncertainty.calibration_normal_sigma_deg
        calibration = CALIBRATION_ADVICE.format(part=part) if part > 0.5 * uncertainty.normal_sigma_deg else ""
        return UNCERTAIN_NORMAL_WARNING.format(normal=uncertainty.normal_sigma_deg, theta=theta, x_h1=x_h1, usual=usual, calibration=calibration)
    return None


def _completed_partial_frames(m: NDArray[np.float64], found: NDArray[np.bool_], m_ref: NDArray[np.float64],
                              normal: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Frames that show part of the target, completed: ``(m, found)`` (F, N, 3), (F,) with NaN
    rows where not found and True where whole, returned with every frame of at least
    :data:`MIN_PARTIAL_POINTS` points (a board partly out of view) completed where the pose
    its found points give (the known-normal solver, given n* and ``m_ref``) projects the
    missing ones (12), and marked found (a copy when any was). n* and the reference points
    come before, from the whole frames only."""
    seen = np.all(np.isfinite(m), axis=-1)
    partial = ~found & (seen.sum(axis=1) >= MIN_PARTIAL_POINTS)
    if not np.any(partial):
        return m, found
    m = m.copy()
    found = found.copy()
    patterns, which = np.unique(seen[partial], axis=0, return_inverse=True)
    frames = np.flatnonzero(partial)
    for index, pattern in enumerate(patterns):
        rows = frames[np.ravel(which) == index]
        try:
            motion = KnownNormalSolver(m_ref[pattern], normal).solve(m[rows][:, pattern])
        except GeometryError:  # the found points are degenerate (collinear): the frames stay unused
            continue
        solved = rows[motion.valid]  # none: the assignments below are empty
        poses = np.column_stack([motion.theta[motion.valid], motion.x_h[motion.valid]])
        predicted = projected_points(normal, m_ref, poses)  # (K, N, 2): (m_y, m_z)
        missing = ~pattern
        m[np.ix_(solved, np.flatnonzero(missing), [0])] = 1.0
        m[np.ix_(solved, np.flatnonzero(missing), [1, 2])] = predicted[:, missing, :]
        found[solved] = True
    return m, found


def _fit_uncertainty(covariance: JointCovariance, t: NDArray[np.float64], used: NDArray[np.bool_], span: slice,
                     trajectory: SplineTrajectory, focal: float, calibration_columns: int = 0,
                     calibration_counted: bool = True) -> FitUncertainty:
    """Every used frame's sigma of (theta_d, x_hd1), and the splines' (how each part goes
    through them: docs/uncertainty.md), from the covariance (whose last ``calibration_columns``
    bias columns are the intrinsics' errors, left out of the sigmas unless
    ``calibration_counted``: n*'s part is reported all the same)."""
    from scipy.interpolate import make_smoothing_spline

    calibration = np.zeros((2, 0)) if covariance.bias_shared is None else covariance.bias_shared[:2, covariance.bias_shared.shape[1] - calibration_columns:]
    if not calibration_counted and calibration_columns:  # a what-if: its columns (the shared shifts' last) leave the band
        covariance = replace(covariance, bias_shared=covariance.bias_shared[:, :-calibration_columns],
                             image_shift_bias=covariance.image_shift_bias[..., :-calibration_columns])
    sigma = covariance.frame_sigma()
    theta_sigma = np.full(t.shape, np.nan)
    x_h1_sigma = np.full(t.shape, np.nan)
    theta_sigma[used], x_h1_sigma[used] = sigma[:, 0], sigma[:, 1]
    # The globals' independent errors, (G, r): covariance.shared = directions directions^T.
    values, vectors = np.linalg.eigh(covariance.shared)
    keep = values > 1e-6 * max(float(values.max()), 1e-300)
    directions = vectors[:, keep] * np.sqrt(values[keep])
    probes = _random_signs(np.random.default_rng(0), int(used.sum()), NOISE_PROBES)
    times = t[span]
    smoothed = []
    for index, channel in ((0, "theta_d"), (1, "x_hd1")):
        own = np.sqrt(np.maximum(covariance.own[:, index, index], 0.0))

        def columns(rows: slice, index: int = index, own: NDArray[np.float64] = own) -> NDArray[np.float64]:
            # What the frames inherit, then the probes of their own error; a block of frames at a time.
            return np.column_stack([*_inherited_columns(covariance, directions, rows, index), probes[rows] * own[rows, None]])

        binned_t, binned = _binned_columns(t[used], columns)
        shared = binned.shape[1] - NOISE_PROBES
        inherited_variance, probed_variance = np.zeros(times.size), np.zeros(times.size)
        # A few columns' splines at a time (a board's biases are ~900 columns), each evaluated
        # a block of frames at a time: the same splines, column by column, as all at once.
        for first in range(0, binned.shape[1], SPLINE_COLUMNS):
            spline = make_smoothing_spline(binned_t, binned[:, first:first + SPLINE_COLUMNS], lam=trajectory.channels[channel].smoothing)
            split = max(shared - first, 0)
            for block in range(0, times.size, UNCERTAINTY_BLOCK):
                at = spline(times[block:block + UNCERTAINTY_BLOCK])
                inherited_variance[block:block + UNCERTAINTY_BLOCK] += np.sum(at[:, :split] ** 2, axis=1)
                probed_variance[block:block + UNCERTAINTY_BLOCK] += np.sum(at[:, split:] ** 2, axis=1)
        smoothed.append(np.sqrt(inherited_variance + probed_variance / NOISE_PROBES))
    return FitUncertainty(
        normal_sigma_deg=float(np.degrees(covariance.normal_sigma)),
        calibration_normal_sigma_deg=float(np.degrees(np.sqrt(np.sum(calibration ** 2)))),
        point_noise_px=float(covariance.noise * focal),
        theta_sigma=theta_sigma,
        x_h1_sigma=x_h1_sigma,
        smooth_theta_sigma=smoothed[0],
        smooth_x_h1_sigma=smoothed[1],
        error_modes=partial(_error_modes, covariance, directions, t[used], trajectory),
    )


def _inherited_columns(covariance: JointCovariance, directions: NDArray[np.float64], rows: slice, index: int) -> list[NDArray[np.float64]]:
    """How the frames ``rows`` move in component ``index`` of (theta, x_h1, x_h2) with the
    globals' independent errors, then with a detector's biases (common to the frames as well)."""
    inherited = [covariance.sensitivity[rows, index, :] @ directions]
    if (bias := covariance.bias_rows(rows, index)) is not None:
        inherited.append(bias)
    return inherited


def _error_modes(covariance: JointCovariance, directions: NDArray[np.float64], t_used: NDArray[np.float64],
                 trajectory: SplineTrajectory, times: ArrayLike) -> NDArray[np.float64]:
    """:attr:`FitUncertainty.error_modes` at ``times`` (T,) s, shape (T, 3, C), in the columns
    docs/uncertainty.md lists (the probes scaled so that the columns' sum of squares is the
    variance). x_hd2 follows the splines by (25), ``x_hd2_dot = x_hd1 theta_d_dot``, from its
    offset, the mean of the frames' x_h2 less that integral."""
    from scipy.interpolate import make_smoothing_spline

    times = np.asarray(times, dtype=float)
    values, vectors = np.linalg.eigh(covariance.own)
    own_roots = vectors * np.sqrt(np.maximum(values, 0.0))[:, None, :]  # (K, 3, 3): own = roots roots^T
    signs = np.random.default_rng(1).choice([-1.0, 1.0], size=(t_used.size, 3, NOISE_PROBES)) / np.sqrt(NOISE_PROBES)

    def columns(rows: slice, index: int) -> NDArray[np.float64]:
        own = np.einsum("kb,kbp->kp", own_roots[rows, index], signs[rows])
        return np.column_stack([*_inherited_columns(covariance, directions, rows, index), own])

    binned = [_binned_columns(t_used, partial(columns, index=index)) for index in range(3)]
    grid, channels = binned[0][0], [moved for _, moved in binned]
    splines = [make_smoothing_spline(grid, moved, lam=trajectory.channels[name].smoothing) for moved, name in zip(channels, CHANNELS)]
    taught = trajectory.evaluate(grid)
    moved_rate = splines[1](grid) * taught.theta_d_dot[:, None] + taught.x_hd1[:, None] * splines[0].derivative()(grid)
    integral = np.concatenate([np.zeros((1, moved_rate.shape[1])), np.cumsum((moved_rate[1:] + moved_rate[:-1]) / 2 * np.diff(grid)[:, None], axis=0)])
    offset = np.mean(channels[2] - integral, axis=0)
    x_hd2 = offset + np.column_stack([np.interp(times, grid, column) for column in integral.T])
    return np.stack([splines[0](times), splines[1](times), x_hd2], axis=1)


def _binned_columns(t: NDArray[np.float64], columns: Callable[[slice], NDArray[np.float64]]
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``t`` (K,) and the columns (K, C) averaged in groups of consecutive rows, at most
    :data:`MAX_SPLINE_SAMPLES` groups; ``columns(rows)`` forms the columns of a slice of the K
    rows, which are asked for (and averaged) :data:`UNCERTAINTY_BLOCK` rows or one group at a
    time, so that a long recording's columns are never held whole."""
    group = max(int(np.ceil(t.size / MAX_SPLINE_SAMPLES)), 1)
    usable = t.size // group * group
    step = max(UNCERTAINTY_BLOCK // group, 1) * group
    averaged = lambda block: block.reshape(-1, group, block.shape[1]).mean(axis=1)  # noqa: E731
    return (t[:usable].reshape(-1, group).mean(axis=1),
            np.concatenate([averaged(columns(slice(k, min(k + step, usable)))) for k in range(0, usable, step)]))


def _random_signs(rng: np.random.Generator, rows: int, columns: int) -> NDArray[np.int8]:
    """``rng.choice([-1, 1], size=(rows, columns))`` as int8, drawn :data:`UNCERTAINTY_BLOCK`
    rows at a time: the same draws (the generator's stream continues from block to block),
    without the frame-long int64 indices that ``choice`` draws them through (512 bytes a
    frame, against the signs' 64)."""
    signs = np.array([-1, 1], dtype=np.int8)
    return np.concatenate([rng.choice(signs, size=(min(UNCERTAINTY_BLOCK, rows - k), columns))
                           for k in range(0, rows, UNCERTAINTY_BLOCK)] or [np.empty((0, columns), np.int8)])


def frame_stats(t: NDArray[np.float64], used: NDArray[np.bool_], outliers: int, max_lost: float, max_gap: float) -> FrameStats:
    """Which frames are used, and whether they are enough (see :func:`fit_desired_trajectory`)."""
    total = int(used.size)
    n_used = int(used.sum())
    if n_used < MIN_SAMPLES:
        raise InsufficientDataError(
            f"the target was found in only {n_used} of {total} frames; at least {MIN_SAMPLES} are needed",
            reason="too_few", used=n_used, total=total,
        )
    lost_fraction = 1.0 - n_used / total
    indices = np.flatnonzero(used)
    gaps = [(float(t[before]), float(t[after]))
            for before, after in zip(indices[:-1], indices[1:]) if after - before > 1]
    longest = max((b - a for a, b in gaps), default=0.0)
    if lost_fraction > max_lost:
        raise InsufficientDataError(
            f"the target is missing from {100 * lost_fraction:.0f} % of the frames (more than {100 * max_lost:.0f} %)",
            reason="lost", lost_fraction=lost_fraction, max_lost=max_lost,
        )
    if longest > max_gap:
        a, b = max(gaps, key=lambda g: g[1] - g[0])
        raise InsufficientDataError(
            f"the target is missing from t = {a:.2f} s to {b:.2f} s ({longest:.2f} s), longer than {max_gap:g} s",
            reason="gap", start=a, end=b, longest=longest, max_gap=max_gap,
        )
    return FrameStats(
        total=total,
        used=n_used,
        lost=total - n_used,
        outliers=outliers,
        lost_fraction=lost_fraction,
        gaps=gaps,
        longest_gap_s=longest,
        frame_interval_s=taught_frame_interval(t),  # t holds at least MIN_SAMPLES frames here
        trimmed_start=int(indices[0]),
        trimmed_end=int(total - 1 - indices[-1]),
    )
