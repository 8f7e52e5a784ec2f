"""A short simulated teach -> fit -> repeat makes the same run as at commit 7bf9143.

Refactors of the loop, the options and the robot interfaces (issue 45) must not change what a
``--sim`` run computes. The digests in ``tests/data/run_digests.json`` were made by the code
at 7bf9143: a changed digest means a changed run, not a stale file. Regenerate them only for a
change that is meant to alter runs, and say so in its commit:
``python tests/test_byte_identity.py`` (writes the file from the installed hbvs).

The digest is of every message (topic, log time, payload bytes) and of the metadata records
without ``hbvs_version``, so a version bump alone does not change it.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
from pathlib import Path

import pytest

DIGESTS = Path(__file__).resolve().parent / "data" / "run_digests.json"
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


def test_sim_runs_are_the_same_as_before_the_refactor(tmp_path):
    from conftest import call_hbvs

    assert make_runs(tmp_path, call_hbvs) == json.loads(DIGESTS.read_text())


if __name__ == "__main__":
    import tempfile

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from conftest import call_hbvs

    with tempfile.TemporaryDirectory() as folder:
        DIGESTS.write_text(json.dumps(make_runs(Path(folder), call_hbvs), indent=1) + "\n")
    print(f"wrote {DIGESTS}")
