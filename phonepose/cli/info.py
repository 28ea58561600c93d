"""``phonepose info``: what a session holds."""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path

import typer
from rich.table import Table

from phonepose.cli import app
from phonepose.cli.output import print_table, shown, stdout_console
from phonepose.errors import SessionContentError
from phonepose.schemas.topics import Topic
from phonepose.session import SessionReader, codec


def _task_window(reader: SessionReader, s) -> list[float] | None:
    """The task window from the session's info message, in seconds after the session start."""
    if not s.has(Topic.SESSION_INFO):
        return None
    try:
        info = reader.first(Topic.SESSION_INFO)
    except SessionContentError:     # a broken info message: info still shows the rest
        return None
    t0, t1 = codec.timestamp_ns(info.task_start), codec.timestamp_ns(info.task_end)
    if not (t0 and t1):
        return None
    return [round((t0 - s.start_ns) / 1e9, 3), round((t1 - s.start_ns) / 1e9, 3)]


@app.command()
def info(
    file: Path = typer.Argument(..., help="Session file (.mcap)."),
    as_json: bool = typer.Option(False, "--json", help="Print machine-readable JSON."),
    verify: bool = typer.Option(False, "--verify", help="Also read every chunk and check its CRC."),
) -> None:
    """Channels, schemas, message counts, duration and start time of a session.

    Example: [bold]phonepose info s.mcap --verify[/bold]
    """
    from phonepose.calibration.ground_truth import ground_truth_source
    with SessionReader(file) as reader:
        s = reader.summary()
        chunks = reader.verify(deep=verify)   # damaged chunks: one error line pointing to `recover`
        task = _task_window(reader, s)
        try:
            gt_source = ground_truth_source(reader)
        except SessionContentError:     # a broken info message: info still shows the rest
            gt_source = ""
    from phonepose.playback.livereport import live_report, summary_lines
    try:
        live = live_report(file)        # the live trackers' figures (record live -t)
    except SessionContentError as exc:  # damaged figures: info still shows the rest
        typer.echo(f"phonepose: warning: {exc}", err=True)
        live = None
    start = dt.datetime.fromtimestamp(s.start_ns / 1e9, tz=dt.UTC).isoformat() if s.message_count else None
    if as_json:
        typer.echo(json.dumps({
            "path": str(file), "messages": s.message_count, "start_ns": s.start_ns, "end_ns": s.end_ns,
            "start_time": start, "duration_s": s.duration_s, "task_window_s": task, "ground_truth_source": gt_source,
            "live_tracking": live,
            "channels": [{"topic": c.topic, "schema": c.schema, "encoding": c.encoding, "messages": c.count}
                         for c in s.channels],
        }, indent=2))
        return
    console = stdout_console()     # piped: topic names are never cut to the terminal's 80 columns
    console.print(f"[bold]{shown(str(file))}[/bold]: {s.message_count} messages, {s.duration_s:.2f} s, start {start}")
    if task is not None:   # what playback scores and --start/--end must overlap
        console.print(f"task window {task[0]:.2f}-{task[1]:.2f} s (seconds after the start)")
    if gt_source:
        console.print(f"ground truth: {shown(gt_source)}")
    table = Table("topic", "schema", "encoding", "messages")
    for c in s.channels:
        table.add_row(shown(c.topic), shown(c.schema), shown(c.encoding), str(c.count))
    print_table(console, table)
    for line in summary_lines(live) if live is not None else []:
        typer.echo(shown(line))
    if verify:
        typer.echo(f"verified: {chunks} chunks intact (CRC checked)")
