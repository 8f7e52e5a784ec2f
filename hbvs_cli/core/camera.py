"""The pinhole camera: intrinsics, and pixels <-> the paper's normalised coordinates
``m = [1, m_y, m_z]`` (9), (11) (x forward, y left, z up). With OpenCV's ``K`` (x right, y down,
z forward): ``[x_n, y_n, 1] = K^-1 [u, v, 1]`` and ``m = [1, -x_n, -y_n]``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import CalibrationError, NonFiniteInputError, PointBehindCameraError

#: Distortion models hbvs understands (ROS names); ``equidistant`` is ``cv2.fisheye``'s.
SUPPORTED_DISTORTION_MODELS = ("plumb_bob", "rational_polynomial", "equidistant", "none", "")


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics in px (OpenCV: the top-left pixel's centre is (0, 0)) and the
    ``distortion`` coefficients of ``distortion_model`` in OpenCV order; ``sigma``: the
    standard deviations the calibration states of ``(fx, fy, cx, cy, *distortion)`` (px, then
    the coefficients' units; OpenCV's ``stdDeviationsIntrinsics`` order), () when it states
    none. Not part of the camera's identity (equality)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    distortion_model: str = "none"
    distortion: tuple[float, ...] = field(default_factory=tuple)
    sigma: tuple[float, ...] = field(default=(), compare=False)

    def __post_init__(self) -> None:
        if not all(np.isfinite(v) for v in (self.fx, self.fy, self.cx, self.cy)):
            raise CalibrationError("camera intrinsics contain NaN or infinity")
        if self.fx <= 0 or self.fy <= 0:
            raise CalibrationError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise CalibrationError(f"image size must be positive, got {self.width}x{self.height}")
        if self.distortion_model not in SUPPORTED_DISTORTION_MODELS:
            raise CalibrationError(f"unsupported distortion model {self.distortion_model!r} "
                                   "(supported: plumb_bob, rational_polynomial, equidistant, none)")
        if not all(np.isfinite(v) for v in self.distortion):
            raise CalibrationError("distortion coefficients contain NaN or infinity")
        if not all(np.isfinite(v) and v >= 0.0 for v in self.sigma):
            raise CalibrationError("the intrinsics' standard deviations must be finite and non-negative")

    @property
    def K(self) -> NDArray[np.float64]:
        """The 3x3 intrinsic matrix (OpenCV axes)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def mean_focal(self) -> float:
        """``(fx + fy) / 2`` (px): pixels per unit of normalised coordinates."""
        return 0.5 * (self.fx + self.fy)

    @property
    def has_distortion(self) -> bool:
        """True when any distortion coefficient is non-zero."""
        return any(abs(v) > 0.0 for v in self.distortion)


def camera_description(camera: CameraIntrinsics) -> dict[str, Any]:
    """A JSON-ready description of a camera (the ``camera`` of a world description)."""
    return {
        "fx": camera.fx, "fy": camera.fy, "cx": camera.cx, "cy": camera.cy,
        "width": camera.width, "height": camera.height,
        "distortion_model": camera.distortion_model, "distortion": list(camera.distortion),
    }


def camera_from_description(data: Any) -> CameraIntrinsics:
    """Inverse of :func:`camera_description`; KeyError, TypeError or ValueError when malformed."""
    return CameraIntrinsics(
        fx=float(data["fx"]), fy=float(data["fy"]), cx=float(data["cx"]), cy=float(data["cy"]),
        width=int(data["width"]), height=int(data["height"]),
        distortion_model=str(data.get("distortion_model", "none")),
        distortion=tuple(float(v) for v in data.get("distortion", ())),
    )


#: The default simulated camera: 640x480, f = 500 px (65 deg horizontal field of view).
DEFAULT_CAMERA = CameraIntrinsics(fx=500.0, fy=500.0, cx=319.5, cy=239.5, width=640, height=480)


def pixels_to_normalized(camera: CameraIntrinsics, pixels: ArrayLike) -> NDArray[np.float64]:
    """Ideal pinhole pixels (..., 2) to ``m`` (..., 3), (9), (11); no undistortion."""
    pixels = np.asarray(pixels, dtype=float)
    x_n = (pixels[..., 0] - camera.cx) / camera.fx
    y_n = (pixels[..., 1] - camera.cy) / camera.fy
    return np.stack([np.ones_like(x_n), -x_n, -y_n], axis=-1)


def normalized_to_pixels(camera: CameraIntrinsics, m: ArrayLike) -> NDArray[np.float64]:
    """Ideal pinhole pixels (..., 2) of ``m`` (..., 3), (9), (11): ``[1, m_y, m_z]`` or points
    in F (the first component is divided out). Inverse of :func:`pixels_to_normalized`."""
    m = np.asarray(m, dtype=float)
    u = camera.cx - camera.fx * m[..., 1] / m[..., 0]
    v = camera.cy - camera.fy * m[..., 2] / m[..., 0]
    return np.stack([u, v], axis=-1)


def normalize_points(points_camera: ArrayLike) -> NDArray[np.float64]:
    """Points in F (..., N, 3) (m) to ``m = m_bar / x`` (9); PointBehindCameraError if x <= 0."""
    points_camera = np.asarray(points_camera, dtype=float)
    if not np.all(np.isfinite(points_camera)):
        raise NonFiniteInputError("point coordinates contain NaN or infinity")
    depth = points_camera[..., 0]
    if np.any(depth <= 1e-9):
        raise PointBehindCameraError("a target point is behind (or on the plane of) the camera")
    return points_camera / depth[..., None]


def undistort_pixels(camera: CameraIntrinsics, pixels: ArrayLike) -> NDArray[np.float64]:
    """Ideal pinhole pixels (N, 2), same ``K``, of measured ones (OpenCV's iterative undistortion)."""
    pixels = np.asarray(pixels, dtype=float)
    if not camera.has_distortion or pixels.size == 0:
        return pixels
    import cv2  # lazy: keep the core importable without loading OpenCV

    undistort = cv2.fisheye.undistortPoints if camera.distortion_model == "equidistant" else cv2.undistortPoints
    undistorted = undistort(pixels.reshape(-1, 1, 2), camera.K, np.asarray(camera.distortion, dtype=float), P=camera.K)
    return undistorted.reshape(pixels.shape)


def distort_pixels(camera: CameraIntrinsics, pixels: ArrayLike) -> NDArray[np.float64]:
    """Apply lens distortion to ideal pinhole pixels (N, 2): the lens's forward model."""
    pixels = np.asarray(pixels, dtype=float)
    if not camera.has_distortion or pixels.size == 0:
        return pixels
    import cv2

    m = pixels_to_normalized(camera, pixels)  # [1, -x_n, -y_n]: OpenCV's (x_n, y_n) negated
    distortion = np.asarray(camera.distortion, dtype=float)
    if camera.distortion_model == "equidistant":
        distorted = cv2.fisheye.distortPoints(-m[:, 1:].reshape(-1, 1, 2), camera.K, distortion)
    else:
        object_points = np.column_stack([-m[:, 1:], m[:, :1]]).reshape(-1, 1, 3)
        distorted, _ = cv2.projectPoints(object_points, np.zeros(3), np.zeros(3), camera.K, distortion)
    return distorted.reshape(pixels.shape)


def measured_pixels_to_normalized(camera: CameraIntrinsics, pixels: ArrayLike) -> NDArray[np.float64]:
    """Measured pixels (..., 2; NaN stays NaN) to ``m`` (..., 3), (9), (11), undistorted first."""
    pixels = np.asarray(pixels, dtype=float)
    flat = pixels.reshape(-1, 2)
    undistorted = np.full_like(flat, np.nan)
    found = np.all(np.isfinite(flat), axis=1)
    undistorted[found] = undistort_pixels(camera, flat[found])
    return pixels_to_normalized(camera, undistorted.reshape(pixels.shape))


#: A calibration that states no standard deviations (ROS camera_info, Kalibr, plain JSON) is
#: not counted in the fit's uncertainty: fit reports what an error of this size (px, 1 sigma,
#: on each of fx, fy, cx and cy) would add to n*'s, a what-if, not a guess of the error.
UNSTATED_CALIBRATION_PROBE_PX = 1.0


def calibration_shifts(camera: CameraIntrinsics, sigma: Sequence[float], m: ArrayLike) -> NDArray[np.float64]:
    """How the points ``m`` (..., N, 3), normalised from measured pixels with ``camera``, move
    with an error of one standard deviation ``sigma`` in each of ``(fx, fy, cx, cy,
    *distortion)`` (those beyond the camera's coefficients are left out): (..., 2N, D), each
    point's ``(m_y, m_z)`` in turn by the D errors of non-zero sigma. A central difference:
    the pixels (distorted again) are normalised with the camera moved by +-sigma."""
    m = np.asarray(m, dtype=float)
    pixels = distort_pixels(camera, normalized_to_pixels(camera, m).reshape(-1, 2))
    values = (camera.fx, camera.fy, camera.cx, camera.cy, *camera.distortion)

    def moved(index: int, step: float) -> NDArray[np.float64]:
        v = [value + step * (k == index) for k, value in enumerate(values)]
        shifted = replace(camera, fx=v[0], fy=v[1], cx=v[2], cy=v[3], distortion=tuple(v[4:]))
        return measured_pixels_to_normalized(shifted, pixels)[:, 1:].reshape(*m.shape[:-2], -1)

    columns = [0.5 * (moved(k, size) - moved(k, -size)) for k, size in enumerate(sigma[:len(values)]) if size > 0.0]
    return np.stack(columns, axis=-1) if columns else np.zeros((*m.shape[:-2], 2 * m.shape[-2], 0))


def pixels_to_normalized_floats(camera: CameraIntrinsics, pixels: NDArray[np.float64]) -> tuple[list[float], list[float]]:
    """:func:`pixels_to_normalized` of one frame's few points as plain floats ``(m_y, m_z)``
    (faster without numpy)."""
    m_y = [(camera.cx - u) / camera.fx for u in pixels[:, 0].tolist()]
    m_z = [(camera.cy - v) / camera.fy for v in pixels[:, 1].tolist()]
    return m_y, m_z
