"""Batch evaluation: every (session, tracker, parameter) combination into one Parquet table (docs/batch.md).

    from phonepose.batch import run_batch
    r = run_batch(["a.mcap", "b.mcap"], "results.parquet", trackers="paper", params=["rate_hz=10,20"], workers=2)

Modules: ``plan`` (parameters, cross product, row keys, what to skip), ``run`` (one playback →
rows, in a worker), ``table`` (Parquet read / merge / atomic write), ``executor`` (local process
pool or Dask cluster, both a concurrent.futures.Executor), ``driver`` (run_batch, summary).
"""

from phonepose.batch.driver import BatchResult, run_batch, summarize
from phonepose.batch.plan import PARAMS
from phonepose.batch.table import RUNTIME_COLUMNS

__all__ = ["BatchResult", "PARAMS", "RUNTIME_COLUMNS", "run_batch", "summarize"]
