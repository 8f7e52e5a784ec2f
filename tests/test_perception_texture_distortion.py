"""A texture under lens distortion (issue 24's JPEG-70 photograph): its points follow the
picture as the footage maker's truth says, although the picture's frame-to-frame map is no
homography in the recorded pixels (tests/footage.py, no hbvs renderer)."""

from __future__ import annotations

import cv2
import numpy as np

from hbvs_cli.core.camera import CameraIntrinsics, undistort_pixels
from hbvs_cli.perception.tracked import DetectorSpec, TrackedDetector, texture_points_for_template

import footage

DRIVE = footage.Drive(duration=12.0, fps=5.0, speed=0.24, period=9.0)


def test_texture_points_follow_the_picture_through_barrel_distortion():
    """Frames 0, 30 and 55 of the photograph with barrel distortion (k1 -0.22), blur and JPEG
    70: the tracked points, undistorted, against where the true homography between the
    undistorted frames puts F*'s (the poster's corners' homography; it ignores the motion
    blur's spread over the exposure). Measured 0.05-0.21 px at frames 30 and 55; 0.16-0.95 px
    at frame 30 when the texture was aligned in the recorded pixels."""
    wall, camera, effects, _ = footage.extra_case("photo_distorted_jpeg70")
    maker = footage.FootageMaker(wall, camera, effects, seed=7)
    times = DRIVE.times()
    poses = DRIVE.poses(times)
    pose_of = lambda t: np.array([np.interp(t, times, poses[:, j]) for j in range(3)])  # noqa: E731
    frames = [0, 30, 55]
    images = [cv2.imdecode(cv2.imencode(".jpg", maker.render(pose_of, times[k]), [cv2.IMWRITE_JPEG_QUALITY, 70])[1], cv2.IMREAD_COLOR)
              for k in frames]
    intrinsics = CameraIntrinsics(camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height, "plumb_bob", tuple(camera.distortion))
    spec = DetectorSpec(kind="texture", n_points=4, template_pixels=texture_points_for_template(images[0], intrinsics))
    tracker = TrackedDetector(spec, intrinsics, seed=0)
    tracked = [undistort_pixels(intrinsics, tracker.detect(image)) for image in images]
    corners = footage.ideal_pixels(wall, camera, poses[frames])  # the poster's corners, undistorted
    for k in (1, 2):
        truth, _ = cv2.findHomography(corners[0], corners[k], 0)
        expected = cv2.perspectiveTransform(tracked[0].reshape(-1, 1, 2), truth).reshape(-1, 2)
        miss = np.linalg.norm(tracked[k] - expected, axis=1)
        assert np.max(miss) < 0.4, (frames[k], miss)
