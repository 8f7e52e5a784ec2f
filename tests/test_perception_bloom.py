"""Bloom: saturated LEDs whose excess charge spills down the columns (tests/footage.py
``leds_bloom``) pull every dot's centroid alike; the pull is measured from the clipped cores
(perception/dots.py ``SharedPull``) for the fit's uncertainty (docs/uncertainty.md)."""

from __future__ import annotations

import cv2
import pytest

from hbvs_cli.core.camera import CameraIntrinsics
from hbvs_cli.perception.dots import SharedPull
from hbvs_cli.perception.tracked import DetectorSpec, TrackedDetector

import footage


@pytest.mark.parametrize("name, low, high", [("leds_bloom", 0.05, 0.2), ("bright_dots", 0.0, 0.0)])
def test_the_pull_of_saturated_dots_is_measured_and_unsaturated_ones_have_none(name, low, high):
    """Twelve frames through JPEG, as the video stores them. With bloom, every dot's
    intensity-weighted centre sits 0.11-0.13 px below the truth (seed 7's whole drive), and
    its clipped core above that centre in most detections: the pull measured (0.075 px on
    these twelve frames; 0.10-0.13 px over seeds 0, 1 and 7's whole taught drives). The
    unbloomed LEDs, drawn just below white, clip in few detections: no pull."""
    wall, camera, effects, extra = footage.any_style(name)
    drive = footage.STYLE_DRIVES.get(name, footage.Drive(duration=12.0, fps=5.0, speed=0.24, period=9.0))
    maker = footage.BloomMaker(wall, camera, effects, 7, extra) if isinstance(extra, footage.Bloom) else footage.FootageMaker(wall, camera, effects, 7)
    pose_of = footage.drive_pose_function(drive)
    intrinsics = CameraIntrinsics(camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height)
    detector = TrackedDetector(DetectorSpec(kind="dots", n_points=3, polarity="light"), intrinsics)
    pull = SharedPull("light")
    for t in drive.times()[::5]:
        image = cv2.imdecode(cv2.imencode(".jpg", maker.render(pose_of, t), [cv2.IMWRITE_JPEG_QUALITY, 90])[1], cv2.IMREAD_GRAYSCALE)
        pull.add(image, detector.detect(image))
    assert low <= pull.pull_px <= high, pull.pull_px
