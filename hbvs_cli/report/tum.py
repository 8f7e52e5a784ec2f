"""``--export-tum``: the taught and repeated trajectories in the TUM RGB-D format
(``timestamp tx ty tz qx qy qz qw``: s, m in the world frame with tz the camera height), for
``evo_ape tum run.taught.tum run.repeated.tum``."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from ..core.frames import yaw_to_quaternion
from ..errors import InputError, UsageError
from ..io.output_target import write_output_bytes
from ..io.run_file import RunData

#: Suffixes of the two files written per run.
TAUGHT_SUFFIX = ".taught.tum"
REPEATED_SUFFIX = ".repeated.tum"


def check_exportable(runs: Sequence[RunData], directory: Path) -> None:
    """UsageError before writing anything for a run without ground truth (a replay or a real run), or
    two runs with one file stem."""
    seen: dict[Path, str] = {}
    for run in runs:
        if not run.has_poses():
            raise UsageError(
                f"{run.name}: --export-tum needs ground-truth poses, and this {run.info.get('mode', 'unknown')} run has none "
                "(only hbvs repeat --sim records them)"
            )
        taught = tum_paths(run, directory)[0]
        if taught in seen:
            raise UsageError(f"--export-tum: {seen[taught]} and {run.name} would both write {taught}; rename one of them")
        seen[taught] = run.name


def tum_paths(run: RunData, directory: Path) -> tuple[Path, Path]:
    """Where a run's taught and repeated trajectories go: ``<run-stem>.taught.tum`` and ``.repeated.tum``."""
    stem = Path(run.name).stem or "run"
    return directory / f"{stem}{TAUGHT_SUFFIX}", directory / f"{stem}{REPEATED_SUFFIX}"


def write_tum(run: RunData, directory: Path) -> tuple[Path, Path]:
    """Write a run's taught and repeated trajectories, at its camera height, into ``directory``
    (created if needed; the run passed :func:`check_exportable`); both paths."""
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{directory}: cannot create the folder for --export-tum ({exc.strerror})") from None
    paths = tum_paths(run, directory)
    z = run.camera_height
    for path, poses in zip(paths, (run.desired_pose, run.true_pose)):  # planar poses (K, 3), one line each
        lines = [f"{stamp:.9f} {x:.9f} {y:.9f} {z:.9f} {q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}"
                 for stamp, x, y, q in zip(run.state["t"], poses[:, 0], poses[:, 1], yaw_to_quaternion(poses[:, 2]))]
        text = "\n".join(["# timestamp tx ty tz qx qy qz qw", *lines]) + "\n"
        write_output_bytes(path, text.encode("utf-8"), "TUM trajectory")
    return paths
