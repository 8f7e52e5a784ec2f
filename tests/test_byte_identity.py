"""A short simulated teach -> fit -> repeat makes the same run as at commit 7bf9143.

Refactors of the loop, the options and the robot interfaces (issue 45) must not change what a
``--sim`` run computes. The reference is the code of 7bf9143 itself, taken from git and run
beside this checkout's with the same numpy, SciPy and OpenCV: their releases change a run's
last bits (numpy 2.4.6, SciPy 1.17.1 and OpenCV 5.1.0 changed both digests), so digests kept
in a file hold only where they were made. Without that commit in the checkout (a shallow
clone), the digests in ``tests/data/run_digests.json`` are the reference, if they were made
with this machine's library versions; otherwise the test is skipped and says why. Regenerate
the file with ``python tests/test_byte_identity.py`` (from the installed hbvs) only for a
change meant to alter runs, and say so in its commit.

The digest is of every message (topic, log time, payload bytes) and of the metadata records
without ``hbvs_version``, so a version bump alone does not change it.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import subprocess
import sys
import tarfile
from pathlib import Path

import pytest

DIGESTS = Path(__file__).resolve().parent / "data" / "run_digests.json"
ROOT = Path(__file__).resolve().parent.parent
#: The commit before issue 45's refactors.
REFERENCE_COMMIT = "7bf9143224d9b2f7dd58ba1350903cf5717d90be"
#: Each run's ``hbvs repeat`` arguments after the fit file: the paper's law exactly, and the default law and filter.
RUNS = {
    "paper-no-filter": ("--sim", "--law", "paper", "--filter", "none"),
    "lateral-gain-default-filter": ("--sim", "--law", "lateral-gain"),
}
#: Seconds taught: 90 frames at 30 Hz, enough for the filter, the adaptation and the limits to act.
TEACH_SECONDS = "3"


def run_digest(path: Path) -> str:
    """sha256 of a run file's messages and its metadata without the version (hex)."""
    from mcap.reader import make_reader

    digest = hashlib.sha256()
    with open(path, "rb") as stream:
        reader = make_reader(stream)
        for record in reader.iter_metadata():
            kept = {key: value for key, value in record.metadata.items() if key != "hbvs_version"}
            digest.update(json.dumps([record.name, kept], sort_keys=True).encode())
        for _, channel, message in reader.iter_messages(log_time_order=True):
            digest.update(channel.topic.encode() + message.log_time.to_bytes(8, "little") + message.data)
    return digest.hexdigest()


def make_runs(folder: Path, hbvs) -> dict[str, str]:
    """Teach, fit and each of :data:`RUNS` in ``folder`` (relative names: a run records its input as given)."""
    here = os.getcwd()
    os.chdir(folder)
    try:
        for args in (("teach", "--sim", "--duration", TEACH_SECONDS, "-o", "t.mcap", "-q"), ("fit", "t.mcap", "-o", "f.mcap", "-q")):
            result = hbvs(*args)
            assert result.returncode == 0, result.stderr
        for name, args in RUNS.items():
            result = hbvs("repeat", "f.mcap", *args, "-o", f"{name}.mcap", "-q")
            assert result.returncode == 0, result.stderr
        return {name: run_digest(folder / f"{name}.mcap") for name in RUNS}
    finally:
        os.chdir(here)


def library_versions() -> dict[str, str]:
    """The versions of the libraries whose last bits a run's numbers depend on."""
    import cv2
    import numpy
    import scipy

    return {"numpy": numpy.__version__, "scipy": scipy.__version__, "opencv": cv2.__version__}


def reference_checkout(folder: Path) -> Path | None:
    """:data:`REFERENCE_COMMIT`'s tree extracted into ``folder`` from this checkout's git, or
    None when git or the commit is not there."""
    try:
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", "--format=tar", REFERENCE_COMMIT],
                                 capture_output=True, check=True, timeout=120).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
        tar.extractall(folder, filter="data")
    return folder


def test_sim_runs_are_the_same_as_before_the_refactor(tmp_path):
    from conftest import call_hbvs, run_hbvs

    reference = reference_checkout(tmp_path / "reference")
    if reference is None:
        stored = json.loads(DIGESTS.read_text())
        if stored["libraries"] != library_versions():
            pytest.skip(f"{REFERENCE_COMMIT[:7]} is not in this checkout, and {DIGESTS.name} was made with "
                        f"{stored['libraries']}, not {library_versions()}")
        expected = stored["digests"]
    else:
        (tmp_path / "before").mkdir()
        expected = make_runs(tmp_path / "before", lambda *args: run_hbvs(*args, env={"PYTHONPATH": str(reference)}))
    (tmp_path / "now").mkdir()
    assert make_runs(tmp_path / "now", call_hbvs) == expected


if __name__ == "__main__":
    import tempfile

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from conftest import call_hbvs

    with tempfile.TemporaryDirectory() as folder:
        record = {"libraries": library_versions(), "digests": make_runs(Path(folder), call_hbvs)}
        DIGESTS.write_text(json.dumps(record, indent=1) + "\n")
    print(f"wrote {DIGESTS}")
