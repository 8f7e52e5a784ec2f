"""Camera calibration files: read the common formats, write ROS ``camera_info`` YAML.

Formats are recognised by content: ROS ``camera_info`` YAML (:mod:`.ros`), OpenCV
``FileStorage`` YAML/JSON/XML (:mod:`.opencv`), Kalibr ``camchain.yaml`` (:mod:`.kalibr`)
and plain JSON (:mod:`.plain_json`); keys match without regard to case, ``_`` or ``-``
(:mod:`.mapping`), and every format passes :mod:`.validate`. A user's mistake raises
:class:`~hbvs_cli.errors.CalibrationError`, one line starting with the file name.
"""

from __future__ import annotations

from .foxglove import calibration_from_foxglove, calibration_to_foxglove
from .load import MAX_CALIBRATION_BYTES, load_calibration, parse_calibration
from .ros import save_calibration_ros
from .validate import intrinsics_from_values

__all__ = [
    "MAX_CALIBRATION_BYTES",
    "load_calibration",
    "parse_calibration",
    "save_calibration_ros",
    "calibration_to_foxglove",
    "calibration_from_foxglove",
    "intrinsics_from_values",
]
