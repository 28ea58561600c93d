"""The results table: read an existing Parquet file, merge new rows, write it back atomically.

Rows are kept as dicts by key ``(session, params, tracker)``; a new row replaces the old one with
the same key. Every write sorts the rows (session, parameters in typed order, tracker in natural
order) and gives each column a fixed type, so the same batch gives the same table however many
workers ran it and in whichever order units finished. Writing goes to a temporary file next to
the target, then ``os.replace``: a reader (or a killed batch) only ever sees a complete table.

A table carries two checksums, so a bit flipped on the disk is found when a batch resumes it instead
of becoming rows: Parquet's own page CRCs (checked by pyarrow on reading), and a SHA-256 of the
columns in the file's metadata (``phonepose.columns_sha256``; it also covers what a page CRC does not,
such as the footer's statistics and a flip that still decodes). Tables written before it carry a
SHA-256 of their rows as JSON (``phonepose.content_sha256``), which is still checked; older ones have
no hash and are read as they are.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from phonepose.batch.plan import MAX_UNITS, PARAMS, params_sort_key, row_key, tracker_sort_key
from phonepose.errors import OutputError
from phonepose.evaluation.metrics import flat_columns
from phonepose.files import OutputFile

# column → arrow type, in table order; metric columns go between "error" and "n_ticks"
HEAD = {"session": pa.string(), "tracker": pa.string(), "params": pa.string()}
STATUS = {"status": pa.string(), "error": pa.string()}
TAIL = {"n_ticks": pa.int64(), "n_task_ticks": pa.int64(), "frames_decoded": pa.int64(),
        "session_bytes": pa.int64(), "session_mtime_ns": pa.int64(), "runtime_s": pa.float64(),
        "phonepose_version": pa.string()}
REQUIRED = ("session", "params", "tracker", "status")
RUNTIME_COLUMNS = ("runtime_s",)
CHECKSUM_KEY = b"phonepose.columns_sha256"
ROWS_CHECKSUM_KEY = b"phonepose.content_sha256"     # what tables written before 2026-12-05 carry


def columns_hash(table: pa.Table) -> str:
    """SHA-256 of the table as Arrow holds it: each column's name, type, nulls and values, in order.

    Numbers are hashed as their bytes and strings as their lengths and UTF-8, the same before writing
    and after reading back. Hashing every row as JSON (``rows_hash``) would be most of a rewrite, and a
    stopped batch waits for its last rewrite."""
    digest = hashlib.sha256()
    for name, column in zip(table.column_names, table.columns, strict=True):
        values = column.combine_chunks()
        digest.update(f"{name}\0{values.type}\0{len(values)}\0".encode())
        digest.update(np.packbits(values.is_null().to_numpy(zero_copy_only=False)).tobytes())
        if pa.types.is_string(values.type) or pa.types.is_large_string(values.type):
            encoded = [str(v).encode() for v in values.fill_null("").to_pylist()]
            digest.update(np.fromiter(map(len, encoded), "<i8", len(encoded)).tobytes())
            digest.update(b"".join(encoded))
        elif pa.types.is_boolean(values.type) or pa.types.is_integer(values.type) or pa.types.is_floating(values.type):
            zero = False if pa.types.is_boolean(values.type) else 0
            digest.update(np.ascontiguousarray(values.fill_null(zero).to_numpy(zero_copy_only=False)).tobytes())
        elif not pa.types.is_null(values.type):     # no such column is written; hashed, not skipped
            digest.update(repr(values.to_pylist()).encode())
    return digest.hexdigest()


def rows_hash(rows: list[dict]) -> str:
    """SHA-256 of the rows as JSON (keys sorted; NaN spelled NaN): the checksum of older tables."""
    return hashlib.sha256(json.dumps(rows, sort_keys=True, allow_nan=True, default=str).encode()).hexdigest()


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


def _metric_type(name: str, rows: list[dict]) -> pa.DataType:
    """A metric's declared type (phonepose.evaluation.metrics); other columns' from their values."""
    kind = flat_columns().get(name)
    if kind is not None:
        return pa.int64() if kind is int else pa.float64()
    return _infer([r.get(name) for r in rows])


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
    fields += [pa.field(n, _metric_type(n, rows)) for n in metrics]
    fields += [pa.field(n, t) for n, t in TAIL.items()]
    return pa.schema(fields)


@functools.lru_cache(maxsize=2 * MAX_UNITS)
def _params_order(params_text: str) -> tuple:
    """The typed order of a ``params`` text. Cached: the table is sorted on every rewrite, and parsing
    each row's JSON again would be most of a rewrite's time."""
    try:
        params = json.loads(params_text)
    except ValueError:
        params = {}
    return params_sort_key(params if isinstance(params, dict) else {})


@functools.lru_cache(maxsize=4096)
def _tracker_order(name: str) -> tuple:
    return tracker_sort_key(name)


def sort_key(row: dict) -> tuple:
    return (row.get("session") or "", _params_order(row.get("params") or "{}"), _tracker_order(row.get("tracker") or ""))


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


def _refuse(path: Path, why: str) -> OutputError:
    return OutputError(f"{{out}} {path} {why}; move it away or choose another {{out}}", parameter="out", value=path)


def read_rows(path: Path) -> dict[tuple[str, str, str], dict]:
    """The rows of an existing table by key ({} if the file does not exist): checked against its
    checksums and column types, so a damaged or foreign table is one line, never rows."""
    if not path.exists():
        return {}
    try:
        table = pq.read_table(path, page_checksum_verification=True)
        names = table.column_names
        rows = table.to_pylist()
    except (pa.ArrowException, OSError) as exc:
        raise _refuse(path, f"exists but is not a readable Parquet table ({' '.join(str(exc).split())})") from None
    except (UnicodeDecodeError, ValueError, TypeError):      # a flipped bit in a column name or a string value
        raise _refuse(path, "exists but is not a readable Parquet table (text that is not UTF-8)") from None
    missing = [c for c in REQUIRED if c not in names]
    if missing:
        raise _refuse(path, f"is not a phonepose batch table (no column {', '.join(missing)})")
    for name, want in {**HEAD, **STATUS, **TAIL}.items():
        if name in names:
            got = table.schema.field(name).type
            if got != want and not pa.types.is_null(got):
                raise _refuse(path, f"is not a phonepose batch table (column {name} is {got}, not {want})")
    metadata = table.schema.metadata or {}
    if CHECKSUM_KEY in metadata:
        matches = metadata[CHECKSUM_KEY].decode(errors="replace") == columns_hash(table)
    else:
        matches = ROWS_CHECKSUM_KEY not in metadata or metadata[ROWS_CHECKSUM_KEY].decode(errors="replace") == rows_hash(rows)
    if not matches:
        raise _refuse(path, "does not match its checksum: it changed on the disk after phonepose wrote it")
    return {row_key(r["session"], r["params"], r["tracker"]): r for r in rows}


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
        table = table.replace_schema_metadata({CHECKSUM_KEY: columns_hash(table).encode()})
        assert self.output is not None and self.output.tmp is not None, "write() runs inside the batch's OutputPlan"
        try:
            with open(self.output.tmp, "wb") as f:
                pq.write_table(table, f, write_page_checksum=True)
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
