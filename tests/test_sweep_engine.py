"""The sweep engine on a real LocalCluster: bounded batches of runs, dead workers, a missing Dask."""

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
    """Task 3 kills its worker every time; the others note each attempt in a file."""
    if task.index == 3:
        os._exit(1)
    with open(f"{task.marker}-{task.index}", "a") as attempts:
        attempts.write(f"{os.getpid()}\n")
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
        # One batch at a time: task 0 alone (no run time known yet), then 1-5 in one batch,
        # which task 3 kills twice; the batch is split and 1, 2, 4, 5 give their rows.
        attempts = str(tmp_path / "attempt")
        produced = run_tasks(client, (Task(i, attempts) for i in range(6)), crash_always, rows.append, on_lost, in_flight=1, key_prefix="test-always")
        assert produced == 6 and [i for i, _ in lost] == [3]
        assert "KilledWorker" in lost[0][1]
        assert {r["index"]: r["status"] for r in rows} == {0: "ok", 1: "ok", 2: "ok", 3: "failed", 4: "ok", 5: "ok"}
        # Task 1 ran twice in the batch that task 3 killed twice, then once alone.
        assert len(Path(f"{attempts}-1").read_text().split()) == 3
        assert len(Path(f"{attempts}-0").read_text().split()) == 1


class _FakeFuture:
    def __init__(self, key, batch):
        self.key, self.batch, self.status, self.doomed = key, batch, "pending", False

    def release(self):
        pass


#: Keys of the fake batches that started (what run_batch sets on the scheduler).
_STARTED: set = set()


class _FakeClient:
    """Runs batches in submission order; see :class:`_DyingCluster`."""

    def scheduler_info(self):
        return {"workers": {"a": {}, "b": {}}}

    def get_metadata(self, key, default):
        return key in _STARTED or default

    def submit(self, function, *args, key, pure, retries):
        return _FakeFuture(key, args[1])


class _DyingCluster:
    """``as_completed`` of a cluster where a batch holding task 3 kills its worker, and
    every other batch in flight at that moment is lost with it (the worst case of runs that
    shared the dying worker or its queued results): what made a healthy run look like a
    killer when the rule depended on who happened to be running."""

    def __init__(self, with_results, raise_errors):
        self.futures, self.submitted = [], []

    def dies_before_start(self, future):
        return False

    def add(self, future):
        self.futures.append(future)
        self.submitted.append(future.key)

    def has_ready(self):
        return bool(self.futures)

    def is_empty(self):
        return not self.futures

    def __iter__(self):
        return self

    def __next__(self):
        from hbvs_cli.sweep.engine import run_batch

        if not self.futures:
            raise StopIteration
        future = self.futures.pop(0)
        if self.dies_before_start(future):
            future.status = "error"
            error = RuntimeError("KilledWorker: its workers died before it started")
            return future, (type(error), error, None)
        if any(task.index == 3 for task in future.batch):
            _STARTED.add(future.key)
        if future.doomed or any(task.index == 3 for task in future.batch):
            for other in self.futures:
                other.doomed = True
            future.status = "error"
            error = RuntimeError("KilledWorker: a worker died running it")
            return future, (type(error), error, None)
        future.status = "finished"
        return future, run_batch(_ok, future.batch)


def _ok(task):
    return {"index": task.index, "status": "ok"}


@pytest.mark.parametrize("in_flight", [1, 2, 4, 8])
def test_only_the_run_that_kills_its_worker_with_the_cluster_to_itself_is_recorded(monkeypatch, in_flight):
    """The rule is deterministic: runs lost beside a killer are run again, and a run is
    recorded as lost only after it failed while nothing else was in flight."""
    import distributed

    from hbvs_cli.sweep.engine import run_tasks

    clusters = []
    monkeypatch.setattr(distributed, "as_completed", lambda **kw: clusters.append(_DyingCluster(**kw)) or clusters[-1])
    rows, lost = [], []

    def on_lost(task, error):
        lost.append(task.index)
        return {"index": task.index, "status": "failed"}

    produced = run_tasks(_FakeClient(), (Task(i, "") for i in range(12)), _ok, rows.append, on_lost, in_flight=in_flight,
                         key_prefix="fake", total=12)
    assert produced == 12 and lost == [3]
    assert {r["index"]: r["status"] for r in rows} == {i: "failed" if i == 3 else "ok" for i in range(12)}


class _RestartingWorkers(_DyingCluster):
    """Also: task 4's first two runs alone meet workers that die while being restarted,
    before it starts (what Dask counted against a healthy run at load 20)."""

    def dies_before_start(self, future):
        return [task.index for task in future.batch] == [4] and len(_keys_of_4(self.submitted)) <= 2


def _keys_of_4(keys):
    return [key for key in keys if key == "fake-4" or key.startswith("fake-4-")]


def test_a_run_whose_workers_die_before_it_starts_is_run_again_not_recorded(monkeypatch):
    import distributed

    from hbvs_cli.sweep.engine import run_tasks

    clusters = []
    monkeypatch.setattr(distributed, "as_completed", lambda **kw: clusters.append(_RestartingWorkers(**kw)) or clusters[-1])
    rows, lost = [], []
    produced = run_tasks(_FakeClient(), (Task(i, "") for i in range(8)), _ok, rows.append,
                         lambda task, error: lost.append(task.index) or {"index": task.index, "status": "failed"},
                         in_flight=1, key_prefix="fake", total=8)
    assert produced == 8 and lost == [3]
    assert len(_keys_of_4(clusters[0].submitted)) == 3  # twice its workers died before it started, then it ran


class _NoWorkers(_FakeClient):
    def scheduler_info(self):
        return {"workers": {}}


class _NeverDone(_DyingCluster):
    def has_ready(self):
        return False


def test_a_cluster_left_without_workers_stops_the_sweep_instead_of_waiting_forever(monkeypatch):
    import distributed

    from hbvs_cli.errors import OutputError
    from hbvs_cli.sweep.engine import run_tasks

    monkeypatch.setattr(distributed, "as_completed", lambda **kw: _NeverDone(**kw))
    with pytest.raises(OutputError, match="no worker for 0.3 s.*the same command resumes"):
        run_tasks(_NoWorkers(), (Task(i, "") for i in range(3)), _ok, [].append, None, in_flight=2, key_prefix="none",
                  no_worker_seconds=0.3)


def test_batches_hold_a_second_of_cpu_time_and_shrink_to_single_runs_at_the_end():
    from hbvs_cli.sweep.engine import BATCH_CPU_SECONDS, BATCH_WALL_SECONDS, MAX_BATCH, BatchSizer

    sizer = BatchSizer(total=1000, workers=2)
    assert sizer.next_size() == 1  # no run time known yet
    sizer.take(8)
    sizer.observe(8, 8 * 0.3, 8 * 0.1)  # 100 ms of CPU a run, 300 ms of wall time (a loaded machine)
    assert sizer.next_size() == int(BATCH_CPU_SECONDS / 0.1) == 10
    sizer.take(1000 - 8 - 30)  # 30 left: at most 30 / (2 x 2 workers) = 7 a batch
    assert sizer.next_size() == 7
    sizer.take(27)  # 3 left: single runs, so both workers finish together
    assert sizer.next_size() == 1
    short = BatchSizer(total=None, workers=2)
    short.observe(100, 100 * 0.001, 100 * 0.001)  # 1 ms runs: at most MAX_BATCH a batch
    assert short.next_size() == MAX_BATCH
    waiting = BatchSizer(total=None, workers=2)
    waiting.observe(10, 10 * 1.0, 10 * 0.001)  # runs that wait 1 s and compute little
    assert waiting.next_size() == int(BATCH_WALL_SECONDS / 1.0) == 5
    long = BatchSizer(total=None, workers=2)
    long.observe(4, 4 * 2.0, 4 * 2.0)  # 2 s runs: one a batch
    assert long.next_size() == 1


def test_without_dask_the_error_names_the_extra(tmp_path):
    code = (
        "import sys; sys.modules['distributed'] = None\n"
        "from hbvs_cli.cli.app import main\n"
        f"main(['sweep', {str(tmp_path / 'fit.mcap')!r}, '--vary', 'law=paper'])\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    assert result.stderr.strip() == "hbvs: error: hbvs sweep needs dask[distributed]: pip install 'hbvs[sweep]'"
