"""``phonepose recover``: salvage a truncated or damaged session into a valid file."""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path

import typer
from rich.table import Table

from phonepose.cli import app
from phonepose.cli.options import QUIET_ACCEPTED
from phonepose.cli.output import print_table, shown, stdout_console
from phonepose.files import OutputPlan, check_input
from phonepose.session.recover import RecoveryReport, salvage
from phonepose.text import printable


def _t(ns: int | None, t0: int | None) -> str:
    if ns is None:
        return "?"
    if t0 is None:
        return dt.datetime.fromtimestamp(ns / 1e9, tz=dt.UTC).isoformat()
    return f"{(ns - t0) / 1e9:+.3f} s"


def report_lines(r: RecoveryReport) -> list[str]:
    """What was lost, in plain sentences (also used by the docs and tests)."""
    t0 = r.start_ns
    lines = [f"recovered {r.messages} messages from {r.chunks_recovered} chunks"
             + (f", {_t(r.start_ns, None)} .. {_t(r.end_ns, t0)}" if r.start_ns is not None else "")]
    if not r.damaged:
        lines.append("the file was not damaged: nothing lost")
        return lines
    lines.append(f"lost: {r.chunks_skipped} damaged chunk(s), {r.bytes_unreadable} of {r.file_size} bytes unreadable, "
                 f"about {r.time_lost_s:.2f} s of log time")
    for s in r.lost:
        if s.start_ns is not None and s.end_ns is not None and s.end_ns == s.start_ns:
            what = "index/summary records only, no messages"
        elif s.end_ns is None:
            what = f"from {_t(s.start_ns, t0)} to the end of the recording (length unknown)"
        else:
            what = f"log time {_t(s.start_ns, t0)} .. {_t(s.end_ns, t0)} ({s.duration_s:.2f} s)"
        lines.append(f"  {s.bytes} bytes: {what}")
    if r.orphan_messages:
        lines.append(f"  {r.orphan_messages} messages dropped: their channel definition was in a lost chunk")
    if r.summary_damaged:
        lines.append("  the summary section fails its CRC" + (
            f"; these topics are named only there (their chunk was lost), check them: "
            f"{', '.join(r.channels_from_damaged_summary)}" if r.channels_from_damaged_summary else
            ": not used, every channel is defined in the chunks"))
    if not r.had_summary:
        lines.append("  the file ends before its footer (recording interrupted or file cut): "
                     "anything not yet written to disk is gone")
    return lines


@app.command()
def recover(
    file: Path = typer.Argument(..., help="Damaged or truncated session (.mcap)."),
    out: Path = typer.Option(..., "--out", "-o", help="Where to write the recovered session (a new file)."),
    as_json: bool = typer.Option(False, "--json", help="Print the report as JSON."),
    force: bool = typer.Option(False, "--force", help="Replace --out if it exists."),
    quiet: bool = typer.Option(False, "--quiet", "-q", **QUIET_ACCEPTED),
) -> None:
    """Salvage every intact chunk of a truncated or corrupted session into a valid, indexed file.

    Exit code 0 when something was recovered; 3 when nothing could be (see docs/reliability.md).

    Example: [bold]phonepose recover damaged.mcap --out fixed.mcap[/bold]
    """
    check_input(file, "MCAP file")
    plan = OutputPlan(inputs=[file])
    fixed = plan.file(out, "out", suffixes=(".mcap",), what="an MCAP session", session=True, force=force)
    with plan:   # checked before reading; written to a temporary; renamed only when complete
        assert fixed.tmp is not None   # the plan's block made it
        r = salvage(file, fixed.tmp, replace=True, staged=False)
    r.out = str(out)
    if as_json:
        typer.echo(json.dumps({
            "path": r.path, "out": r.out, "messages": r.messages, "messages_per_topic": r.messages_per_topic,
            "chunks_recovered": r.chunks_recovered, "chunks_skipped": r.chunks_skipped,
            "bytes_unreadable": r.bytes_unreadable, "file_size": r.file_size, "time_lost_s": r.time_lost_s,
            "orphan_messages": r.orphan_messages, "had_summary": r.had_summary,
            "summary_damaged": r.summary_damaged, "channels_from_damaged_summary": r.channels_from_damaged_summary,
            "start_ns": r.start_ns, "end_ns": r.end_ns,
            "lost": [{"start_ns": s.start_ns, "end_ns": s.end_ns, "bytes": s.bytes} for s in r.lost],
        }, indent=2))
        return
    console = stdout_console()
    typer.echo(f"{file} -> {out}")
    table = Table("topic", "messages recovered")
    for topic, n in r.messages_per_topic.items():
        table.add_row(shown(topic), str(n))     # a damaged file's topic names: anyone's text
    print_table(console, table)
    for line in report_lines(r):
        typer.echo(printable(line))
