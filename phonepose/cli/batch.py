"""``phonepose batch``: every (session, tracker, parameter) playback into one Parquet table (docs/batch.md)."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Table

from phonepose.cli import app
from phonepose.cli.options import QUIET, TRACKER_HELP, number
from phonepose.cli.output import ProgressBar, print_table, stdout_console
from phonepose.cli.output import shown as shown_text
from phonepose.numbers import SECONDS_MAX, UNIT_TIMEOUT_S, WORKERS_MAX
from phonepose.text import printable

FAILURES_SHOWN = 3   # lines printed per cause of failure; the rest are counted, one line at the end


def failure_cause(row: dict) -> str:
    """What tells causes apart: the error without its session's path and with every number as #
    (``the session runs 14.48 s`` is one cause whatever the session, the start, the rate)."""
    text = row["error"] or ""
    for path in sorted({row["session"], os.path.abspath(row["session"])}, key=len, reverse=True):
        text = text.replace(path, "SESSION")
    return re.sub(r"[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?", "#", text)


class FailureLines:
    """``failed SESSION (params): error`` for the first FAILURES_SHOWN failures of each cause, then
    one line per cause at the end: ``... and N more failures like this: error`` (every failure is a
    row in the table anyway)."""

    def __init__(self, print_line, shown: int = FAILURES_SHOWN):
        self.print_line, self.shown = print_line, shown
        self.counts: dict[str, int] = {}
        self.first: dict[str, str] = {}

    def failed(self, row: dict, params: str) -> None:
        cause = failure_cause(row)
        n = self.counts[cause] = self.counts.get(cause, 0) + 1
        self.first.setdefault(cause, row["error"])
        if n <= self.shown:
            self.print_line(f"[red]failed[/red] {shown_text(row['session'])}{' (' + params + ')' if params else ''}: "
                            f"{shown_text(row['error'] or '')}")

    def more_lines(self) -> list[str]:
        return [f"... and {n - self.shown:,} more failure{'s' if n - self.shown != 1 else ''} like this: "
                f"{printable(self.first[cause])}" for cause, n in self.counts.items() if n > self.shown]


SUMMARY_ROWS_SHOWN = 100   # a sweep of 10^5 combinations would print 10^5 x trackers summary rows


def summary_table(summary: list[dict], out: object = None, shown: int = SUMMARY_ROWS_SHOWN) -> Table:
    from phonepose.batch.driver import SUMMARY_METRICS

    more = len(summary) - shown
    summary = summary[:shown] if more > 0 else summary
    table = Table(title="batch summary: mean ± sd over sessions (total scope)",
                  caption=f"... and {more:,} more rows (tracker x parameter combinations): read them from {out}"
                  if more > 0 else None)
    table.add_column("tracker", style="bold")
    if any(e["params"] is not None for e in summary):
        table.add_column("params")
    table.add_column("ok", justify="right")
    table.add_column("errors", justify="right")
    for _, label, _ in SUMMARY_METRICS:
        table.add_column(label, justify="right")
    for e in summary:
        cells = [e["tracker"]] + ([e["params"]] if e["params"] is not None else []) + [str(e["ok"]), str(e["errors"])]
        for col, _, scale in SUMMARY_METRICS:
            mean, sd = e[col]
            cells.append("n/a" if mean is None else f"{mean * scale:.2f} ±{sd * scale:.2f}")
        table.add_row(*cells)
    return table


@app.command()
def batch(
    sessions: list[Path] = typer.Argument(..., help="Session files (.mcap); on a cluster every worker must see these paths."),
    tracker: list[str] = typer.Option(["all"], "--tracker", "-t", help=TRACKER_HELP),
    param: list[str] = typer.Option([], "--param", "-p",
                                    help="KEY=V1,V2,... (repeat): rate_hz, correction_math, cm1_reading, start_s, end_s; "
                                         "the batch runs the cross product."),
    out: Path = typer.Option(..., "--out", "-o", help="Parquet table; rows already in it with status ok are skipped."),
    workers: int | None = typer.Option(None, "--workers", "-j", callback=number(1, WORKERS_MAX, integer=True),
                                          help="Local worker processes (default: one per core)."),
    scheduler: str | None = typer.Option(None, "--scheduler",
                                            help="Dask scheduler address (tcp://host:8786) instead of local processes."),
    unit_timeout: float = typer.Option(UNIT_TIMEOUT_S, "--unit-timeout",
                                       callback=number(0, SECONDS_MAX, lo_open=True, unit="s"),
                                       help="Seconds one playback may take; a longer one becomes error rows."),
    quiet: bool = typer.Option(False, "--quiet", "-q", **QUIET),
    keep_waiting: bool = typer.Option(False, "--keep-waiting", help="With --scheduler: when the cluster has no "
                                      "worker, wait for one for ever instead of stopping after 30 s."),
    calibrate_gt: bool = typer.Option(False, "--calibrate-gt", help="Calibrate each session's ground truth from "
                                      "itself first (`phonepose calibrate-gt`); its rows have param_gt_calibration."),
) -> None:
    """Play back every session x parameter combination with every tracker; one row per run into a Parquet table.

    Exit 0 when every row is ok, 1 when some playbacks failed (their rows say why; they are
    retried by the next run with the same --out). Ctrl-C or SIGTERM stop the workers and keep
    every finished row in --out.

    Example: [bold]phonepose batch s1.mcap s2.mcap -t T1,T8 -p rate_hz=10,20 -j 2 --out sweep.parquet[/bold]
    """
    from phonepose.batch import summarize
    from phonepose.batch.driver import execute_batch, prepare_batch
    from phonepose.batch.executor import NO_WORKER_TIMEOUT_S
    from phonepose.batch.plan import params_label

    prepared = prepare_batch([str(s) for s in sessions], out, trackers=tracker, params=param, workers=workers,
                             scheduler=scheduler, unit_timeout_s=unit_timeout, calibrate_gt=calibrate_gt)
    console = Console(stderr=True)
    with ProgressBar(TextColumn("batch"), BarColumn(), MofNCompleteColumn(), TextColumn("playbacks"),
                     TextColumn("{task.fields[rows]} rows, {task.fields[errors]} errors"), TimeElapsedColumn(),
                     TimeRemainingColumn(), console=console, quiet=quiet) as bar:
        task = bar.add_task("units", total=None, rows=0, errors=0)
        counts = {"rows": 0, "errors": 0}

        varying: list[str] = []

        def on_start(plan, executor: str) -> None:
            varying.extend(plan.varying)
            n_rows = len(plan.keys)
            redo = f", {plan.retried} error rows retried" if plan.retried else ""
            redo += f", {plan.stale} rows of changed sessions rerun" if plan.stale else ""
            where = f"{len(plan.units)} playbacks on {executor}" if plan.units else "nothing to run"
            bar.console.print(f"{plan.sessions} sessions x {plan.combinations} parameter combinations x "
                              f"{len(plan.trackers)} trackers = {n_rows} rows; {plan.skipped} already in {out} (skipped)"
                              f"{redo}; {where}", highlight=False, soft_wrap=True)
            bar.update(task, total=len(plan.units))

        def on_workers(n: int) -> None:
            if n == 0:
                wait = "for ever (--keep-waiting)" if keep_waiting else f"up to {NO_WORKER_TIMEOUT_S:g} s"
                bar.console.print(f"phonepose: warning: --scheduler {scheduler}: the cluster has no worker now; "
                                  f"waiting {wait} for one (start `dask worker {scheduler}`)", highlight=False,
                                  soft_wrap=True, markup=False)
            else:
                bar.console.print(f"Dask cluster {scheduler} ({n} worker{'s' if n != 1 else ''} now)", highlight=False,
                                  soft_wrap=True)

        failures = FailureLines(lambda line: bar.console.print(line, highlight=False, soft_wrap=True))

        def progress(done: int, total: int, rows: list[dict]) -> None:
            counts["rows"] += len(rows)
            if rows and rows[0]["status"] != "ok":
                counts["errors"] += len(rows)
                failures.failed(rows[0], params_label(json.loads(rows[0]["params"]), varying))
            bar.update(task, completed=done, total=total, **counts)

        try:
            try:
                result = execute_batch(prepared, progress=progress, on_start=on_start, on_workers=on_workers,
                                       no_worker_timeout_s=None if keep_waiting else NO_WORKER_TIMEOUT_S)
            finally:
                for line in failures.more_lines():
                    bar.console.print(line, highlight=False, soft_wrap=True, markup=False)
        except KeyboardInterrupt as exc:    # Ctrl-C or SIGTERM: the workers are gone, the finished rows kept
            n = len(prepared.table.rows)
            raise type(exc)(f"{n} finished row{'s' if n != 1 else ''} {'are' if n != 1 else 'is'} in {out}; the next "
                            "run with the same --out goes on from there") from None
    print_table(stdout_console(), summary_table(summarize(result.rows), result.out))
    rate = f" ({result.rows_run / result.wall_s:.1f} rows/s)" if result.rows_run and result.wall_s > 0 else ""
    typer.echo(f"{result.units_run} playbacks ({result.rows_run} rows) run in {result.wall_s:.1f} s{rate}, "
               f"{result.skipped} rows skipped (already in the table) -> {result.out}")
    if result.errors:
        typer.echo(f"phonepose: error: {result.errors} of {len(result.rows)} rows failed (status error in {result.out}; "
                   "the next run with the same --out retries them)", err=True)
        raise typer.Exit(1)
