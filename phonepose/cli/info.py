"""``phonepose info``: what a session holds."""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path

import typer
from rich.table import Table

from phonepose.cli import app
from phonepose.cli.output import stdout_console
from phonepose.session import SessionReader


@app.command()
def info(
    file: Path = typer.Argument(..., help="Session file (.mcap)."),
    as_json: bool = typer.Option(False, "--json", help="Print machine-readable JSON."),
    verify: bool = typer.Option(False, "--verify", help="Also read every chunk and check its CRC."),
) -> None:
    """Channels, schemas, message counts, duration and start time of a session."""
    with SessionReader(file) as reader:
        s = reader.summary()
        chunks = reader.verify(deep=verify)   # damaged chunks: one error line pointing to `recover`
    start = dt.datetime.fromtimestamp(s.start_ns / 1e9, tz=dt.timezone.utc).isoformat() if s.message_count else None
    if as_json:
        typer.echo(json.dumps({
            "path": str(file), "messages": s.message_count, "start_ns": s.start_ns, "end_ns": s.end_ns,
            "start_time": start, "duration_s": s.duration_s,
            "channels": [{"topic": c.topic, "schema": c.schema, "encoding": c.encoding, "messages": c.count}
                         for c in s.channels],
        }, indent=2))
        return
    console = stdout_console()     # piped: topic names are never cut to the terminal's 80 columns
    console.print(f"[bold]{file}[/bold]: {s.message_count} messages, {s.duration_s:.2f} s, start {start}")
    table = Table("topic", "schema", "encoding", "messages")
    for c in s.channels:
        table.add_row(c.topic, c.schema, c.encoding, str(c.count))
    console.print(table)
    if verify:
        typer.echo(f"verified: {chunks} chunks intact (CRC checked)")
