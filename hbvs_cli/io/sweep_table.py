"""The results table of a sweep, written as runs finish and valid after any interruption: ``sweep.json``
(spec and fit digest, which a resume must match), ``parts/part-NNNNNN.parquet`` (one per flush),
``runs.parquet`` and ``runs.csv`` (sorted at the end); one process writes it at a time."""

from __future__ import annotations

import io
import json
import math
import os
import time
from pathlib import Path
from typing import Any, Iterator, Mapping, Sequence

from ..errors import InputError, OutputError, UsageError
from ..io.output_target import FolderLock, partial_name_of, remove_stale_partials, replace_through_partial

SPEC_FILE = "sweep.json"
PARTS = "parts"
PARQUET = "runs.parquet"
CSV = "runs.csv"
LOCK = ".hbvs-sweep.lock"

#: Row column -> the dotted key of ``hbvs report --json`` it holds.
METRICS: dict[str, str] = {
    "converged": "verdict.converged",
    "final_position_m": "pose_error.position_m.final",
    "final_heading_deg": "pose_error.heading_deg.final",
    "settling_time_position_s": "pose_error.position_m.settling_time_s",
    "settling_time_heading_s": "pose_error.heading_deg.settling_time_s",
    "rmse_position_m": "pose_error.position_m.rmse",
    "rmse_heading_deg": "pose_error.heading_deg.rmse",
    "final_e1": "errors.e1.final",
    "final_e2": "errors.e2.final",
    "final_ebar2": "errors.ebar2.final",
    "final_e3_deg": "errors.e3.final",
    "v_ratio": "lyapunov.ratio",
    "v_increase_fraction": "lyapunov.increase_fraction",
    "dhat0_m": "depth.dhat0",
    "dhat_final_m": "depth.dhat_final",
    "d_true_m": "depth.d_true",
    "dhat_relative_error": "depth.relative_error",
    "lost_fraction": "target.lost_fraction",
    "saturated_fraction": "commands.saturated_fraction",
    "v_peak_mps": "commands.v_peak_mps",
    "w_peak_radps": "commands.w_peak_radps",
    "dv_dt_rms_mps2": "commands.dv_dt_rms_mps2",
    "dw_dt_rms_radps2": "commands.dw_dt_rms_radps2",
    "at_limit_fraction": "commands.at_limit_fraction",
    "dropped_fraction": "target.dropped_fraction",
    "duration_s": "run.duration_s",
    "steps": "run.steps",
    "truncated": "run.truncated",
}
#: Metric columns that are booleans or whole numbers (the rest are floats).
BOOLEAN_METRICS = ("converged", "truncated")
INTEGER_METRICS = ("steps",)

#: What became of a run: reported; stopped for a lost target; failed before a report existed.
STATUS_OK, STATUS_STOPPED, STATUS_FAILED = "ok", "stopped", "failed"


def row_schema(kinds: Mapping[str, str]) -> Any:
    """The Arrow schema of a row: indices, the parameters (``kinds``: each one's, in order), status, the report's metrics."""
    import pyarrow as pa

    arrow = {"float": pa.float64(), "int": pa.int64(), "choice": pa.string()}
    fields = [pa.field(n, pa.int64()) for n in ("index", "point", "repeat", "seed")]
    fields += [pa.field(name, arrow[kind]) for name, kind in kinds.items()]
    fields += [pa.field("status", pa.string()), pa.field("error", pa.string())]
    metric = dict.fromkeys(BOOLEAN_METRICS, pa.bool_()) | dict.fromkeys(INTEGER_METRICS, pa.int64())
    fields += [pa.field(column, metric.get(column, pa.float64())) for column in METRICS]
    fields += [pa.field("run_time_s", pa.float64()), pa.field("run_file", pa.string()), pa.field("command", pa.string())]
    return pa.schema(fields)


def read_description(folder: Path, need_spec: bool = True) -> dict[str, Any]:
    """``sweep.json`` of a results folder, checked (``need_spec``: with the spec's ``vary`` and ``fixed``)."""
    path = Path(folder) / SPEC_FILE
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"{folder}: not the results folder of hbvs sweep (no {SPEC_FILE})") from None
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: unreadable ({exc})") from None
    fingerprint = document.get("fingerprint") if isinstance(document, dict) else None
    spec = fingerprint.get("spec") if isinstance(fingerprint, dict) else None
    schema = document.get("schema") if isinstance(document, dict) else None
    spec_ok = isinstance(spec, dict) and isinstance(spec.get("vary"), dict) and isinstance(spec.get("fixed"), dict)
    if not (isinstance(document, dict) and (spec_ok or not need_spec) and "fingerprint" in document
            and isinstance(schema, dict) and all(isinstance(k, str) and isinstance(v, str) for k, v in schema.items())
            and isinstance(document.get("runs", 0), int)):
        raise InputError(f"{path}: not the description hbvs sweep writes (fingerprint, spec, schema)")
    return document


#: Run indices per window of the streamed merge: the rows in memory at once.
MERGE_WINDOW = 1024


def _result_files(folder: Path) -> list[Path]:
    return ([folder / PARQUET] if (folder / PARQUET).is_file() else []) + sorted((folder / PARTS).glob("part-*.parquet"))


def _read_table(path: Path, schema_only: bool = False, **options: Any) -> Any:
    """A results file's rows (or, with ``schema_only``, its schema); :class:`InputError` when unreadable."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        return pq.read_schema(path) if schema_only else pq.read_table(path, **options)
    except (OSError, pa.ArrowException) as exc:
        raise InputError(f"{path}: unreadable results ({exc})") from None


def _indices(path: Path) -> Any:
    """The run indices of a results file (only its index column is read)."""
    return _read_table(path, columns=["index"]).column("index").to_numpy()


def _sorted_unique(table: Any) -> Any:
    """``table`` sorted by run index, one row per index (a kill during the final merge repeats some)."""
    import numpy as np

    # The first row of each index, in the order of the indices.
    _, first = np.unique(table.column("index").to_numpy(), return_index=True)
    return table.take(first)


def merged_windows(folder: Path, schema: Any) -> Iterator[Any]:
    """The rows of ``runs.parquet`` and the parts, sorted by run index, in tables of at most
    :data:`MERGE_WINDOW` consecutive indices: one window's rows in memory at a time."""
    spans = [(path, int(index.min()), int(index.max())) for path in _result_files(folder) if (index := _indices(path)).size]
    if not spans:
        return
    low = min(span[1] for span in spans)
    high = max(span[2] for span in spans)
    for start in range(low, high + 1, MERGE_WINDOW):
        stop = start + MERGE_WINDOW
        pieces = [
            _cast(path, _read_table(path, filters=[("index", ">=", start), ("index", "<", stop)]), schema)
            for path, first, last in spans if first < stop and last >= start
        ]
        if pieces:
            import pyarrow as pa

            table = _sorted_unique(pa.concat_tables(pieces))
            if table.num_rows:
                yield table


def _cast(path: Path, table: Any, schema: Any) -> Any:
    """``table`` with the sweep's column types; :class:`InputError` for another sweep's rows."""
    import pyarrow as pa

    foreign = sorted(set(table.column_names) - set(schema.names))
    if foreign:
        raise InputError(f"{path}: holds the rows of another sweep (columns {', '.join(foreign)} are not this sweep's); "
                         "move it away or give another -o folder")
    try:
        return table.cast(schema)
    except (pa.ArrowException, ValueError) as exc:
        raise InputError(f"{path}: holds the rows of another sweep ({' '.join(str(exc).split())[:200]})") from None


def write_merged(folder: Path, schema: Any, parquet: Path | None, csv: Path) -> int:
    """Stream the merged rows into ``csv`` (and ``parquet`` when given); returns the row count."""
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    rows = 0
    parquet_writer = pq.ParquetWriter(str(parquet), schema) if parquet is not None else None
    try:
        with pacsv.CSVWriter(str(csv), schema) as csv_writer:
            for table in merged_windows(folder, schema):
                rows += table.num_rows
                if parquet_writer is not None:
                    parquet_writer.write_table(table, row_group_size=MERGE_WINDOW)
                csv_writer.write_table(table)
    finally:
        if parquet_writer is not None:
            parquet_writer.close()
    return rows


def read_rows(folder: Path, columns: Sequence[str] | None = None) -> Any:
    """Every row written so far, one per run index, sorted; :class:`InputError` if not a sweep's folder."""
    import pyarrow as pa

    folder = Path(folder)
    described = read_description(folder, need_spec=False)["schema"]
    try:
        schema = pa.schema([pa.field(n, pa.type_for_alias(t)) for n, t in described.items()])
    except (ValueError, pa.ArrowException) as exc:
        raise InputError(f"{folder / SPEC_FILE}: not the description hbvs sweep writes ({exc})") from None
    wanted = None if columns is None else [n for n in dict.fromkeys(["index", *columns]) if n in schema.names]
    target = schema if wanted is None else pa.schema([schema.field(n) for n in wanted])
    pieces = []
    for path in _result_files(folder):
        present = None if wanted is None else [n for n in wanted if n in _read_table(path, schema_only=True).names]
        pieces.append(_cast(path, _read_table(path, columns=present), target))
    return _sorted_unique(pa.concat_tables(pieces)) if pieces else target.empty_table()


class ResultsTable:
    """Appends rows as runs finish; a folder of another ``fingerprint`` is refused; a part is
    written with the first row, then when ``flush_rows`` wait or ``flush_seconds`` after the
    last one."""

    def __init__(self, folder: Path, schema: Any, fingerprint: Mapping[str, Any], description: Mapping[str, Any] | None = None,
                 flush_rows: int = 256, flush_seconds: float = 2.0) -> None:
        self.folder = Path(folder)
        self.schema = schema
        self.flush_rows = flush_rows
        self.flush_seconds = flush_seconds
        self._buffer: list[dict[str, Any]] = []
        # The first row is written at once: however fast the runs, a kill soon after the
        # start keeps it, and a user sees the sweep's first result on disk.
        self._last_flush = -math.inf
        self._lock: FolderLock | None = None
        try:
            self._open(dict(fingerprint), dict(description or {}))
        except BaseException:
            self.release()
            raise
        numbers = (p.stem.removeprefix("part-") for p in (self.folder / PARTS).glob("part-*.parquet"))
        self._part = 1 + max((int(number) for number in numbers if number.isdecimal()), default=0)

    def _open(self, fingerprint: dict[str, Any], description: dict[str, Any]) -> None:
        # An output that cannot be made is exit 6, as for every -o.
        if self.folder.is_symlink() and not self.folder.exists():
            raise OutputError(f"{self.folder}: a symbolic link to {os.readlink(self.folder)}, which does not exist; give a folder")
        if self.folder.exists() and not self.folder.is_dir():
            raise UsageError(f"{self.folder}: exists and is not a folder")
        if not self.folder.parent.is_dir():
            raise OutputError(f"{self.folder}: the folder {self.folder.parent} does not exist")
        spec_path = self.folder / SPEC_FILE
        if not spec_path.is_file() and self.folder.exists() and any(p.name != LOCK for p in self.folder.iterdir()):
            raise UsageError(f"{self.folder}: exists, is not empty and holds no sweep; give a new or empty folder")
        try:
            self.folder.mkdir(exist_ok=True)
        except OSError as exc:
            raise OutputError(f"{self.folder}: cannot create the results folder ({exc.strerror})") from None
        # Checked again under the lock: another sweep may have started it meanwhile.
        self._lock = FolderLock(self.folder / LOCK, f"{self.folder}/ (a sweep's results)")
        if spec_path.is_file():
            if read_description(self.folder, need_spec=False).get("fingerprint") != fingerprint:
                raise UsageError(
                    f"{self.folder} holds the results of another sweep (different spec, seed or fit); "
                    "give another -o folder, or the same command to resume that one"
                )
        elif any(p.name not in (LOCK, PARTS) for p in self.folder.iterdir()):
            raise UsageError(f"{self.folder}: exists, is not empty and holds no sweep; give a new or empty folder")
        (self.folder / PARTS).mkdir(exist_ok=True)
        if not spec_path.is_file():
            document = {"fingerprint": fingerprint, **description, "schema": {f.name: str(f.type) for f in self.schema}}
            replace_through_partial(spec_path, lambda p: p.write_text(json.dumps(document, indent=2) + "\n"))
        # Partial files of a sweep that was killed (its process is gone); nobody else's.
        remove_stale_partials(self.folder.rglob("*.partial"))
        # Rewrite the CSV from the Parquet rows: drops a line torn by a kill.
        replace_through_partial(self.folder / CSV, lambda p: write_merged(self.folder, self.schema, None, p))
        #: Run indices with a row when the table was opened.
        self.done: set[int] = {int(i) for path in _result_files(self.folder) for i in _indices(path)}

    def release(self) -> None:
        """Let another process write the folder (also done when this one ends)."""
        if self._lock is not None:
            self._lock.close()
            self._lock = None

    def append(self, row: Mapping[str, Any]) -> None:
        self._buffer.append(dict(row))
        if len(self._buffer) >= self.flush_rows or time.monotonic() - self._last_flush >= self.flush_seconds:
            self.flush()

    def flush(self) -> None:
        """Write the waiting rows: a new Parquet part, and the same lines onto the CSV."""
        import pyarrow as pa
        import pyarrow.csv as pacsv
        import pyarrow.parquet as pq

        self._last_flush = time.monotonic()
        if not self._buffer:
            return
        # Taken out first: a stop signal here must not make a second flush write them again.
        rows, self._buffer = self._buffer, []
        table = pa.Table.from_pylist(rows, schema=self.schema)
        partial = partial_name_of(self.folder / PARTS / "part.parquet")
        try:
            pq.write_table(table, partial)
            # Linked, not renamed, into place: a link never replaces a part that is there.
            while True:
                path = self.folder / PARTS / f"part-{self._part:06d}.parquet"
                self._part += 1
                try:
                    os.link(partial, path)
                    break
                except FileExistsError:
                    continue
        finally:
            partial.unlink(missing_ok=True)
        lines = io.BytesIO()  # written in one call: a kill tears at most the last line
        pacsv.write_csv(table, lines, write_options=pacsv.WriteOptions(include_header=False))
        with open(self.folder / CSV, "ab") as handle:
            handle.write(lines.getvalue())
            handle.flush()
            os.fsync(handle.fileno())

    def close(self) -> None:
        """After an interruption: write the waiting rows; the CSV rewritten from the Parquet rows."""
        self.flush()
        replace_through_partial(self.folder / CSV, lambda p: write_merged(self.folder, self.schema, None, p))

    def finish(self) -> int:
        """Merge everything into ``runs.parquet`` and ``runs.csv``; returns the number of rows."""
        self.flush()
        merged = partial_name_of(self.folder / PARQUET)
        csv_partial = partial_name_of(self.folder / CSV)
        try:
            rows = write_merged(self.folder, self.schema, merged, csv_partial)
            # The merged file replaces runs.parquet only now: until here the rows were read from it.
            os.replace(merged, self.folder / PARQUET)
            os.replace(csv_partial, self.folder / CSV)
        finally:
            merged.unlink(missing_ok=True)
            csv_partial.unlink(missing_ok=True)
        for part in (self.folder / PARTS).glob("part-*.parquet"):
            part.unlink()
        return rows


def failed_row(task: Any, error: str) -> dict[str, Any]:
    """The row of a run whose worker could not give one (it died too often); a run that ends
    gives this row with its status, metrics, run time and kept file over it."""
    return {
        "index": task.index, "point": task.point, "repeat": task.repeat, "seed": task.seed, **task.values,
        "status": STATUS_FAILED, "error": error, **dict.fromkeys(METRICS), "run_time_s": None, "run_file": None,
        "command": task.command,
    }
