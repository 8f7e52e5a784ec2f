"""An independent footage maker: teach videos that hbvs's own renderer did not draw.

Nothing here imports ``hbvs_cli``: only numpy, OpenCV and scikit-image. A *wall image*
(BGR, with the target drawn on it and the wall's lighting baked in) is warped into each
frame by the plane-to-image homography with ``cv2.warpPerspective`` at ``supersample``
times the resolution; then the lens distortion (plumb_bob, by an inverse map), motion blur
(the average of the warps at several poses across the exposure), the box filter down to
the sensor's pixels, vignetting, exposure drift, Gaussian noise and JPEG (the video is
MJPG). The robot drives a unicycle path of its own (not one of hbvs's presets). Written
out: ``drive.avi``, ``camera.yaml`` (ROS ``camera_info``) and ``truth.npz`` (times, poses,
the true n* and d*).

Conventions are those of the paper as hbvs documents them (docs/conventions.md):
robot frame x forward, y left, z up; theta = phi* - phi; x_h = Rz(phi)^T (p* - p) / d*;
n* is the wall's unit normal in F*, pointing from the camera to the wall.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np


# --------------------------------------------------------------------------- camera
@dataclass(frozen=True)
class Camera:
    """A pinhole camera with plumb_bob distortion, ``camera_height`` m above the floor."""

    width: int = 640
    height: int = 480
    fx: float = 505.0
    fy: float = 502.0
    cx: float = 323.5
    cy: float = 238.0
    distortion: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)
    camera_height: float = 0.30

    @property
    def written_distortion(self) -> tuple[float, float, float, float, float]:
        """The distortion its calibration file says (the lens itself, here)."""
        return self.distortion

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def write_ros_yaml(self, path: Path) -> Path:
        """The ROS camera calibrator's ``camera_info`` YAML, written by hand (no hbvs code)."""
        k = self.K.ravel().tolist()
        p = [self.fx, 0.0, self.cx, 0.0, 0.0, self.fy, self.cy, 0.0, 0.0, 0.0, 1.0, 0.0]
        fmt = lambda values: "[" + ", ".join(repr(float(v)) for v in values) + "]"  # noqa: E731
        path.write_text(
            f"image_width: {self.width}\nimage_height: {self.height}\ncamera_name: footage\n"
            f"camera_matrix:\n  rows: 3\n  cols: 3\n  data: {fmt(k)}\n"
            f"distortion_model: plumb_bob\n"
            f"distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: {fmt(self.written_distortion)}\n"
            f"rectification_matrix:\n  rows: 3\n  cols: 3\n  data: {fmt(np.eye(3).ravel())}\n"
            f"projection_matrix:\n  rows: 3\n  cols: 4\n  data: {fmt(p)}\n"
            # Not ROS's: fx, fy, cx, cy are this camera's own, exact (hbvs's fit reads it).
            f"std_deviations_intrinsics:\n  rows: 4\n  cols: 1\n  data: [0.0, 0.0, 0.0, 0.0]\n"
        )
        return path


# --------------------------------------------------------------------------- wall
@dataclass
class Wall:
    """A vertical wall with a picture on it.

    Attributes
    ----------
    image : ndarray, shape (H, W, 3), uint8
        What the wall looks like (BGR), lighting included.
    metres_per_px : float
    centre : (x, y, z)
        World position of the image's centre (m).
    yaw : float
        Direction of the wall's normal (toward the camera side is ``-normal``), rad from
        the world x axis.
    points : ndarray, shape (N, 2)
        Wall-image pixels of the target's points (dots' centres, marker corners), for tests.
    """

    image: np.ndarray
    metres_per_px: float
    centre: tuple[float, float, float]
    yaw: float
    points: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))

    @property
    def normal(self) -> np.ndarray:
        """Unit normal in the world, pointing away from the camera (into the wall)."""
        return np.array([np.cos(self.yaw), np.sin(self.yaw), 0.0])

    @property
    def along(self) -> np.ndarray:
        """The image's column direction (to the right as seen by a camera facing the wall)."""
        return np.array([np.sin(self.yaw), -np.cos(self.yaw), 0.0])

    def wall_to_world(self) -> np.ndarray:
        """3x3 map from homogeneous wall-image pixels (col, row, 1) to world points (affine, 4x3 without the last row)."""
        h, w = self.image.shape[:2]
        s = self.metres_per_px
        up = np.array([0.0, 0.0, 1.0])
        origin = np.asarray(self.centre) - s * (w - 1) / 2 * self.along + s * (h - 1) / 2 * up
        return np.column_stack([s * self.along, -s * up, origin])  # (3, 3): world = M @ [c, r, 1]


def camera_rotation(phi: float) -> np.ndarray:
    """World -> OpenCV camera rotation for a robot heading ``phi`` (camera looks forward)."""
    forward = np.array([np.cos(phi), np.sin(phi), 0.0])
    left = np.array([-np.sin(phi), np.cos(phi), 0.0])
    up = np.array([0.0, 0.0, 1.0])
    return np.vstack([-left, -up, forward])


def wall_homography(wall: Wall, camera: Camera, pose: np.ndarray, K: np.ndarray | None = None) -> np.ndarray:
    """Wall-image pixels -> ideal (undistorted) image pixels for a robot at ``pose`` (x, y, phi)."""
    R = camera_rotation(pose[2])
    centre = np.array([pose[0], pose[1], camera.camera_height])
    M = wall.wall_to_world()
    cam = R @ M
    cam[:, 2] -= R @ centre
    return (camera.K if K is None else K) @ cam


# --------------------------------------------------------------------------- path
def unicycle_poses(times: np.ndarray, start: tuple[float, float, float], v, w, substeps: int = 50) -> np.ndarray:
    """Exact-enough unicycle poses (x, y, phi) at ``times`` for commands v(t), w(t) (midpoint rule, fine steps)."""
    poses = np.empty((len(times), 3))
    state = np.array(start, dtype=float)
    t_now = float(times[0])
    poses[0] = state
    for k in range(1, len(times)):
        dt = (times[k] - t_now) / substeps
        for _ in range(substeps):
            tm = t_now + 0.5 * dt
            phi_mid = state[2] + 0.5 * dt * w(tm)
            state = state + dt * np.array([v(tm) * np.cos(phi_mid), v(tm) * np.sin(phi_mid), w(tm)])
            t_now += dt
        poses[k] = state
    return poses


@dataclass(frozen=True)
class Drive:
    """A drive toward the wall: a gentle weave that is none of hbvs's presets."""

    duration: float = 12.0
    fps: float = 5.0
    start: tuple[float, float, float] = (0.0, 0.15, 0.05)
    speed: float = 0.24
    weave: float = 0.10  # rad/s amplitude of w
    period: float = 9.0

    def times(self) -> np.ndarray:
        return np.arange(int(round(self.duration * self.fps))) / self.fps

    def v(self, t: float) -> float:
        return self.speed * (1.0 - 0.15 * np.cos(2 * np.pi * t / self.duration))

    def w(self, t: float) -> float:
        return -self.weave * np.sin(2 * np.pi * t / self.period + 0.4)

    def poses(self, times: np.ndarray) -> np.ndarray:
        return unicycle_poses(times, self.start, self.v, self.w)


# --------------------------------------------------------------------------- rendering
@dataclass(frozen=True)
class Effects:
    """What the sensor and the optics do to the picture."""

    supersample: int = 2
    exposure_s: float = 0.0  # motion blur: the pose moves during this time
    blur_samples: int = 1
    optical_blur: float = 0.5  # Gaussian sigma (px) of the lens
    vignetting: float = 0.25  # relative fall-off at the frame's corners
    exposure_drift: float = 0.1  # gain varies by +-this over the drive
    noise: float = 2.0  # gray levels
    jpeg_quality: int = 90


class FootageMaker:
    """Render frames of a wall from robot poses, and write the teach video."""

    def __init__(self, wall: Wall, camera: Camera, effects: Effects = Effects(), seed: int = 0) -> None:
        # The wall is printed at 2 mm per pixel and seen from afar at 5-10 wall pixels per
        # frame pixel: warping (bilinear, no area filter) would alias its sharp edges into
        # a jitter of a tenth of a pixel that no camera has. A blur of 1.5 wall pixels (3
        # mm, a few hundredths of a frame pixel) band-limits it first.
        self.wall = Wall(cv2.GaussianBlur(wall.image, (0, 0), 1.5), wall.metres_per_px, wall.centre, wall.yaw, wall.points)
        self.camera = camera
        self.effects = effects
        self.rng = np.random.default_rng(seed)
        ss = effects.supersample
        # The ideal (undistorted) supersampled canvas has a margin so that a barrel-distorted
        # frame's corners, which look farther out, still land on it.
        self.margin = 40 * ss if any(camera.distortion) else 0
        self.canvas = (camera.width * ss + 2 * self.margin, camera.height * ss + 2 * self.margin)
        offset = self.margin + (ss - 1) / 2.0
        self.K_canvas = np.array([[ss, 0, offset], [0, ss, offset], [0, 0, 1.0]]) @ camera.K
        self._map = self._distortion_map() if any(camera.distortion) else None
        height, width = camera.height, camera.width
        y, x = np.mgrid[0:height, 0:width].astype(np.float32)
        r2 = ((x - camera.cx) ** 2 + (y - camera.cy) ** 2) / (camera.cx**2 + camera.cy**2)
        self._vignette = (1.0 - effects.vignetting * r2).astype(np.float32)

    def _distortion_map(self):
        """For every supersample of the distorted frame: where it comes from on the ideal canvas."""
        cam, ss = self.camera, self.effects.supersample
        u = (np.arange(cam.width * ss) + 0.5) / ss - 0.5
        v = (np.arange(cam.height * ss) + 0.5) / ss - 0.5
        grid = np.stack(np.meshgrid(u, v), axis=-1).reshape(-1, 1, 2)
        if any(cam.distortion):
            ideal = cv2.undistortPoints(
                grid, cam.K, np.asarray(cam.distortion), R=None, P=cam.K,
                criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-6),
            ).reshape(-1, 2)
        else:
            ideal = grid.reshape(-1, 2)
        canvas = (ideal + 0.5) * ss - 0.5 + self.margin
        shape = (cam.height * ss, cam.width * ss)
        return canvas[:, 0].reshape(shape).astype(np.float32), canvas[:, 1].reshape(shape).astype(np.float32)

    def _warp(self, pose: np.ndarray) -> np.ndarray:
        H = wall_homography(self.wall, self.camera, pose, self.K_canvas)
        return cv2.warpPerspective(self.wall.image, H, self.canvas, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def render(self, pose_of_time, t: float, gain: float = 1.0) -> np.ndarray:
        """The BGR frame (uint8) at time ``t``; ``pose_of_time(t)`` gives (x, y, phi)."""
        return self._sensor(self._exposure(pose_of_time, t), gain)

    def _exposure(self, pose_of_time, t: float) -> np.ndarray:
        """The ideal supersampled canvas (float32) of the exposure at ``t``, motion blur included."""
        fx = self.effects
        if fx.blur_samples > 1 and fx.exposure_s > 0:
            offsets = (np.arange(fx.blur_samples) + 0.5) / fx.blur_samples - 0.5
            # Summed in place: np.mean of a list first copies the frames into one array.
            canvas = self._warp(pose_of_time(t + fx.exposure_s * offsets[0])).astype(np.float32)
            for o in offsets[1:]:
                canvas += self._warp(pose_of_time(t + fx.exposure_s * o))
            canvas *= np.float32(1.0 / fx.blur_samples)
        else:
            canvas = self._warp(pose_of_time(t)).astype(np.float32)
        return canvas

    def _sensor(self, canvas: np.ndarray, gain: float) -> np.ndarray:
        """Lens distortion, the sensor's pixels, optical blur, vignetting, gain and noise."""
        fx = self.effects
        if any(self.camera.distortion):
            distorted = cv2.remap(canvas, self._map[0], self._map[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        else:
            distorted = canvas  # the map is the identity
        ss = fx.supersample
        frame = cv2.resize(distorted, (self.camera.width, self.camera.height), interpolation=cv2.INTER_AREA) if ss > 1 else distorted
        if fx.optical_blur > 0:
            frame = cv2.GaussianBlur(frame, (0, 0), fx.optical_blur)
        frame = frame * (gain * self._vignette)[:, :, None]
        frame = frame + self.rng.normal(0.0, fx.noise, frame.shape).astype(np.float32)
        return np.clip(np.rint(frame), 0, 255).astype(np.uint8)

    def write(self, folder: Path, drive: Drive) -> dict:
        """Render the drive into ``folder``: drive.avi (MJPG), camera.yaml, truth.npz."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        times = drive.times()
        pose_of_time = drive_pose_function(drive)
        poses = np.array([pose_of_time(t) for t in times])
        video = folder / "drive.avi"
        writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), drive.fps, (self.camera.width, self.camera.height), True)
        assert writer.isOpened(), "OpenCV cannot write MJPG video"
        writer.set(cv2.VIDEOWRITER_PROP_QUALITY, self.effects.jpeg_quality)
        for k, t in enumerate(times):
            gain = 1.0 + self.effects.exposure_drift * np.sin(2 * np.pi * k / max(len(times) - 1, 1))
            writer.write(self.render(pose_of_time, t, gain))
        writer.release()
        self.camera.write_ros_yaml(folder / "camera.yaml")
        truth = self.truth(times, poses)
        np.savez(folder / "truth.npz", **truth)
        return {"video": video, "calibration": folder / "camera.yaml", **truth}

    def truth(self, times: np.ndarray, poses: np.ndarray, reference: int = 0) -> dict:
        """theta_d, x_hd (F, 2), n* and d* for F* = frame ``reference``."""
        ref = poses[reference]
        phi_ref = ref[2]
        forward = np.array([np.cos(phi_ref), np.sin(phi_ref), 0.0])
        left = np.array([-np.sin(phi_ref), np.cos(phi_ref), 0.0])
        normal_world = self.wall.normal
        camera_ref = np.array([ref[0], ref[1], self.camera.camera_height])
        d_star = float((np.asarray(self.wall.centre) - camera_ref) @ normal_world)
        normal = np.array([forward @ normal_world, left @ normal_world, 0.0])
        theta = ref[2] - poses[:, 2]
        delta = ref[:2] - poses[:, :2]
        c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
        x_f = np.column_stack([c * delta[:, 0] + s * delta[:, 1], -s * delta[:, 0] + c * delta[:, 1]])
        return {"t": times, "poses": poses, "theta_d": theta, "x_hd": x_f / d_star, "normal": normal, "d_star": d_star}


def drive_pose_function(drive: Drive):
    """The drive's pose (x, y, phi) at any time ``t`` (s, a number or an array of shape (T,):
    then (3, T)), interpolated on a 200 Hz grid from half a second before the first frame to
    half a second after the last (motion blur and a rolling shutter look that far)."""
    times = drive.times()
    fine = np.linspace(times[0] - 0.5, times[-1] + 0.5, int((times[-1] - times[0] + 1.0) * 200) + 1)
    fine_poses = _poses_from(drive, fine)
    return lambda t: np.array([np.interp(t, fine, fine_poses[:, k]) for k in range(3)])


def _poses_from(drive: Drive, fine: np.ndarray) -> np.ndarray:
    """Poses on a fine grid that extends half a second before the start (motion blur needs it)."""
    # Integrate from the drive's start forward, and backward for the times before it.
    after = fine >= 0.0
    forward = unicycle_poses(np.concatenate([[0.0], fine[after]]), drive.start, drive.v, drive.w, substeps=4)[1:]
    before_times = fine[~after][::-1]
    if before_times.size:
        back = unicycle_poses(np.concatenate([[0.0], -before_times]), drive.start, lambda t: -drive.v(-t), lambda t: -drive.w(-t), substeps=4)[1:]
        back = back[::-1]
    else:
        back = np.empty((0, 3))
    return np.concatenate([back, forward])


# --------------------------------------------------------------------------- walls
WALL_MPP = 0.002  # 2 mm per wall-image pixel


def _canvas(width_m: float, height_m: float, colour, metres_per_px: float = WALL_MPP) -> np.ndarray:
    w, h = int(round(width_m / metres_per_px)), int(round(height_m / metres_per_px))
    image = np.empty((h, w, 3), np.uint8)
    image[:] = colour
    return image


def _lighting(image: np.ndarray, left: float, right: float, top: float = 1.0, bottom: float = 1.0) -> np.ndarray:
    """A light gradient across the wall (left to right, top to bottom)."""
    h, w = image.shape[:2]
    gain = np.linspace(left, right, w)[None, :] * np.linspace(top, bottom, h)[:, None]
    return np.clip(image * gain[:, :, None], 0, 255).astype(np.uint8)


def _disc(image: np.ndarray, centre_m, radius_m: float, colour, wall_h_m: float) -> np.ndarray:
    """Draw an anti-aliased disc; returns its centre in wall pixels (col, row)."""
    shift = 4
    col = centre_m[0] / WALL_MPP
    row = (wall_h_m - centre_m[1]) / WALL_MPP
    cv2.circle(image, (int(round(col * 2**shift)), int(round(row * 2**shift))), int(round(radius_m / WALL_MPP * 2**shift)),
               tuple(int(c) for c in colour), -1, cv2.LINE_AA, shift)
    return np.array([col, row])


def luma601(bgr) -> float:
    """Rec.601 luma of a BGR colour (0.299 R + 0.587 G + 0.114 B)."""
    blue, green, red = (float(c) for c in bgr)
    return 0.299 * red + 0.587 * green + 0.114 * blue


#: The wall and dot colours (BGR) of the ``red_on_grey`` row: a neutral grey and a saturated
#: red whose Rec.601 luma is within 1 level of it (111 and 110.8).
RED_ON_GREY = ((111, 111, 111), (60, 60, 230))


def dots_wall(kind: str) -> Wall:
    """The dot walls of the issue's table.

    * ``bright``: three bright dots (LEDs, retro-reflectors) on a dark wall;
    * ``red``: four red dots on a light wall, a dark door frame beside them;
    * ``black5``: five black dots of 3-8 cm on a beige poster, with a picture frame nearby;
    * ``red_on_grey``: four saturated red dots on a neutral grey of the same luma, a door
      frame, a picture frame and a darker notice board nearby.
    Dots are placed in wall metres (x from the wall image's left edge, z above the floor).
    """
    width, height = 3.2, 1.8
    if kind == "bright":
        image = _canvas(width, height, (38, 40, 42))
        layout = [((0.75, 1.05), 0.05), ((2.45, 0.95), 0.05), ((1.55, 0.52), 0.05)]
        colour = (235, 240, 245)
        # A dim, round-ish lamp reflection well away from the target (a distractor of the wrong size).
        cv2.rectangle(image, (60, 60), (180, 110), (70, 70, 70), -1)
    elif kind == "red":
        image = _canvas(width, height, (196, 200, 204))
        layout = [((0.65, 1.08), 0.045), ((2.35, 1.12), 0.045), ((2.25, 0.55), 0.045), ((0.85, 0.50), 0.045)]
        colour = (40, 45, 200)
        # A dark door frame to the right of the dots, reaching the floor.
        x0 = int(2.75 / WALL_MPP)
        cv2.rectangle(image, (x0, 100), (x0 + 40, image.shape[0] - 1), (40, 50, 60), -1)
        cv2.rectangle(image, (x0 + 40, 100), (image.shape[1] - 1, 140), (40, 50, 60), -1)
    elif kind == "red_on_grey":
        # Saturated red dots on a neutral grey of the same Rec.601 luma (RED_ON_GREY): in gray
        # the dots vanish; only colour tells them from the wall.
        grey, red = RED_ON_GREY
        image = _canvas(width, height, grey)
        layout = [((0.60, 1.12), 0.05), ((2.40, 1.06), 0.05), ((2.20, 0.50), 0.05), ((0.90, 0.55), 0.05), ((1.50, 0.75), 0.05)]
        colour = red
        # Distractors: a dark door frame reaching the floor on the right, a dark picture
        # frame on the left, and a darker grey notice board between the dots.
        x0 = int(2.75 / WALL_MPP)
        cv2.rectangle(image, (x0, 100), (x0 + 40, image.shape[0] - 1), (40, 50, 60), -1)
        cv2.rectangle(image, (x0 + 40, 100), (image.shape[1] - 1, 140), (40, 50, 60), -1)
        cv2.rectangle(image, (20, 150), (170, 420), (35, 35, 35), 8)
        cv2.rectangle(image, (int(1.3 / WALL_MPP), int(0.55 / WALL_MPP)), (int(1.7 / WALL_MPP), int(0.85 / WALL_MPP)), (80, 80, 80), -1)
    elif kind == "black5":
        image = _canvas(width, height, (150, 160, 165))  # painted wall
        poster = (slice(int(0.55 / WALL_MPP), int(1.45 / WALL_MPP)), slice(int(0.25 / WALL_MPP), int(2.75 / WALL_MPP)))
        image[poster] = (170, 210, 230)  # beige poster
        layout = [((0.45, 1.10), 0.03), ((2.45, 1.15), 0.04), ((1.40, 0.85), 0.05), ((2.30, 0.50), 0.08), ((0.60, 0.45), 0.06)]
        colour = (25, 25, 25)
        # A dark picture frame (a thin rectangle) to the right of the poster.
        cv2.rectangle(image, (int(2.85 / WALL_MPP), 300), (int(3.1 / WALL_MPP), 600), (30, 30, 30), 8)
    elif kind == "low_contrast":
        # Dark-grey dots 25 gray levels below a mid-grey wall (before the lighting and the
        # sensor noise): a dim room, a cheap print.
        image = _canvas(width, height, (128, 128, 128))
        layout = [((0.55, 1.10), 0.05), ((2.40, 1.12), 0.05), ((2.25, 0.50), 0.05), ((0.80, 0.48), 0.05), ((1.50, 0.80), 0.05)]
        colour = (103, 103, 103)
    elif kind == "low_contrast20":
        # Dark-grey dots 20 gray levels below a mid-grey wall, before the lighting (about
        # 17-22 levels after it) and the sensor noise.
        image = _canvas(width, height, (128, 128, 128))
        layout = [((0.55, 1.10), 0.05), ((2.40, 1.12), 0.05), ((2.25, 0.50), 0.05), ((0.80, 0.48), 0.05), ((1.50, 0.80), 0.05)]
        colour = (108, 108, 108)
    elif kind == "sizes3x":
        # Black dots whose radii differ 3x (3 to 9 cm) on a white poster.
        image = _canvas(width, height, (225, 228, 230))
        layout = [((0.50, 1.10), 0.03), ((2.45, 1.15), 0.09), ((1.45, 0.85), 0.05), ((2.30, 0.45), 0.04), ((0.65, 0.45), 0.07)]
        colour = (30, 30, 30)
    else:
        raise ValueError(kind)
    points = np.array([_disc(image, centre, radius, colour, height) for centre, radius in layout])
    image = _lighting(image, 0.8, 1.1, 1.05, 0.9)
    return Wall(image, WALL_MPP, (5.8, -0.05, height / 2), yaw=np.radians(-7.0), points=points)


ARUCO_DICTIONARIES = ("DICT_6X6_250", "DICT_APRILTAG_36h11")


def marker_wall(dictionary: str, marker_id: int, side_m: float = 0.4, extra: list[tuple[str, int, float, tuple[float, float]]] | None = None) -> Wall:
    """A marker of ``side_m`` metres (with its white quiet zone) on a painted wall, centred 1.0 m high."""
    width, height = 2.4, 1.6
    image = _canvas(width, height, (175, 185, 190))
    points = []

    def place(name, ident, side, centre):
        px = int(round(side / WALL_MPP))
        dictionary_ = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))
        marker = cv2.aruco.generateImageMarker(dictionary_, ident, px)
        quiet = px // 6
        col0 = int(round(centre[0] / WALL_MPP - px / 2))
        row0 = int(round((height - centre[1]) / WALL_MPP - px / 2))
        image[row0 - quiet:row0 + px + quiet, col0 - quiet:col0 + px + quiet] = 250
        image[row0:row0 + px, col0:col0 + px] = marker[:, :, None]
        # Corners of the marker as printed, TL, TR, BR, BL (pixel edges: -0.5).
        return np.array([[col0 - 0.5, row0 - 0.5], [col0 + px - 0.5, row0 - 0.5], [col0 + px - 0.5, row0 + px - 0.5], [col0 - 0.5, row0 + px - 0.5]])

    points.append(place(dictionary, marker_id, side_m, (1.2, 0.85)))
    for name, ident, side, centre in extra or []:
        points.append(place(name, ident, side, centre))
    image = _lighting(image, 0.85, 1.05)
    return Wall(image, WALL_MPP, (5.8, -0.05, height / 2), yaw=np.radians(-7.0), points=np.concatenate(points))


def chessboard_wall(inner: tuple[int, int] = (7, 5), square_m: float = 0.06) -> Wall:
    """A printed chessboard of ``inner`` = (columns, rows) inner corners and ``square_m``
    squares (with a white margin of one square) on a painted wall, centred 1.0 m high.
    ``points`` are the inner corners, row by row from the top left (wall pixels)."""
    width, height = 2.4, 1.6
    image = _canvas(width, height, (175, 185, 190))
    px = int(round(square_m / WALL_MPP))
    columns, rows = inner[0] + 1, inner[1] + 1
    col0 = int(round(1.2 / WALL_MPP - columns * px / 2))
    row0 = int(round((height - 1.0) / WALL_MPP - rows * px / 2))
    image[row0 - px:row0 + (rows + 1) * px, col0 - px:col0 + (columns + 1) * px] = 245
    for r in range(rows):
        for c in range(columns):
            if (r + c) % 2 == 0:
                image[row0 + r * px:row0 + (r + 1) * px, col0 + c * px:col0 + (c + 1) * px] = 20
    corners = [[col0 + c * px - 0.5, row0 + r * px - 0.5] for r in range(1, rows) for c in range(1, columns)]
    image = _lighting(image, 0.85, 1.05)
    return Wall(image, WALL_MPP, (5.8, -0.05, height / 2), yaw=np.radians(-7.0), points=np.array(corners, float))


def charuco_wall(squares: tuple[int, int] = (6, 4), square_m: float = 0.12, marker_m: float = 0.09,
                 dictionary: str = "DICT_4X4_50", centre_height_m: float = 1.0, metres_per_px: float = WALL_MPP) -> Wall:
    """A ChArUco board of ``squares`` = (columns, rows) squares of ``square_m`` with markers
    of ``marker_m`` (OpenCV's ``CharucoBoard.generateImage`` as the print, a white margin of
    one square) on a painted wall printed at ``metres_per_px`` (a small board seen from
    close needs finer than 2 mm: its markers' white margins are a few millimetres).
    ``points`` are the inner corners in the board's corner ids' order (row by row from the
    top left), wall pixels."""
    width, height = 2.4, 1.6 + max(0.0, centre_height_m - 0.8)
    image = _canvas(width, height, (175, 185, 190), metres_per_px)
    px = int(round(square_m / metres_per_px))
    columns, rows = squares
    board = cv2.aruco.CharucoBoard(squares, square_m, marker_m, cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary)))
    printed = board.generateImage((columns * px, rows * px), marginSize=0, borderBits=1)
    col0 = int(round(1.2 / metres_per_px - columns * px / 2))
    row0 = int(round((height - centre_height_m) / metres_per_px - rows * px / 2))
    image[row0 - px:row0 + (rows + 1) * px, col0 - px:col0 + (columns + 1) * px] = 245
    image[row0:row0 + rows * px, col0:col0 + columns * px] = np.where(printed[:, :, None] > 127, 245, 20).astype(np.uint8)
    corners = [[col0 + c * px - 0.5, row0 + r * px - 0.5] for r in range(1, rows) for c in range(1, columns)]
    image = _lighting(image, 0.85, 1.05)
    return Wall(image, metres_per_px, (5.8, -0.05, height / 2), yaw=np.radians(-7.0), points=np.array(corners, float))


def marker_board_wall(dictionary: str = "DICT_4X4_50", grid: tuple[int, int] = (3, 2), side_m: float = 0.18, gap_m: float = 0.04,
                      centre_height_m: float = 1.0) -> Wall:
    """A board of ``grid`` = (columns, rows) markers (ids 0, 1, ... row by row) of ``side_m``
    with ``gap_m`` between them, on white paper, on a painted wall; ``points`` are their
    corners, marker by marker (TL, TR, BR, BL), wall pixels."""
    columns, rows = grid
    width, height = 2.4, 2.2
    image = _canvas(width, height, (175, 185, 190))
    px, gap = int(round(side_m / WALL_MPP)), int(round(gap_m / WALL_MPP))
    pitch = px + gap
    col0 = int(round(1.2 / WALL_MPP - (columns * pitch - gap) / 2))
    row0 = int(round((height - centre_height_m) / WALL_MPP - (rows * pitch - gap) / 2))
    image[row0 - gap:row0 + rows * pitch, col0 - gap:col0 + columns * pitch] = 250
    cv_dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    points = []
    for ident in range(columns * rows):
        r, c = divmod(ident, columns)
        top, left = row0 + r * pitch, col0 + c * pitch
        image[top:top + px, left:left + px] = cv2.aruco.generateImageMarker(cv_dictionary, ident, px)[:, :, None]
        points += [[left - 0.5, top - 0.5], [left + px - 0.5, top - 0.5], [left + px - 0.5, top + px - 0.5], [left - 0.5, top + px - 0.5]]
    image = _lighting(image, 0.85, 1.05)
    return Wall(image, WALL_MPP, (5.8, -0.05, height / 2), yaw=np.radians(-7.0), points=np.array(points, float))


def brick_canvas(width_m: float, height_m: float) -> np.ndarray:
    """A brick wall: ``skimage.data``'s photograph of bricks (512 px for about 1 m) tiled, mirrored at each seam."""
    from skimage import data

    tile = cv2.resize(data.brick(), (500, 500), interpolation=cv2.INTER_CUBIC)
    w, h = int(round(width_m / WALL_MPP)), int(round(height_m / WALL_MPP))
    mirrored = np.block([[tile, tile[:, ::-1]], [tile[::-1], tile[::-1, ::-1]]])
    tiled = np.tile(mirrored, (h // 1000 + 1, w // 1000 + 1))[:h, :w]
    # Brick red: the gray photograph as the luminance of a terracotta colour.
    return np.clip(tiled[:, :, None] * (np.array([70, 95, 170]) / 128.0), 0, 255).astype(np.uint8)


def photo_wall(name: str = "coffee", poster_width_m: float = 1.8, brick: bool = False) -> Wall:
    """A real photograph from ``skimage.data`` printed ``poster_width_m`` wide on a painted
    wall, or (``brick``) on a brick wall."""
    from skimage import data

    photo = getattr(data, name)()
    if photo.ndim == 2:
        photo = np.repeat(photo[:, :, None], 3, axis=2)
    photo = cv2.cvtColor(photo[:, :, :3], cv2.COLOR_RGB2BGR)
    px_w = int(round(poster_width_m / WALL_MPP))
    px_h = int(round(px_w * photo.shape[0] / photo.shape[1]))
    poster = cv2.resize(photo, (px_w, px_h), interpolation=cv2.INTER_CUBIC)
    width, height = poster_width_m + 1.0, max(1.9, px_h * WALL_MPP + 0.5)
    if brick:  # the bricks fill the whole view (a painted wall's edges, replicated, look alike)
        width, height = poster_width_m + 9.0, 3.5
    image = brick_canvas(width, height) if brick else _canvas(width, height, (160, 176, 186))
    row0 = int(round((height - 0.95) / WALL_MPP - px_h / 2))
    col0 = int(round((image.shape[1] - px_w) / 2))
    image[row0:row0 + px_h, col0:col0 + px_w] = poster
    image = _lighting(image, 0.85, 1.08)
    corners = np.array([[col0, row0], [col0 + px_w, row0], [col0 + px_w, row0 + px_h], [col0, row0 + px_h]], float) - 0.5
    return Wall(image, WALL_MPP, (5.8, -0.05, height / 2), yaw=np.radians(-7.0), points=corners)


def photo_with_tags_wall(name: str = "coffee", poster_width_m: float = 1.8, tag_m: float = 0.12) -> Wall:
    """:func:`photo_wall` with two small ArUco markers (DICT_4X4_50, ids 1 and 2, ``tag_m``
    wide, white quiet zone) printed side by side in the photograph's top left corner: a
    lab's poster with fiducials for another purpose. ``points`` stay the photograph's
    corners."""
    return tags_printed_in(photo_wall(name, poster_width_m), tag_m, ((0.08, 0.12), (0.18, 0.12)), first_id=1)


def tags_printed_in(wall: Wall, tag_m: float, places, first_id: int) -> Wall:
    """``wall`` (a :func:`photo_wall`) with ArUco markers (DICT_4X4_50, ids from
    ``first_id``, ``tag_m`` wide, white quiet zone) printed in its photograph, centred at
    ``places`` (fractions of its width and height)."""
    image = wall.image.copy()
    (left, top), (right, bottom) = wall.points[0] + 0.5, wall.points[2] + 0.5
    px = int(round(tag_m / WALL_MPP))
    quiet = px // 4
    cv_dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    for ident, (fx, fy) in enumerate(places, start=first_id):
        col = int(round(left + fx * (right - left) - px / 2))
        row = int(round(top + fy * (bottom - top) - px / 2))
        image[row - quiet:row + px + quiet, col - quiet:col + px + quiet] = 245
        image[row:row + px, col:col + px] = cv2.aruco.generateImageMarker(cv_dictionary, ident, px)[:, :, None]
    return replace(wall, image=image)


# --------------------------------------------------------------------------- cases
def case(name: str) -> tuple[Wall, Camera, Effects]:
    """The issue's table, row by row: the wall, the camera and the sensor's effects."""
    plain = Camera()
    if name == "bright_dots":
        return dots_wall("bright"), plain, Effects(noise=2.5)
    if name == "red_dots":
        return dots_wall("red"), plain, Effects()
    if name == "red_on_grey":
        return dots_wall("red_on_grey"), plain, Effects()
    if name == "black_dots_distorted":
        camera = Camera(distortion=(-0.22, 0.05, 0.0005, -0.0003, 0.0))
        return dots_wall("black5"), camera, Effects(exposure_s=0.06, blur_samples=3, jpeg_quality=85)
    if name == "noisy_dots":
        # Low light at high gain: 20 gray levels of sensor noise, then MJPG.
        return dots_wall("black5"), plain, Effects(noise=20.0)
    if name == "aruco_6x6":
        return marker_wall("DICT_6X6_250", 23), plain, Effects()
    if name == "apriltag_36h11":
        return marker_wall("DICT_APRILTAG_36h11", 5), plain, Effects()
    if name == "photo":
        return photo_wall("coffee", 1.8), plain, Effects()
    if name == "small_apriltag":
        # A 25 cm AprilTag, the start 4.3 m from it: about 30 px wide in F*, the farthest frame.
        wall = marker_wall("DICT_APRILTAG_36h11", 5, side_m=0.25)
        return replace(wall, centre=(4.3, *wall.centre[1:])), plain, Effects()
    if name == "chessboard":
        return chessboard_wall(), plain, Effects()
    if name == "low_contrast_dots":
        return dots_wall("low_contrast"), plain, Effects(noise=3.0)
    if name == "dots_sizes_3x":
        return dots_wall("sizes3x"), plain, Effects()
    if name == "low_contrast20_dots":
        return dots_wall("low_contrast20"), plain, Effects(noise=3.0)
    if name == "charuco":
        # A 6x4 ChArUco board of 20 cm squares (DICT_4X4_50, 15 cm markers), the start 4.6 m
        # from it: its markers about 16 px wide in F*.
        wall = charuco_wall(square_m=0.2, marker_m=0.15, centre_height_m=0.65)
        return replace(wall, centre=(4.6, *wall.centre[1:])), plain, Effects()
    if name == "charuco_board":
        # A printed A1 ChArUco board, 7x5 squares of 12 cm (DICT_4X4_50, 9 cm markers), with
        # the 3x2 board's barrel distortion, the start 3.3 m from it: its markers about 13 px
        # wide in F*, the nearest frames show part of it. Printed at 1 mm (its markers'
        # white margins are 1.5 cm).
        wall = charuco_wall((7, 5), 0.12, 0.09, centre_height_m=0.45, metres_per_px=0.001)
        return replace(wall, centre=(3.3, *wall.centre[1:])), Camera(distortion=(-0.22, 0.05, 0.0005, -0.0003, 0.0)), Effects()
    if name == "charuco_partial":
        # The same board hung higher (its centre 1.0 m above the floor): its top row leaves
        # the top of the view in the last frames of the drive.
        wall = charuco_wall(square_m=0.2, marker_m=0.15, centre_height_m=1.0)
        return replace(wall, centre=(4.6, *wall.centre[1:])), plain, Effects()
    if name == "aruco_board_partial":
        # The 3x2 board of ArUco 4x4 markers with barrel distortion, hung high: its
        # top row leaves the top of the view in the last 16 of the 60 frames.
        camera = Camera(distortion=(-0.22, 0.05, 0.0005, -0.0003, 0.0))
        wall = marker_board_wall(centre_height_m=1.2)
        return replace(wall, centre=(4.6, *wall.centre[1:])), camera, Effects()
    if name == "photo_with_tags":
        return photo_with_tags_wall(), plain, Effects()
    raise ValueError(name)


@dataclass(frozen=True)
class CurvingDrive(Drive):
    """A drive whose turn rate ramps up then decays (a curve, then a straight approach)."""

    turn: float = 0.12  # rad/s at its peak

    def w(self, t: float) -> float:
        return self.turn * np.sin(np.pi * min(t / self.duration, 1.0)) ** 2 * (1.0 if t < 0.6 * self.duration else -0.6)


CASES = ("bright_dots", "red_dots", "black_dots_distorted", "aruco_6x6", "apriltag_36h11", "photo")
EXPECTED_KIND = {"charuco": "charuco", "charuco_board": "charuco", "charuco_partial": "charuco", "aruco_board_partial": "aruco", "photo_with_tags": "texture",
                 "low_contrast20_dots": "dots","small_apriltag": "aruco", "chessboard": "chessboard", "low_contrast_dots": "dots", "dots_sizes_3x": "dots",
                 "noisy_dots": "dots", "bright_dots": "dots", "red_dots": "dots", "red_on_grey": "dots", "black_dots_distorted": "dots",
                 "aruco_6x6": "aruco", "apriltag_36h11": "aruco", "photo": "texture"}


def make_footage(name: str, folder: Path, drive: Drive = Drive(), seed: int = 7) -> dict:
    wall, camera, effects = case(name)
    return FootageMaker(wall, camera, effects, seed=seed).write(Path(folder), drive)


def errors_against_truth(model, truth: dict) -> dict:
    """RMS errors of a fit (hbvs FitModel, read by the caller) against the footage's truth."""
    t = np.asarray(truth["t"])
    keep = (t >= model.trajectory.t_start) & (t <= model.trajectory.t_end)
    fitted = model.trajectory.evaluate(t[keep])
    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))  # noqa: E731
    normal = np.asarray(model.normal, float)
    return {
        "theta_deg": float(np.degrees(rms(fitted.theta_d - truth["theta_d"][keep]))),
        "x_hd1": rms(fitted.x_hd1 - truth["x_hd"][keep, 0]),
        "x_hd2": rms(fitted.x_hd2 - truth["x_hd"][keep, 1]),
        "normal_deg": float(np.degrees(np.arccos(np.clip(normal @ truth["normal"] / np.linalg.norm(normal), -1, 1)))),
    }


# --------------------------------------------------------------------------- the bound
def wall_points_world(wall: Wall) -> np.ndarray:
    """The target's points (``wall.points``) in the world (m), shape (N, 3)."""
    M = wall.wall_to_world()
    return (M @ np.column_stack([wall.points, np.ones(len(wall.points))]).T).T


def ideal_pixels(wall: Wall, camera: Camera, poses: np.ndarray) -> np.ndarray:
    """Every target point's ideal (pinhole, undistorted) pixel in every frame, shape (F, N, 2)."""
    world = wall_points_world(wall)
    out = np.empty((len(poses), len(world), 2))
    for k, pose in enumerate(np.asarray(poses, float)):
        q = (world - np.array([pose[0], pose[1], camera.camera_height])) @ camera_rotation(pose[2]).T
        out[k] = np.column_stack([camera.fx * q[:, 0] / q[:, 2] + camera.cx, camera.fy * q[:, 1] / q[:, 2] + camera.cy])
    return out


def cramer_rao_bound(wall: Wall, camera: Camera, poses: np.ndarray, noise_px: float, reference: int = 0,
                     frames: np.ndarray | None = None, shutter: RollingShutter | None = None, drive: Drive | None = None,
                     readout_known: bool = False) -> dict:
    """The Cramer-Rao bound of the joint estimate at the footage's true geometry.

    Unknowns: the wall's normal (yaw and tilt), every target point's two coordinates in the
    wall's plane, and every frame's planar pose (x, y, phi) but F*'s (fixed: the gauge),
    with the distance from F* to the wall fixed (the scale). Measurements: every point's
    ideal pixel in every frame, with independent Gaussian noise of ``noise_px`` per
    coordinate. The Fisher information is ``J^T J / noise^2`` with J the projections'
    Jacobian at the truth (central differences); its inverse bounds the covariance of any
    unbiased estimate. Written here from the footage's own geometry (no hbvs code).

    With a rolling ``shutter`` (``poses`` are then the frames of ``drive``), each point is
    seen as :class:`RollingShutterMaker` draws it: from the pose at its row's time
    (:meth:`RollingShutter.delay_fraction` of its row), the frame's pose moved by the drive's
    motion over that delay. The readout time is then one more unknown, a nuisance that the
    inverse marginalises (it can only raise the bound), unless ``readout_known``.

    Returns
    -------
    dict
        ``theta_sigma`` (rad, per frame of ``frames``; 0 for F*) and ``normal_sigma`` (rad).
    """
    frames = np.arange(len(poses)) if frames is None else np.asarray(frames)
    world = wall_points_world(wall)
    ref = np.asarray(poses[reference], float)
    d = float((np.asarray(wall.centre) - np.array([ref[0], ref[1], camera.camera_height])) @ wall.normal)
    base_yaw = wall.yaw

    def plane(yaw: float, tilt: float):
        n = np.array([np.cos(yaw) * np.cos(tilt), np.sin(yaw) * np.cos(tilt), np.sin(tilt)])
        e1 = np.cross(n, [0.0, 0.0, 1.0])
        e1 /= np.linalg.norm(e1)
        return n, e1, np.cross(n, e1)

    centre_ref = np.array([ref[0], ref[1], camera.camera_height])
    n0, e10, e20 = plane(base_yaw, 0.0)
    coords = np.column_stack([(world - centre_ref) @ e10, (world - centre_ref) @ e20])
    others = [k for k in frames if k != reference]
    readout = [] if shutter is None or readout_known else [shutter.readout_s]
    x0 = np.concatenate([[base_yaw, 0.0], coords.ravel(), np.asarray(poses)[others].ravel(), readout])
    poses_end = 2 + 2 * len(world) + 3 * len(others)

    def project(at: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Pixels (F, N, 2) of ``points`` (N, 3) seen from ``at`` (F, 1 or N, 3), from the principal point."""
        c, s = np.cos(at[..., 2]), np.sin(at[..., 2])
        # camera_rotation's rows (right, down, forward) for every frame (and row) at once.
        right = np.stack([s, -c, np.zeros_like(c)], axis=-1)
        down = np.broadcast_to([0.0, 0.0, -1.0], right.shape)
        forward = np.stack([c, s, np.zeros_like(c)], axis=-1)
        offset = points[None] - np.concatenate([at[..., :2], np.full(at.shape[:-1] + (1,), camera.camera_height)], axis=-1)
        q = [np.einsum("fnk,fnk->fn", np.broadcast_to(axis, offset.shape), offset) for axis in (right, down, forward)]
        return np.stack([camera.fx * q[0] / q[2], camera.fy * q[1] / q[2]], axis=-1)

    true_poses = np.asarray(poses, float)[frames][:, None]
    if shutter is not None:
        # Each point's row's delay (a fraction of the readout) at the truth: where the pose
        # at that delay puts it (a few passes settle which band holds it).
        pose_of_time = drive_pose_function(drive)
        times = drive.times()[frames]
        at_times = pose_of_time(times).T[:, None]  # (F, 1, 3)

        def moved(delay: np.ndarray, readout_s: float) -> np.ndarray:
            """How far the drive moves (F, N, 3) from each frame's time to its points' rows' times."""
            return pose_of_time((times[:, None] + readout_s * delay).ravel()).T.reshape(delay.shape + (3,)) - at_times

        delay = np.zeros((len(frames), len(world)))
        for _ in range(5):
            delay = shutter.delay_fraction(project(true_poses + moved(delay, shutter.readout_s), world)[..., 1] + camera.cy, camera.height)

    def pixels(x: np.ndarray) -> np.ndarray:
        n, e1, e2 = plane(x[0], x[1])
        ab = x[2:2 + 2 * len(world)].reshape(-1, 2)
        points = centre_ref + d * n + ab[:, :1] * e1 + ab[:, 1:] * e2
        all_poses = np.asarray(poses, float).copy()
        all_poses[others] = x[2 + 2 * len(world):poses_end].reshape(-1, 3)
        at = all_poses[frames][:, None]
        if shutter is not None:
            at = at + moved(delay, x[poses_end] if len(readout) else shutter.readout_s)
        return project(at, points).ravel()

    h = 1e-6
    J = np.empty((pixels(x0).size, x0.size))
    for j in range(x0.size):
        step = np.zeros_like(x0)
        step[j] = h
        J[:, j] = (pixels(x0 + step) - pixels(x0 - step)) / (2 * h)
    covariance = np.linalg.inv(J.T @ J) * noise_px**2
    phi_sigma = np.sqrt(np.diag(covariance)[2 + 2 * len(world):poses_end].reshape(-1, 3)[:, 2])
    theta_sigma = np.zeros(len(frames))
    theta_sigma[[i for i, k in enumerate(frames) if k != reference]] = phi_sigma
    return {"theta_sigma": theta_sigma, "normal_sigma": float(np.sqrt(covariance[0, 0] + covariance[1, 1]))}


# --------------------------------------------------------------------------- issue 24's other rows
@dataclass(frozen=True)
class Pole:
    """A vertical pole close to the camera that crosses the view from left to right between
    ``start_s`` and ``end_s`` (drive time), hiding whatever is behind it."""

    start_s: float = 3.0
    end_s: float = 8.0
    width_px: float = 40.0  # in frame pixels
    colour: tuple[int, int, int] = (60, 70, 75)


class PoleMaker(FootageMaker):
    """:class:`FootageMaker` with a :class:`Pole` passing in front of the wall."""

    def __init__(self, wall: Wall, camera: Camera, effects: Effects = Effects(), seed: int = 0, pole: Pole = Pole()) -> None:
        super().__init__(wall, camera, effects, seed)
        self.pole = pole

    def _exposure(self, pose_of_time, t: float) -> np.ndarray:
        canvas = super()._exposure(pose_of_time, t)
        ss, pole = self.effects.supersample, self.pole
        travel = (t - pole.start_s) / (pole.end_s - pole.start_s)
        if 0.0 <= travel <= 1.0:
            left = self.margin + ss * ((self.camera.width + pole.width_px) * travel - pole.width_px)
            columns = np.arange(canvas.shape[1])
            # Its edges anti-aliased: the covered fraction of each canvas column.
            cover = np.clip(np.minimum(columns + 1 - left, left + ss * pole.width_px - columns), 0.0, 1.0).astype(np.float32)
            canvas *= 1.0 - cover[None, :, None]
            canvas += cover[None, :, None] * np.asarray(pole.colour, np.float32)
        return canvas



@dataclass(frozen=True)
class RollingShutter:
    """Rows read out one after the other: the first row ``readout_s / 2`` before the frame's
    time, the last as much after (the truth is the middle row's pose). The frame is
    assembled from ``bands`` bands of rows, each warped at its own time."""

    readout_s: float = 0.033
    bands: int = 8

    def band_rows(self, height: int, band):
        """The first sensor row of a band (or an array of bands) and the one past its last."""
        return band * height // self.bands, (band + 1) * height // self.bands

    def band_delay(self, height: int, band):
        """When a band's rows are exposed, after the frame's time, as a fraction of the readout
        (its middle row's time, in [-1/2, 1/2])."""
        first, last = self.band_rows(height, band)
        return (first + last) / 2.0 / height - 0.5

    def delay_fraction(self, rows: np.ndarray, height: int) -> np.ndarray:
        """:meth:`band_delay` of the bands that hold ideal pixel rows ``rows`` (any shape)."""
        ends = self.band_rows(height, np.arange(self.bands))[1]
        return self.band_delay(height, np.clip(np.searchsorted(ends, np.floor(np.asarray(rows) + 0.5), side="right"), 0, self.bands - 1))


class RollingShutterMaker(FootageMaker):
    """:class:`FootageMaker` with a rolling shutter (rows exposed at different poses)."""

    def __init__(self, wall: Wall, camera: Camera, effects: Effects = Effects(), seed: int = 0,
                 shutter: RollingShutter = RollingShutter()) -> None:
        super().__init__(wall, camera, effects, seed)
        self.shutter = shutter

    def _exposure(self, pose_of_time, t: float) -> np.ndarray:
        ss, bands = self.effects.supersample, self.shutter.bands
        rows = self.camera.height
        canvas = None
        for b in range(bands):
            first, last = self.shutter.band_rows(rows, b)
            offset = self.shutter.readout_s * self.shutter.band_delay(rows, b)
            band = super()._exposure(pose_of_time, t + offset)
            if canvas is None:
                canvas = band
            # The band's rows on the ideal canvas (the margin rows go with the first and last band).
            top = 0 if b == 0 else self.margin + first * ss
            bottom = canvas.shape[0] if b == bands - 1 else self.margin + last * ss
            canvas[top:bottom] = band[top:bottom]
        return canvas


#: Rows of the issue's table that the cases above do not draw: (wall, camera, effects,
#: rolling shutter, a pole or None).
def extra_case(name: str):
    plain = Camera()
    barrel = Camera(distortion=(-0.22, 0.05, 0.0005, -0.0003, 0.0))
    if name == "photo_distorted_jpeg70":
        return photo_wall("coffee", 1.8), barrel, Effects(exposure_s=0.06, blur_samples=3, optical_blur=1.2, jpeg_quality=70), None
    if name == "photo_plain_rolling":
        # The cameraman: a large plain sky; rows read out over 33 ms; exposure drifting +-30 %.
        return photo_wall("camera", 1.8), plain, Effects(exposure_drift=0.3, noise=3.0), RollingShutter()
    if name == "low_contrast_dots_rolling":
        return dots_wall("low_contrast"), plain, Effects(noise=4.0), RollingShutter()
    if name == "aruco_board_3x2":
        return marker_board_wall(grid=(3, 2)), barrel, Effects(), None
    if name == "brick_sign":
        # A 1.2 m sign (a real photograph) on a real photograph of bricks.
        return photo_wall("chelsea", 1.2, brick=True), plain, Effects(), None
    if name == "dots_pole":
        return dots_wall("red"), plain, Effects(), Pole()
    raise ValueError(name)


def any_case(name: str):
    """(wall, camera, effects, rolling shutter, pole or None) of a row, from :func:`case` or :func:`extra_case`."""
    try:
        return (*case(name), None)
    except ValueError:
        return extra_case(name)


def make_any_footage(name: str, folder: Path, drive: Drive = Drive(), seed: int = 7) -> dict:
    """:func:`make_footage` for every row, the rolling-shutter ones included."""
    return make_style_footage(name, folder, drive, seed)


# --------------------------------------------------------------------------- issue 44's styles
@dataclass(frozen=True)
class SwerveDrive(Drive):
    """A drive of this file's own (none of hbvs's presets, nor :class:`Drive`'s weave): a
    start off to one side, two swerves of different periods on top of each other, and a
    speed that eases off toward the wall."""

    start: tuple[float, float, float] = (0.0, -0.20, 0.0)
    speed: float = 0.26
    weave: float = 0.15
    period: float = 8.0
    second_weave: float = 0.05  # rad/s amplitude of the faster swerve
    second_period: float = 3.1

    def v(self, t: float) -> float:
        return self.speed * (1.0 - 0.25 * t / self.duration)

    def w(self, t: float) -> float:
        # Cosines: the heading swings about the start's, not to one side of it.
        return (self.weave * np.cos(2 * np.pi * t / self.period)
                + self.second_weave * np.cos(2 * np.pi * t / self.second_period + 0.3))


def led_wall() -> Wall:
    """Three LEDs (4 cm, drawn at full white: the :class:`Bloom` sensor overexposes them) on a
    dark wall, with a dim grey switch plate well away from them."""
    width, height = 3.2, 1.8
    image = _canvas(width, height, (30, 32, 34))
    cv2.rectangle(image, (1300, 700), (1380, 800), (75, 75, 75), -1)
    layout = [((0.70, 1.10), 0.02), ((2.50, 1.00), 0.02), ((1.45, 0.45), 0.02)]
    points = np.array([_disc(image, centre, radius, (255, 255, 255), height) for centre, radius in layout])
    return Wall(image, WALL_MPP, (5.8, 0.05, height / 2), yaw=np.radians(-4.0), points=points)


def red_distractor_wall() -> Wall:
    """Four red dots on a plain grey wall, and a red fire-exit sign of the same red (a
    rectangle, not a dot) between them: a same-colour distractor."""
    width, height = 3.2, 1.8
    image = _canvas(width, height, (150, 152, 155))
    red = (45, 40, 205)
    layout = [((0.55, 1.15), 0.045), ((2.55, 1.05), 0.045), ((2.35, 0.45), 0.045), ((0.75, 0.50), 0.045)]
    points = np.array([_disc(image, centre, radius, red, height) for centre, radius in layout])
    cv2.rectangle(image, (int(1.35 / WALL_MPP), int(0.70 / WALL_MPP)), (int(1.85 / WALL_MPP), int(0.86 / WALL_MPP)), red, -1)
    image = _lighting(image, 0.9, 1.05, 1.0, 0.92)
    return Wall(image, WALL_MPP, (5.8, -0.10, height / 2), yaw=np.radians(-9.0), points=points)


def photo_small_fiducials_wall(name: str = "astronaut", poster_width_m: float = 1.3, tag_m: float = 0.12) -> Wall:
    """A photograph (``skimage.data``) with five small ArUco markers (DICT_4X4_50, ids 3-7,
    ``tag_m`` wide, white quiet zone) printed in it, one near each corner and one near its
    middle, as a lab marks a poster for another purpose. ``points`` stay the photograph's corners."""
    places = ((0.1, 0.1), (0.9, 0.12), (0.55, 0.45), (0.12, 0.88), (0.88, 0.9))
    return tags_printed_in(photo_wall(name, poster_width_m), tag_m, places, first_id=3)


@dataclass(frozen=True)
class Bloom:
    """A light source's excess charge spilling over (what a saturating LED does to a cheap
    sensor): the sensor's light above ``threshold`` gray levels (in the picture as the wall
    image draws it) is ``overexposure`` times brighter than drawn, and ``share`` of that
    excess spreads into a Gaussian halo of ``halo_px`` and a tail of ``smear_px`` down the
    columns (the readout direction), before the pixels clip at 255."""

    threshold: float = 200.0
    overexposure: float = 12.0
    share: float = 0.2
    halo_px: float = 2.0
    smear_px: float = 3.0


class BloomMaker(FootageMaker):
    """:class:`FootageMaker` whose sensor blooms around bright sources (:class:`Bloom`)."""

    def __init__(self, wall: Wall, camera: Camera, effects: Effects = Effects(), seed: int = 0, bloom: Bloom = Bloom()) -> None:
        super().__init__(wall, camera, effects, seed)
        self.bloom = bloom
        smear = bloom.smear_px * effects.supersample  # on the supersampled canvas
        length = int(np.ceil(6 * smear))
        # filter2D correlates: the upper half of a column kernel moves charge down the column.
        tail = np.exp(-np.arange(length + 1) / smear)
        self._smear = np.concatenate([tail[::-1], np.zeros(length)])[:, None].astype(np.float32)
        self._smear /= self._smear.sum()

    def _exposure(self, pose_of_time, t: float) -> np.ndarray:
        canvas = super()._exposure(pose_of_time, t)
        bloom = self.bloom
        excess = np.maximum(canvas - bloom.threshold, 0.0) * bloom.overexposure
        ss = self.effects.supersample
        spill = cv2.GaussianBlur(excess, (0, 0), bloom.halo_px * ss) + cv2.filter2D(excess, -1, self._smear)
        return canvas + excess * (1.0 - bloom.share) + 0.5 * bloom.share * spill


def fitted_radial_distortion(camera: Camera, true_distortion) -> tuple[float, float, float, float, float]:
    """The plumb_bob coefficients a two-term calibration (k1, k2; tangential kept, k3 = 0)
    reports for a lens whose truth is ``true_distortion`` (k1, k2, p1, p2, k3): the least
    squares fit of the radial factor over the frame's field of view (weighted by area), as a
    calibration that fixes k3 = 0 would find it. Its error is the imperfect lens model."""
    k1, k2, p1, p2, k3 = true_distortion
    corner = np.hypot(max(camera.cx, camera.width - camera.cx) / camera.fx, max(camera.cy, camera.height - camera.cy) / camera.fy)
    r = np.linspace(0.0, corner, 400)[1:]
    target = k1 * r**2 + k2 * r**4 + k3 * r**6
    design = np.column_stack([r**2, r**4]) * np.sqrt(r)[:, None]
    fitted = np.linalg.lstsq(design, target * np.sqrt(r), rcond=None)[0]
    return (float(fitted[0]), float(fitted[1]), p1, p2, 0.0)


@dataclass(frozen=True)
class CalibratedCamera(Camera):
    """A camera whose written calibration (``camera.yaml``) is a two-term fit of its true
    lens (:func:`fitted_radial_distortion`), not the lens itself."""

    @property
    def written_distortion(self) -> tuple[float, float, float, float, float]:
        return fitted_radial_distortion(self, self.distortion)


#: The styles of issue 44's table: (wall, camera, effects, extra) as :func:`any_case`
#: returns them (extra: a RollingShutter, a Pole, a Bloom or None), and each one's drive.
def style_case(name: str):
    plain = Camera()
    if name == "red_distractor":
        return red_distractor_wall(), plain, Effects(noise=2.5), None
    if name == "leds_bloom":
        return led_wall(), plain, Effects(noise=2.0, vignetting=0.3), Bloom()
    if name == "board_barrel_k3":
        # A 3x2 board of ArUco 4x4 markers under a barrel lens with a sixth-order term that
        # the written two-term calibration leaves out (0.1-0.3 px at the frame's edges).
        lens = CalibratedCamera(distortion=(-0.26, 0.08, 0.0004, -0.0002, -0.03))
        return marker_board_wall(grid=(3, 2), side_m=0.16, gap_m=0.05, centre_height_m=0.9), lens, Effects(), None
    if name == "photo_small_fiducials":
        return photo_small_fiducials_wall(), plain, Effects(), None
    if name == "dim_dots_rolling":
        # Dots 20 gray levels below a mid-grey wall, 4 levels of sensor noise, rows read out
        # over 30 ms in 12 bands.
        return dots_wall("low_contrast20"), plain, Effects(noise=4.0), RollingShutter(readout_s=0.030, bands=12)
    raise ValueError(name)


STYLES = ("red_distractor", "leds_bloom", "board_barrel_k3", "photo_small_fiducials", "dim_dots_rolling")
STYLE_DRIVES = {
    "red_distractor": SwerveDrive(start=(0.0, -0.20, 0.0), weave=0.15, period=8.0, second_weave=0.06, second_period=3.1),
    "leds_bloom": SwerveDrive(start=(0.0, 0.10, 0.0), weave=0.13, period=8.5, second_weave=0.05, second_period=2.7),
    "board_barrel_k3": SwerveDrive(start=(0.0, -0.15, 0.0), weave=0.14, period=7.0, second_weave=0.05, second_period=3.7),
    "photo_small_fiducials": SwerveDrive(start=(0.0, -0.05, 0.0), weave=0.13, period=7.5, second_weave=0.05, second_period=3.3),
    "dim_dots_rolling": SwerveDrive(start=(0.0, -0.20, -0.03), speed=0.28, weave=0.15, period=8.0, second_weave=0.06, second_period=2.9),
}


def any_style(name: str):
    """(wall, camera, effects, extra) of any row: :func:`style_case` or :func:`any_case`."""
    try:
        return style_case(name)
    except ValueError:
        return any_case(name)


def make_style_footage(name: str, folder: Path, drive: Drive | None = None, seed: int = 7) -> dict:
    """Render any row (:func:`any_style`) into ``folder`` on ``drive`` (None: the style's own,
    :data:`STYLE_DRIVES`, else :class:`Drive`); :meth:`FootageMaker.write`'s dict and the ``drive``."""
    wall, camera, effects, extra = any_style(name)
    drive = drive or STYLE_DRIVES.get(name, Drive())
    if isinstance(extra, Bloom):
        maker = BloomMaker(wall, camera, effects, seed, extra)
    elif isinstance(extra, Pole):
        maker = PoleMaker(wall, camera, effects, seed, extra)
    elif isinstance(extra, RollingShutter):
        maker = RollingShutterMaker(wall, camera, effects, seed, extra)
    else:
        maker = FootageMaker(wall, camera, effects, seed=seed)
    return maker.write(Path(folder), drive) | {"drive": drive}


def write_ros2_bag(folder: Path, made: dict, camera: Camera, jpeg_quality: int = 90) -> Path:
    """The footage as a ROS 2 bag in SQLite storage (``.db3``), written by the independent
    ``rosbags`` library: the video's frames as JPEG ``sensor_msgs/CompressedImage``, one
    ``CameraInfo`` (the written calibration) and the drive's commands as
    ``geometry_msgs/Twist`` on ``/cmd_vel``, each 1 ms before its frame."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    types = get_typestore(Stores.ROS2_HUMBLE).types
    store = get_typestore(Stores.ROS2_HUMBLE)
    header = lambda ns: types["std_msgs/msg/Header"](stamp=types["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9), frame_id="camera")  # noqa: E731
    drive, times = made["drive"], made["t"]
    capture = cv2.VideoCapture(str(made["video"]))
    folder = Path(folder)
    with Writer(folder, version=8, storage_plugin=StoragePlugin.SQLITE3) as writer:
        images = writer.add_connection("/camera/image_raw/compressed", "sensor_msgs/msg/CompressedImage", typestore=store)
        infos = writer.add_connection("/camera/camera_info", "sensor_msgs/msg/CameraInfo", typestore=store)
        commands = writer.add_connection("/cmd_vel", "geometry_msgs/msg/Twist", typestore=store)
        for k, t in enumerate(times):
            ok, frame = capture.read()
            assert ok, "the footage's video ends early"
            ns = 1_700_000_000_000_000_000 + int(round(t * 1e9))
            if k == 0:
                info = types["sensor_msgs/msg/CameraInfo"](
                    header=header(ns), height=camera.height, width=camera.width, distortion_model="plumb_bob",
                    d=np.array(camera.written_distortion, float), k=camera.K.ravel(), r=np.eye(3).ravel(),
                    p=np.array([camera.fx, 0, camera.cx, 0, 0, camera.fy, camera.cy, 0, 0, 0, 1, 0], float),
                    binning_x=0, binning_y=0,
                    roi=types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))
                writer.write(infos, ns, store.serialize_cdr(info, "sensor_msgs/msg/CameraInfo"))
            vector = types["geometry_msgs/msg/Vector3"]
            twist = types["geometry_msgs/msg/Twist"](linear=vector(x=float(drive.v(t)), y=0.0, z=0.0), angular=vector(x=0.0, y=0.0, z=float(drive.w(t))))
            writer.write(commands, ns - 1_000_000, store.serialize_cdr(twist, "geometry_msgs/msg/Twist"))
            data = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])[1].ravel()
            image = types["sensor_msgs/msg/CompressedImage"](header=header(ns), format="jpeg", data=data)
            writer.write(images, ns, store.serialize_cdr(image, "sensor_msgs/msg/CompressedImage"))
    capture.release()
    return folder
