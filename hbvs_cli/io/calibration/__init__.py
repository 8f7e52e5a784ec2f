"""Camera calibration files: read the common formats, write ROS ``camera_info`` YAML.

Three families of files are recognised by their content (the extension is only a hint
people get wrong):

* the ROS ``camera_info`` YAML written by the ROS camera calibrator (``camera_matrix:
  {rows, cols, data}``...), and also the flat ``k:``/``d:`` lists of a dumped
  ``sensor_msgs/CameraInfo``;
* OpenCV ``FileStorage`` files (YAML with ``!!opencv-matrix`` tags, JSON with
  ``"type_id": "opencv-matrix"``, XML), parsed with :class:`cv2.FileStorage` and their
  matrices read field by field (``FileNode.mat()`` corrupts OpenCV's heap on a malformed
  matrix);
* Kalibr ``camchain.yaml`` (``cam0``: pinhole with radtan, equidistant or no distortion);
* plain JSON such as ``{"K": [[...], [...], [...]], "D": [...], "width": 640, "height": 480}``.

Key names are matched without regard to case, ``_`` or ``-``, so ``camera_matrix``,
``cameraMatrix`` and ``Camera_Matrix`` are the same key.

Every problem a user can cause raises :class:`~hbvs_cli.errors.CalibrationError` with a
one-line message that starts with the file name.

The package's rooms: :mod:`.load` (:func:`load_calibration`, format detection), one module
per format (:mod:`.ros`, :mod:`.opencv`, :mod:`.plain_json`, :mod:`.kalibr`), :mod:`.mapping` (keys to
intrinsics), :mod:`.validate` (the checks every format passes) and :mod:`.foxglove`.
Every public name is re-exported here.
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
