"""The sweep engine on a real LocalCluster: bounded batches, dead workers, a missing Dask."""

from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

pytest.importorskip("distributed")


@dataclass(frozen=True)
class Task:
    index: int
    marker: str


def crash_once(task: Task) -> dict:
    """Kills its worker process the first time it runs task 3; any other run returns."""
    if task.index == 3 and not os.path.exists(task.marker):
        Path(task.marker).write_text(str(os.getpid()))
        os._exit(1)
    return {"index": task.index, "pid": os.getpid(), "status": "ok"}


def crash_always(task: Task) -> dict:
    if task.index == 1:
        os._exit(1)
    return {"index": task.index, "pid": os.getpid(), "status": "ok"}


def test_a_dead_worker_has_its_run_retried_and_a_killer_run_is_recorded(tmp_path):
    import cloudpickle
    import dask

    from hbvs_cli.sweep.engine import dask_client, run_tasks

    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    rows, lost = [], []

    def on_lost(task, error):
        lost.append((task.index, error))
        return {"index": task.index, "status": "failed", "error": error}

    with dask.config.set({"distributed.scheduler.worker-ttl": None}), dask_client(None, None, 2, allowed_worker_deaths=1) as client:
        assert len(client.scheduler_info()["workers"]) == 2
        marker = str(tmp_path / "crashed")
        produced = run_tasks(client, (Task(i, marker) for i in range(12)), crash_once, rows.append, on_lost, in_flight=4, key_prefix="test-once")
        assert produced == 12 and sorted(r["index"] for r in rows) == list(range(12))
        assert all(r["status"] == "ok" for r in rows) and not lost
        assert os.path.exists(marker)  # a worker did die, and its run came back from another
        # Task 3 came back from a live worker, not the one it killed (which may have run
        # other tasks before it died).
        assert next(r["pid"] for r in rows if r["index"] == 3) != int(Path(marker).read_text())
        rows.clear()
        produced = run_tasks(client, (Task(i, marker) for i in range(3)), crash_always, rows.append, on_lost, in_flight=2, key_prefix="test-always")
        assert produced == 3 and [i for i, _ in lost] == [1]
        assert "KilledWorker" in lost[0][1]
        assert {r["index"]: r["status"] for r in rows} == {0: "ok", 1: "failed", 2: "ok"}


def test_without_dask_the_error_names_the_extra(tmp_path):
    code = (
        "import sys; sys.modules['distributed'] = None\n"
        "from hbvs_cli.cli.app import main\n"
        f"main(['sweep', {str(tmp_path / 'fit.mcap')!r}, '--vary', 'law=paper'])\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    assert result.stderr.strip() == "hbvs: error: hbvs sweep needs dask[distributed]: pip install 'hbvs[sweep]'"
