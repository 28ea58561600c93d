"""``run_batch``: plan, skip what the table has, run the rest on an executor, write after each unit."""

from __future__ import annotations

import json
import math
import os
import statistics
import time
from collections.abc import Callable, Sequence
from concurrent.futures import TimeoutError as FuturesTimeout
from concurrent.futures import as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from phonepose.batch.executor import NO_WORKER_TIMEOUT_S, WATCH_INTERVAL_S, NoWorkers, open_executor
from phonepose.batch.plan import (
    PARAMS,
    Plan,
    Unit,
    check_unit_count,
    make_plan,
    param_combinations,
    params_label,
    parse_param_options,
    session_key,
)
from phonepose.batch.run import error_rows, one_line, run_unit
from phonepose.batch.table import ResultTable, sort_key
from phonepose.errors import ConfigError, PhoneposeError
from phonepose.files import OutputFile, OutputPlan, check_input
from phonepose.numbers import SECONDS_MAX, UNIT_TIMEOUT_S, WORKERS_MAX, check_number

WRITE_INTERVAL_S = 1.0   # at most one rewrite of the table per second while units finish (and always at the end)
SUMMARY_METRICS = (("p_ate_m_total", "p_ATE cm", 100.0), ("r_ate_deg_total", "r_ATE deg", 1.0),
                   ("p_re_m_total", "p_RE cm", 100.0))


@dataclass
class BatchResult:
    out: Path
    plan: Plan
    rows: list[dict]               # this batch's rows (run now or already in the table), sorted
    units_run: int                 # playbacks run now
    rows_run: int                  # rows they produced
    errors: int                    # rows of this batch with status error
    wall_s: float
    executor: str
    failures: list[tuple[str, str]] = field(default_factory=list)   # (session, error) per failed unit

    @property
    def skipped(self) -> int:
        return self.plan.skipped


def resolve_trackers(trackers: Sequence[str] | str) -> tuple[list[str], dict[str, str]]:
    """Names as make_trackers resolves them (``all``, ``paper``, ``T1,T7``, ``pkg.mod:Class``), and for a
    user's tracker the reference a worker builds it from (name -> reference); unknown names: ConfigError."""
    from phonepose.pipeline.trackers import check_unique_names, expand_names, is_user_tracker, make_tracker

    names, refs = [], {}
    given = expand_names(trackers)
    for ref in given:
        name = make_tracker(ref).name   # a user's: its name checked (docs/writing-a-tracker.md), a column's value
        names.append(name)
        if is_user_tracker(ref):
            refs[name] = ref
    check_unique_names(names, given)
    return names, refs


@dataclass
class PreparedBatch:
    """A checked batch: its plan, the table it resumes, and where it will run (nothing has run yet)."""

    out: Path
    plan: Plan
    table: ResultTable
    workers: int | None
    scheduler: str | None
    t0: float
    outputs: OutputPlan                 # the table as phonepose.files checked it
    table_output: OutputFile
    unit_timeout_s: float | None = UNIT_TIMEOUT_S


def prepare_batch(sessions: Sequence[str | os.PathLike], out: str | os.PathLike,
                  trackers: Sequence[str] | str = ("all",), params: Sequence[str] | dict[str, list] = (),
                  workers: int | None = None, scheduler: str | None = None,
                  unit_timeout_s: float | None = UNIT_TIMEOUT_S, calibrate_gt: bool = False) -> PreparedBatch:
    """Check every argument and make the plan against what ``out`` holds already; raises ConfigError /
    OutputError (one line) before any playback. ``out`` follows phonepose.files (a .parquet file, never
    a session, in a folder that exists); each version of it is renamed into place whole."""
    t0 = time.perf_counter()
    if scheduler is not None and workers is not None:
        raise ConfigError("{workers} and {scheduler} are exclusive: the cluster's workers are set by `dask worker`",
                          parameter="workers", value=workers, also=["scheduler"])
    if workers is not None:
        check_number("workers", workers, 1, WORKERS_MAX, integer=True)
    if unit_timeout_s is not None:
        check_number("unit_timeout_s", unit_timeout_s, 0, SECONDS_MAX, lo_open=True, unit="s")
    if not sessions:
        raise ConfigError("no session given")
    names, refs = resolve_trackers(trackers)
    sweep = parse_param_options(params) if not isinstance(params, dict) else \
        parse_param_options(f"{k}={','.join('none' if v is None else str(v) for v in vs)}" for k, vs in params.items())
    check_unit_count(len({session_key(s) for s in sessions}), sweep)   # before the product is built
    combos = param_combinations(sweep)
    if calibrate_gt:   # each session's ground truth calibrated from itself: its own rows (param_gt_calibration)
        combos = [{**c, "gt_calibration": "calibrate-gt"} for c in combos]
    for s in sessions:     # a missing one may exist on the cluster's workers: its rows will say; a FIFO never
        if os.path.lexists(s):
            check_input(s, "session")
    outputs = OutputPlan(inputs=sessions)
    table_output = outputs.file(out, "out", suffixes=(".parquet",), what="a Parquet table", rewritten=True)
    outputs.check()
    table = ResultTable(out)
    plan = make_plan(sessions, names, combos, table.rows, refs)
    return PreparedBatch(Path(out), plan, table, workers, scheduler, t0, outputs, table_output, unit_timeout_s)


def execute_batch(batch: PreparedBatch, progress: Callable[[int, int, list[dict]], None] | None = None,
                  on_start: Callable[[Plan, str], None] | None = None,
                  on_workers: Callable[[int], None] | None = None,
                  no_worker_timeout_s: float | None = NO_WORKER_TIMEOUT_S) -> BatchResult:
    """Run the plan's units on the executor; merge and write the table as they finish (at most once per
    ``WRITE_INTERVAL_S``, and at the end, also when interrupted: Ctrl-C, SIGTERM). A unit running longer
    than ``unit_timeout_s`` becomes error rows. On a Dask cluster, ``on_workers(n)`` hears each change of its
    worker count; one left without a worker for ``no_worker_timeout_s`` stops the batch with one line
    (PhoneposeError, its finished rows written); None: it waits for one for ever (``--keep-waiting``)."""
    plan, table = batch.plan, batch.table
    units_run = rows_run = 0
    failures: list[tuple[str, str]] = []
    description = "nothing to run"
    with batch.outputs:   # locked while the batch runs: a second batch on the same --out stops with one line
        table.output = batch.table_output
        if plan.units:
            with open_executor(batch.workers, batch.scheduler) as (executor, description):
                if on_start is not None:
                    on_start(plan, description)
                futures = {executor.submit(run_unit, unit, batch.unit_timeout_s): unit for unit in plan.units}
                # a Dask cluster's workers are not the batch's: one left without any is said, and waited for a bound
                watch = NoWorkers(executor, on_workers, no_worker_timeout_s) if batch.scheduler is not None else None
                remaining = set(futures)
                try:
                    while remaining:
                        try:
                            for fut in as_completed(remaining, timeout=WATCH_INTERVAL_S if watch else None):
                                remaining.discard(fut)
                                unit: Unit = futures[fut]
                                try:
                                    rows = fut.result()
                                except (Exception, SystemExit, GeneratorExit) as exc:   # noqa: BLE001 - the worker
                                    # died (crash, lost Dask worker), or its task ended with what run_unit does not catch
                                    rows = error_rows(unit, f"worker failed: {one_line(exc)}")
                                table.update(rows)
                                table.write(WRITE_INTERVAL_S)
                                units_run += 1
                                rows_run += len(rows)
                                if rows and rows[0]["status"] != "ok":
                                    failures.append((unit.session, rows[0]["error"]))
                                if progress is not None:
                                    progress(units_run, len(plan.units), rows)
                        except FuturesTimeout:
                            pass
                        if watch is not None and remaining and watch.check():
                            n = len(table.rows)
                            raise PhoneposeError(
                                f"{{scheduler}} {batch.scheduler}: the cluster has had no worker for "
                                f"{no_worker_timeout_s:g} s, so {len(remaining)} playbacks cannot run; {n} finished "
                                f"row{'s are' if n != 1 else ' is'} in {batch.out} (start a `dask worker "
                                f"{batch.scheduler}` and run the same command again, or add "
                                "{no_worker_timeout_s=None})", parameter="scheduler", value=batch.scheduler,
                                also=["no_worker_timeout_s"])
                finally:
                    for fut in futures:
                        fut.cancel()
                    table.write()   # what finished is kept, even when interrupted
        elif on_start is not None:
            on_start(plan, description)
        table.write()
    rows = sorted((table.rows[k] for k in plan.keys), key=sort_key)
    errors = sum(1 for r in rows if r.get("status") != "ok")
    return BatchResult(batch.out, plan, rows, units_run, rows_run, errors, time.perf_counter() - batch.t0,
                       description, failures)


def run_batch(sessions: Sequence[str | os.PathLike], out: str | os.PathLike, trackers: Sequence[str] | str = ("all",),
              params: Sequence[str] | dict[str, list] = (), workers: int | None = None, scheduler: str | None = None,
              progress: Callable[[int, int, list[dict]], None] | None = None,
              on_start: Callable[[Plan, str], None] | None = None,
              unit_timeout_s: float | None = UNIT_TIMEOUT_S) -> BatchResult:
    """Play every (session, parameter combination) back with every tracker; one row per tracker in ``out``.

    ``params``: ``["rate_hz=10,20", ...]`` (the CLI's --param) or ``{"rate_hz": [10.0, 20.0]}``.
    ``workers``: local processes (default one per core); ``scheduler``: a Dask scheduler address instead.
    ``progress(done_units, total_units, rows_of_the_unit)`` after each finished unit;
    ``on_start(plan, executor_description)`` once the executor is up.
    ``unit_timeout_s``: a playback running longer becomes error rows (None: no limit).
    Errors in the arguments raise before any playback (ConfigError, OutputError).
    """
    return execute_batch(prepare_batch(sessions, out, trackers, params, workers, scheduler, unit_timeout_s),
                         progress, on_start)


def _spread(values: list[float | None]) -> tuple[float | None, float | None]:
    vals = [v for v in values if v is not None and not (isinstance(v, float) and math.isnan(v))]
    if not vals:
        return None, None
    return statistics.fmean(vals), (statistics.stdev(vals) if len(vals) > 1 else 0.0)


def summarize(rows: list[dict]) -> list[dict]:
    """Per tracker (and parameter combination, when the batch has several): runs ok / failed, and
    mean and sample standard deviation over the sessions of each total metric (SUMMARY_METRICS)."""
    groups: dict[tuple[str, str], list[dict]] = {}
    for r in rows:
        groups.setdefault((r["params"], r["tracker"]), []).append(r)
    combos = [json.loads(p) for p in {p for p, _ in groups}]
    varying = [k for k in PARAMS if len({json.dumps(c.get(k)) for c in combos}) > 1]
    several = len(combos) > 1
    out = []
    for (params, tracker), rs in sorted(groups.items(), key=lambda kv: sort_key(kv[1][0])[1:]):
        ok = [r for r in rs if r.get("status") == "ok"]
        entry: dict[str, Any] = {"tracker": tracker, "params": params_label(json.loads(params), varying) if several else None,
                                 "ok": len(ok), "errors": len(rs) - len(ok)}
        for col, _, _ in SUMMARY_METRICS:
            entry[col] = _spread([r.get(col) for r in ok])
        out.append(entry)
    return out
