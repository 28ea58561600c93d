"""The results table: read an existing Parquet file, merge new rows, write it back atomically.

Rows are kept as dicts by key ``(session, params, tracker)``; a new row replaces the old one with
the same key. Every write sorts the rows (session, parameters in typed order, tracker in natural
order) and gives each column a fixed type, so the same batch gives the same table however many
workers ran it and in whichever order units finished. Writing goes to a temporary file next to
the target, then ``os.replace``: a reader (or a killed batch) only ever sees a complete table.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from phonepose.batch.plan import PARAMS, params_sort_key, row_key, tracker_sort_key
from phonepose.errors import OutputError
from phonepose.files import OutputFile

# column → arrow type, in table order; metric columns go between "error" and "n_ticks"
HEAD = {"session": pa.string(), "tracker": pa.string(), "params": pa.string()}
STATUS = {"status": pa.string(), "error": pa.string()}
TAIL = {"n_ticks": pa.int64(), "n_task_ticks": pa.int64(), "frames_decoded": pa.int64(),
        "session_bytes": pa.int64(), "session_mtime_ns": pa.int64(), "runtime_s": pa.float64(),
        "phonepose_version": pa.string()}
REQUIRED = ("session", "params", "tracker", "status")
RUNTIME_COLUMNS = ("runtime_s",)   # the only columns that differ between two runs of the same batch


def _infer(values: list) -> pa.DataType:
    """Type of a metric column from its values: int64, float64, bool or string (all-null: float64)."""
    present = [v for v in values if v is not None]
    if not present:
        return pa.float64()
    if all(isinstance(v, bool) for v in present):
        return pa.bool_()
    if all(isinstance(v, int) and not isinstance(v, bool) for v in present):
        return pa.int64()
    if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in present):
        return pa.float64()
    return pa.string()


def schema_for(rows: list[dict]) -> pa.Schema:
    names: set[str] = set()
    for r in rows:
        names.update(r)
    params = [f"param_{k}" for k in PARAMS] + sorted(n for n in names if n.startswith("param_")
                                                      and n[6:] not in PARAMS)
    fixed = set(HEAD) | set(STATUS) | set(TAIL) | set(params)
    metrics = sorted(n for n in names if n not in fixed)
    fields: list[pa.Field] = [pa.field(n, t) for n, t in HEAD.items()]
    for n in params:
        spec = PARAMS.get(n[6:])
        fields.append(pa.field(n, pa.float64() if spec is not None and spec.arrow_type == "float64" else
                               pa.string() if spec is not None else _infer([r.get(n) for r in rows])))
    fields += [pa.field(n, t) for n, t in STATUS.items()]
    fields += [pa.field(n, _infer([r.get(n) for r in rows])) for n in metrics]
    fields += [pa.field(n, t) for n, t in TAIL.items()]
    return pa.schema(fields)


def sort_key(row: dict) -> tuple:
    try:
        params = json.loads(row.get("params") or "{}")
    except ValueError:
        params = {}
    return (row.get("session") or "", params_sort_key(params), tracker_sort_key(row.get("tracker") or ""))


def _coerce(rows: list[dict], schema: pa.Schema) -> list[dict]:
    """Ints where the column is float (a metric that was 0 in one row and 0.5 in another)."""
    floats = [f.name for f in schema if pa.types.is_floating(f.type)]
    out = []
    for r in rows:
        r = dict(r)
        for n in floats:
            v = r.get(n)
            if isinstance(v, int) and not isinstance(v, bool):
                r[n] = float(v)
        out.append(r)
    return out


def to_arrow(rows: list[dict]) -> pa.Table:
    rows = sorted(rows, key=sort_key)
    schema = schema_for(rows)
    return pa.Table.from_pylist(_coerce(rows, schema), schema=schema)


def read_rows(path: Path) -> dict[tuple[str, str, str], dict]:
    """The rows of an existing table by key ({} if the file does not exist)."""
    if not path.exists():
        return {}
    try:
        table = pq.read_table(path)
    except (pa.ArrowException, OSError) as exc:
        raise OutputError(f"--out {path} exists but is not a readable Parquet table ({' '.join(str(exc).split())}); "
                          "move it away or choose another --out") from None
    missing = [c for c in REQUIRED if c not in table.column_names]
    if missing:
        raise OutputError(f"--out {path} is not a phonepose batch table (no column {', '.join(missing)}); "
                          "move it away or choose another --out")
    return {row_key(r["session"], r["params"], r["tracker"]): r for r in table.to_pylist()}


class ResultTable:
    """The rows of ``path`` plus the ones this batch adds, written back atomically."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)          # checked by phonepose.files before (batch.driver.prepare_batch)
        self.rows = read_rows(self.path)
        self.output: OutputFile | None = None   # where write() puts each version: set while the batch runs
        self.writes = 0
        self._last_write = 0.0
        self._last_cost = 0.0
        self._dirty = False

    def update(self, rows: list[dict]) -> None:
        for r in rows:
            self.rows[row_key(r["session"], r["params"], r["tracker"])] = r
        self._dirty = True

    def write(self, min_interval_s: float = 0.0) -> bool:
        """Rewrite the file if rows changed and at least ``min_interval_s`` passed since the last write
        (or, when that is > 0, ten times what the last rewrite took: large tables stay under 10 % of the time)."""
        interval = max(min_interval_s, 10 * self._last_cost) if min_interval_s > 0 else 0.0
        if not self._dirty or time.monotonic() - self._last_write < interval:
            return False
        t0 = time.monotonic()
        table = to_arrow(list(self.rows.values()))
        assert self.output is not None and self.output.tmp is not None, "write() runs inside the batch's OutputPlan"
        try:
            with open(self.output.tmp, "wb") as f:
                pq.write_table(table, f)
                f.flush()
                os.fsync(f.fileno())
        except OSError as exc:
            raise OutputError(f"cannot write {self.path}: {exc.strerror or exc}") from None
        self.output.checkpoint()   # renamed into place whole; the next version goes to a new temporary
        self._dirty = False
        self._last_write = time.monotonic()
        self._last_cost = self._last_write - t0
        self.writes += 1
        return True
