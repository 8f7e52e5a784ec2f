"""Homography refinement by intensity alignment (OpenCV's ECC), shared by the marker and
texture detectors.

Aligning every template pixel with the frame (``cv2.findTransformECC``, invariant to gain
and offset) takes a homography from corners or matches (a few tenths of a pixel) to a few
hundredths; it is accepted only when it converges near its start.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

#: ECC iterations and the step (template pixels) at which it stops.
ECC_ITERATIONS = 15
ECC_EPSILON = 1e-3
#: An alignment that moves the target's points farther than this (px) from the start is rejected.
MAX_CORRECTION_PX = 3.0


def align_homography(
    template: NDArray[np.uint8],
    frame: NDArray[np.uint8],
    homography: NDArray[np.float64],
    check_points: NDArray[np.float64],
    blur: int = 3,
    min_correlation: float | None = None,
    settle_px: float | None = None,
) -> tuple[NDArray[np.float64] | None, float]:
    """The template -> frame homography refined by ECC alignment, and how well they match.

    Parameters
    ----------
    template : ndarray, shape (h, w), uint8
        What the target looks like (a marker's ideal image, a crop of the reference).
    frame : ndarray, shape (H, W), uint8
    homography : ndarray, shape (3, 3)
        Template pixels -> frame pixels, to a pixel or so.
    check_points : ndarray, shape (N, 2)
        Template pixels of the target's points: the refined homography may not move them
        more than :data:`MAX_CORRECTION_PX` from where ``homography`` puts them.
    blur : int
        Gaussian filter size ECC applies to both images (odd).
    min_correlation : float, optional
        Reject an alignment whose correlation coefficient ends below this.
    settle_px : float, optional
        Take one ECC step first, and go on to the usual criteria only when it moved a check
        point farther than this (px): from a close start a small step is as good as converged.

    Returns
    -------
    homography : ndarray, shape (3, 3), or None
        None when ECC did not converge, wandered off or (``min_correlation``) matches too poorly.
    correlation : float
        ECC's criterion at the end, the correlation coefficient of the aligned images (1 for
        images equal up to gain and offset); NaN when ECC failed.
    """
    height, width = frame.shape
    start = transfer(homography, check_points)
    # Work on the frame's region around the target: ECC warps the whole input each step.
    low = np.floor(start.min(axis=0) - 8).astype(int)
    high = np.ceil(start.max(axis=0) + 8).astype(int)
    x0, y0 = max(int(low[0]), 0), max(int(low[1]), 0)
    x1, y1 = min(int(high[0]), width), min(int(high[1]), height)
    if x1 - x0 < 8 or y1 - y0 < 8:
        return None, float("nan")
    shift = np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]])
    warp = (shift @ homography).astype(np.float32)
    warp /= warp[2, 2]
    crop = np.ascontiguousarray(frame[y0:y1, x0:x1])
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, ECC_ITERATIONS, ECC_EPSILON)
    try:
        if settle_px is not None:
            first = warp
            correlation, warp = cv2.findTransformECC(template, crop, first.copy(), cv2.MOTION_HOMOGRAPHY, (cv2.TERM_CRITERIA_COUNT, 1, 0.0),
                                                     None, blur)
            step = transfer(warp.astype(np.float64), check_points)
            before = transfer(first.astype(np.float64), check_points)
            settled = bool(np.max(np.abs(step - before)) <= settle_px)
        else:
            settled = False
        if not settled:
            correlation, warp = cv2.findTransformECC(template, crop, warp, cv2.MOTION_HOMOGRAPHY, criteria, None, blur)
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
