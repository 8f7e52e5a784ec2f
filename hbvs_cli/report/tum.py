"""``--export-tum``: the taught and the repeated trajectories in the TUM RGB-D format.

One line per control step, space separated::

    timestamp tx ty tz qx qy qz qw

timestamp in seconds from the run's start, position in metres in the simulator's world
frame (z up; tz is the camera's height above the floor), orientation the unit quaternion
of the heading about z. ``evo_ape tum run.taught.tum run.repeated.tum`` then compares
them. Only runs with ground truth (``hbvs repeat --sim``) have poses to export.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..core.frames import yaw_to_quaternion
from ..errors import InputError, UsageError
from ..io.mcap import McapStream
from ..io.run_file import TRUE_POSE_TOPIC, RunData

#: Suffixes of the two files written per run.
TAUGHT_SUFFIX = ".taught.tum"
REPEATED_SUFFIX = ".repeated.tum"


def camera_height_m(source: Any, name: str = "") -> float | None:
    """The camera's height (m): the z of the first ground-truth pose of a run file.

    :func:`~hbvs_cli.io.run_file.read_run` keeps planar poses only; the height is constant,
    so one message is enough. ``None`` when the file has no ground-truth pose.

    Parameters
    ----------
    source : str, path or binary stream
        The run file (a stream must be positioned at its start).
    name : str
        How to name it in error messages.
    """
    for message in McapStream(source, topics={TRUE_POSE_TOPIC}, name=name):
        return float(message.foxglove(name).pose.position.z)
    return None


def require_ground_truth(run: RunData) -> None:
    """Raise :class:`UsageError` when the run has no poses to export (a replay or a real run)."""
    if run.true_pose is None or run.desired_pose is None:
        raise UsageError(
            f"{run.name}: --export-tum needs ground-truth poses, and this {run.info.get('mode', 'unknown')} run has none "
            "(only hbvs repeat --sim records them)"
        )


def check_exportable(runs: Sequence[RunData], directory: Path) -> None:
    """Fail before writing anything: a run without ground truth, or two runs with one file stem.

    Raises
    ------
    UsageError
    """
    seen: dict[Path, str] = {}
    for run in runs:
        require_ground_truth(run)
        taught = tum_paths(run, directory)[0]
        if taught in seen:
            raise UsageError(f"--export-tum: {seen[taught]} and {run.name} would both write {taught}; rename one of them")
        seen[taught] = run.name


def tum_lines(t: np.ndarray, poses: np.ndarray, height_m: float) -> list[str]:
    """TUM lines of planar poses.

    Parameters
    ----------
    t : ndarray, shape (K,)
        Timestamps (s).
    poses : ndarray, shape (K, 3)
        ``(x, y, phi)`` (m, m, rad).
    height_m : float
        The constant z (m).
    """
    quaternions = yaw_to_quaternion(poses[:, 2])
    return [
        f"{stamp:.9f} {x:.9f} {y:.9f} {height_m:.9f} {q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}"
        for stamp, x, y, q in zip(t, poses[:, 0], poses[:, 1], quaternions)
    ]


def tum_paths(run: RunData, directory: Path) -> tuple[Path, Path]:
    """Where a run's taught and repeated trajectories go: ``<run-stem>.taught.tum`` and ``.repeated.tum``."""
    stem = Path(run.name).stem or "run"
    return directory / f"{stem}{TAUGHT_SUFFIX}", directory / f"{stem}{REPEATED_SUFFIX}"


def write_tum(run: RunData, directory: Path, height_m: float) -> tuple[Path, Path]:
    """Write the taught and repeated trajectories of a run into ``directory`` (created if needed).

    Parameters
    ----------
    run : RunData
        A run with ground truth.
    directory : Path
    height_m : float
        Camera height (m), written as tz.

    Returns
    -------
    (taught, repeated) : paths written

    Raises
    ------
    UsageError
        The run has no ground truth.
    InputError
        The folder cannot be created or written.
    """
    from ..io.output_target import write_output_bytes

    require_ground_truth(run)
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{directory}: cannot create the folder for --export-tum ({exc.strerror})") from None
    paths = tum_paths(run, directory)
    t = run.state["t"]
    for path, poses in zip(paths, (run.desired_pose, run.true_pose)):
        text = "\n".join(["# timestamp tx ty tz qx qy qz qw", *tum_lines(t, poses, height_m)]) + "\n"
        write_output_bytes(path, text.encode("utf-8"), "TUM trajectory")
    return paths
