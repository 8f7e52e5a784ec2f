"""Camera calibration files: ROS ``camera_info`` YAML (read and written), OpenCV ``FileStorage``,
Kalibr ``camchain.yaml`` and plain JSON, recognised by content; every format passes :mod:`.validate`,
and a user's mistake raises a one-line :class:`~hbvs_cli.errors.CalibrationError`."""

from __future__ import annotations

from .load import MAX_CALIBRATION_BYTES, load_calibration
from .ros import calibration_from_foxglove, calibration_to_foxglove, save_calibration_ros
from .mapping import intrinsics_from_values, stated_sigma

__all__ = [
    "MAX_CALIBRATION_BYTES", "load_calibration", "save_calibration_ros", "calibration_to_foxglove",
    "calibration_from_foxglove", "intrinsics_from_values", "stated_sigma",
]
