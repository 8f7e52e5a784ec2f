"""The results table of a sweep: written as runs finish, valid after any interruption.

Layout of the results folder::

    sweep.json        the spec, the fit and its SHA-256 (a resume must match it)
    parts/            part-NNNNNN.parquet, one per flush while the sweep runs
    runs.parquet      the whole table, sorted by run index (written when the sweep ends)
    runs.csv          the same rows as CSV: appended at every flush, rewritten sorted at the end
    runs/             run files kept by --keep-runs

Every Parquet file is written as ``NAME.partial`` and renamed when complete, so a part is
either whole or absent. The CSV gets whole lines appended; a line torn by a kill is
dropped when the sweep resumes, which rewrites the CSV from the Parquet rows. A resume
skips every run index already in ``runs.parquet`` or a part.
"""

from __future__ import annotations

import io
import json
import os
import time
from pathlib import Path
from typing import Any, Iterator, Mapping, Sequence

from ..errors import InputError, UsageError

SPEC_FILE = "sweep.json"
PARTS = "parts"
PARQUET = "runs.parquet"
CSV = "runs.csv"
RUNS = "runs"

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

#: What became of a run: reported; reported after ``repeat`` stopped it for a lost
#: target (it did not converge); or failed before a report existed (``error`` says why).
STATUS_OK, STATUS_STOPPED, STATUS_FAILED = "ok", "stopped", "failed"


def empty_metrics() -> dict[str, Any]:
    return {column: None for column in METRICS}


def row_schema(parameters: Sequence[str], kinds: Mapping[str, str]) -> Any:
    """The Arrow schema of a row: indices, the parameters, status, the report's metrics."""
    import pyarrow as pa

    arrow = {"float": pa.float64(), "int": pa.int64(), "choice": pa.string()}
    fields = [pa.field(n, pa.int64()) for n in ("index", "point", "repeat", "seed")]
    fields += [pa.field(name, arrow[kinds[name]]) for name in parameters]
    fields += [pa.field("status", pa.string()), pa.field("error", pa.string())]
    for column in METRICS:
        kind = pa.bool_() if column in BOOLEAN_METRICS else pa.int64() if column in INTEGER_METRICS else pa.float64()
        fields.append(pa.field(column, kind))
    fields += [pa.field("run_time_s", pa.float64()), pa.field("run_file", pa.string()), pa.field("command", pa.string())]
    return pa.schema(fields)


def _replace(path: Path, write: Any) -> None:
    """Write ``path`` through ``path.partial`` and a rename."""
    partial = path.with_name(path.name + ".partial")
    write(partial)
    os.replace(partial, path)


def _csv_bytes(table: Any, header: bool) -> bytes:
    import pyarrow.csv as pacsv

    buffer = io.BytesIO()
    pacsv.write_csv(table, buffer, write_options=pacsv.WriteOptions(include_header=header))
    return buffer.getvalue()


#: Run indices per window of the streamed merge: the rows in memory at once.
MERGE_WINDOW = 1024


def _result_files(folder: Path) -> list[Path]:
    return ([folder / PARQUET] if (folder / PARQUET).is_file() else []) + sorted((folder / PARTS).glob("part-*.parquet"))


def _read_table(path: Path, **options: Any) -> Any:
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        return pq.read_table(path, **options)
    except (OSError, pa.ArrowException) as exc:
        raise InputError(f"{path}: unreadable results ({exc})") from None


def _sorted_unique(table: Any) -> Any:
    """``table`` sorted by run index, one row per index (a part written again after a kill
    during the final merge repeats some)."""
    import numpy as np
    import pyarrow as pa
    import pyarrow.compute as pc

    table = table.take(pc.sort_indices(table, [("index", "ascending")]))
    index = table.column("index").to_numpy()
    if index.size > 1:
        keep = np.concatenate([[True], index[1:] != index[:-1]])
        if not keep.all():
            table = table.filter(pa.array(keep))
    return table


def merged_windows(folder: Path, schema: Any, window: int | None = None) -> Iterator[Any]:
    """The rows of ``runs.parquet`` and the parts, sorted by run index, in tables of at most
    ``window`` consecutive indices.

    Only one window's rows are in memory at a time (plus every file's index column), so
    the merge of a 100 000-run sweep takes the memory of a few thousand rows. A part holds
    the runs that finished together, so its indices are close and it is read for one or two
    windows; ``runs.parquet`` is sorted and written in row groups of one window, which the
    reader's statistics skip.
    """
    window = window or MERGE_WINDOW
    spans = []
    for path in _result_files(folder):
        index = _read_table(path, columns=["index"]).column("index").to_numpy()
        if index.size:
            spans.append((path, int(index.min()), int(index.max())))
    if not spans:
        return
    low = min(span[1] for span in spans)
    high = max(span[2] for span in spans)
    for start in range(low, high + 1, window):
        stop = start + window
        pieces = [
            _read_table(path, filters=[("index", ">=", start), ("index", "<", stop)]).cast(schema)
            for path, first, last in spans if first < stop and last >= start
        ]
        if pieces:
            import pyarrow as pa

            table = _sorted_unique(pa.concat_tables(pieces))
            if table.num_rows:
                yield table


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
                for batch in table.to_batches(max_chunksize=MERGE_WINDOW):
                    csv_writer.write_batch(batch)
    finally:
        if parquet_writer is not None:
            parquet_writer.close()
    return rows


def done_indices(folder: Path) -> set[int]:
    """Run indices with a row in ``runs.parquet`` or a part (only the index column is read)."""
    done: set[int] = set()
    for path in _result_files(folder):
        done.update(_read_table(path, columns=["index"]).column("index").to_pylist())
    return done


def read_rows(folder: Path, columns: Sequence[str] | None = None) -> Any:
    """Every row written so far (``runs.parquet`` and the parts), one per run index, sorted.

    Raises
    ------
    InputError
        Not a sweep's results folder.
    """
    import pyarrow as pa

    folder = Path(folder)
    if not (folder / SPEC_FILE).is_file():
        raise InputError(f"{folder}: not the results folder of hbvs sweep (no {SPEC_FILE})")
    wanted = None if columns is None else list(dict.fromkeys(["index", *columns]))
    pieces = [_read_table(path, columns=wanted) for path in _result_files(folder)]
    if not pieces:
        schema = json.loads((folder / SPEC_FILE).read_text())["schema"]
        return pa.schema([pa.field(n, pa.type_for_alias(t)) for n, t in schema.items()]).empty_table() if wanted is None else \
            pa.table({n: pa.array([], pa.type_for_alias(schema[n])) for n in wanted})
    return _sorted_unique(pa.concat_tables(pieces, promote_options="default"))


class ResultsTable:
    """Appends rows as runs finish; see the module docstring for the files.

    Parameters
    ----------
    folder : Path
    schema : pyarrow.Schema
    fingerprint : dict
        What decides the runs (spec, fit, digest); a folder with another one is refused.
    flush_rows, flush_seconds :
        Write a part when this many rows wait, or this long after the last part.
    """

    def __init__(self, folder: Path, schema: Any, fingerprint: Mapping[str, Any], description: Mapping[str, Any] | None = None,
                 flush_rows: int = 256, flush_seconds: float = 2.0) -> None:
        self.folder = Path(folder)
        self.schema = schema
        self.flush_rows = flush_rows
        self.flush_seconds = flush_seconds
        self._buffer: list[dict[str, Any]] = []
        self._last_flush = time.monotonic()
        self._open(dict(fingerprint), dict(description or {}))
        self._part = 1 + max((int(p.stem.split("-")[1]) for p in (self.folder / PARTS).glob("part-*.parquet")), default=0)

    def _open(self, fingerprint: dict[str, Any], description: dict[str, Any]) -> None:
        if self.folder.exists() and not self.folder.is_dir():
            raise UsageError(f"{self.folder}: exists and is not a folder")
        spec_path = self.folder / SPEC_FILE
        if spec_path.is_file():
            try:
                recorded = json.loads(spec_path.read_text())
            except (OSError, ValueError) as exc:
                raise InputError(f"{spec_path}: unreadable ({exc})") from None
            if recorded.get("fingerprint") != fingerprint:
                raise UsageError(
                    f"{self.folder} holds the results of another sweep (different spec, seed or fit); "
                    "give another -o folder, or the same command to resume that one"
                )
        elif self.folder.exists() and any(self.folder.iterdir()):
            raise UsageError(f"{self.folder}: exists, is not empty and holds no sweep; give a new or empty folder")
        (self.folder / PARTS).mkdir(parents=True, exist_ok=True)
        if not spec_path.is_file():
            document = {"fingerprint": fingerprint, **description, "schema": {f.name: str(f.type) for f in self.schema}}
            _replace(spec_path, lambda p: p.write_text(json.dumps(document, indent=2) + "\n"))
        for stray in self.folder.rglob("*.partial"):
            stray.unlink()
        # Rewrite the CSV from the Parquet rows: drops a line torn by a kill.
        _replace(self.folder / CSV, lambda p: write_merged(self.folder, self.schema, None, p))
        self._done = done_indices(self.folder)

    @property
    def done(self) -> set[int]:
        """Run indices with a row (read when the table was opened)."""
        return self._done

    def append(self, row: Mapping[str, Any]) -> None:
        self._buffer.append(dict(row))
        if len(self._buffer) >= self.flush_rows or time.monotonic() - self._last_flush >= self.flush_seconds:
            self.flush()

    def flush(self) -> None:
        """Write the waiting rows: a new Parquet part, and the same lines onto the CSV."""
        import pyarrow as pa
        import pyarrow.parquet as pq

        self._last_flush = time.monotonic()
        if not self._buffer:
            return
        # Taken out first: a stop signal landing in here must not make a second flush
        # write these rows again (a lost row is only re-run on resume).
        rows, self._buffer = self._buffer, []
        table = pa.Table.from_pylist(rows, schema=self.schema)
        path = self.folder / PARTS / f"part-{self._part:06d}.parquet"
        self._part += 1
        _replace(path, lambda p: pq.write_table(table, p))
        with open(self.folder / CSV, "ab") as handle:
            handle.write(_csv_bytes(table, False))
            handle.flush()
            os.fsync(handle.fileno())

    def close(self) -> None:
        """After an interruption: write the waiting rows, and make the CSV hold exactly the
        Parquet rows (the signal may have cut a flush between the two)."""
        self.flush()
        _replace(self.folder / CSV, lambda p: write_merged(self.folder, self.schema, None, p))

    def finish(self) -> int:
        """Merge everything into ``runs.parquet`` and ``runs.csv``, sorted by run index, in a
        streamed merge (:func:`merged_windows`); returns the number of rows."""
        self.flush()
        merged = self.folder / (PARQUET + ".merged.partial")
        csv_partial = self.folder / (CSV + ".partial")
        rows = write_merged(self.folder, self.schema, merged, csv_partial)
        # The merged file replaces runs.parquet only now: until here the rows were read from it.
        os.replace(merged, self.folder / PARQUET)
        os.replace(csv_partial, self.folder / CSV)
        for part in (self.folder / PARTS).glob("part-*.parquet"):
            part.unlink()
        return rows


def failed_row(task: Any, error: str) -> dict[str, Any]:
    """The row of a run whose worker could not give one (it died too often)."""
    return {
        "index": task.index, "point": task.point, "repeat": task.repeat, "seed": task.seed, **task.values,
        "status": STATUS_FAILED, "error": error, **empty_metrics(), "run_time_s": None, "run_file": None,
        "command": task.command,
    }
