"""``phonepose playback``: rerun trackers on a recorded session at a fixed rate (docs/playback.md)."""

from __future__ import annotations

import logging
from pathlib import Path

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeRemainingColumn
from rich.table import Table

from phonepose.cli import app
from phonepose.cli.options import SECONDS, TRACKER_HELP, CorrectionMath, number
from phonepose.cli.output import ProgressBar, print_table, stdout_console
from phonepose.errors import ConfigError
from phonepose.numbers import RATE_MAX_HZ, RATE_MIN_HZ
from phonepose.schemas.topics import Topic


def _fmt(v, scale: float = 1.0, digits: int = 2) -> str:
    return "n/a" if v is None else f"{v * scale:.{digits}f}"


def metrics_table(metrics: dict) -> Table:
    """One row per tracker and scope (inside / outside the FoV / total); n/a where not computable."""
    rate = metrics.get("rate_hz")
    table = Table(title=f"{metrics['session']}" + (f" @ {rate} Hz" if rate is not None else ""))
    table.add_column("tracker", style="bold")
    table.add_column("scope")
    for label in ("frames", "p_ATE cm", "r_ATE deg", "p_RE cm", "jump max / RMS cm", "lag ms",
                  "jitter mm / deg", "avail. %"):
        table.add_column(label, justify="right")
    for name, m in metrics["trackers"].items():
        for i, scope in enumerate(("inside", "outside", "total")):
            d = m[scope]
            jump = ""   # the boundary jump: at the ticks where the marker enters or leaves the view
            if scope == "total" and d.get("boundary_jumps"):
                jump = f"{_fmt(d['boundary_jump_max_m'], 100.0)} / {_fmt(d['boundary_jump_rms_m'], 100.0)}"
            table.add_row(name if i == 0 else "", scope, str(d["frames"]), _fmt(d["p_ate_m"], 100.0),
                          _fmt(d["r_ate_deg"]), _fmt(d["p_re_m"], 100.0), jump, *_controller_cells(d, scope),
                          end_section=(scope == "total"))
    return table


def _controller_cells(d: dict, scope: str) -> list[str]:
    """Lag, jitter and availability (phonepose.evaluation.controller): the total row only."""
    if scope != "total" or "lag_s" not in d:
        return ["", "", ""]
    jitter = "" if d["jitter_m"] is None else f"{_fmt(d['jitter_m'], 1000.0)} / {_fmt(d['jitter_deg'])}"
    return [_fmt(d["lag_s"], 1000.0, 0), jitter, _fmt(d["availability"], 100.0, 1)]


def _check_live(session: Path) -> None:
    from phonepose.errors import PhoneposeError
    from phonepose.files import check_input
    from phonepose.playback.livecheck import check_live

    check_input(session, "session")
    checks = check_live(session)
    for c in checks:
        typer.echo(f"{c.tracker}: {c.compared} ticks compared, {c.identical} identical, {c.different} different")
    bad = [c for c in checks if c.different]
    if bad:
        raise PhoneposeError("live estimates differ from playback's: " + ", ".join(
            f"{c.tracker} at {c.different} of {c.compared} ticks (first at log time {c.first_difference_ns} ns)"
            for c in bad))


@app.command()
def playback(
    session: Path = typer.Argument(..., help="The session (.mcap) to play back."),
    tracker: list[str] = typer.Option(["all"], "--tracker", "-t", help=TRACKER_HELP),
    correction_math: CorrectionMath = typer.Option(CorrectionMath.paper, "--correction-math", case_sensitive=False,
                                                   help="paper (equations 1-6) or se3."),
    rate: float = typer.Option(20.0, "--rate", callback=number(RATE_MIN_HZ, RATE_MAX_HZ, unit="Hz"),
                               help="Ticks per second."),
    start: float | None = typer.Option(None, "--start", **SECONDS, help="Start, seconds after the session start."),
    end: float | None = typer.Option(None, "--end", **SECONDS, help="End, seconds after the session start."),
    out: Path | None = typer.Option(None, "--out", "-o", show_default="./playback-<session>",
                                       help="Output directory."),
    rerun: Path | None = typer.Option(None, "--rerun", help="Save a Rerun recording (.rrd) with a default layout."),
    spawn: bool = typer.Option(False, "--spawn", help="Stream to a new Rerun viewer."),
    realtime: bool = typer.Option(False, "--realtime", help="Pace ticks to real time (demos)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
    gt_calibration: Path | None = typer.Option(None, "--gt-calibration", "--hand-eye",
                                                  help="A file from `phonepose calibrate-gt` (or calibrate-hand-eye): "
                                                  "score against the ground truth in the phone's frame, clock and "
                                                  "display_vio (docs/calibration.md)."),
    gt: Path | None = typer.Option(None, "--gt", help="Ground truth from a trajectory file (TUM, or EuRoC .csv) "
                                      "instead of the session's; use with --gt-calibration from `calibrate-gt --gt`."),
    gt_format: str | None = typer.Option(None, "--gt-format", help="tum or euroc (default: euroc for .csv, else tum)."),
    check_live: bool = typer.Option(False, "--check-live", help="Compare the session's live estimates (record live "
                                    "-t) with playback's, tick by tick, bit for bit; writes nothing (exit 1 if any "
                                    "tick differs)."),
) -> None:
    """Replay a session through trackers at a fixed rate; write trajectories, metrics, Rerun."""
    if check_live:
        _check_live(session)
        return
    from phonepose.files import OutputPlan, check_input
    from phonepose.pipeline.trackers import make_trackers
    from phonepose.playback.engine import default_out_dir, run_playback

    if rerun is not None and spawn:
        raise ConfigError("--rerun and --spawn are exclusive: give one")
    if start is not None and end is not None and end <= start:
        raise ConfigError(f"--end ({end}) must be after --start ({start})")
    correction_math = correction_math.value
    make_trackers(tracker, correction_math)  # unknown names fail here, before any work
    # the output rule (phonepose.files): the folder and the .rrd are written under temporary names and put in
    # place whole when the playback is complete, so no file of an earlier run survives beside the new ones and a
    # failed or killed run leaves the earlier output as it was; a second playback into the same --out stops
    named = [(session, "session"), (gt_calibration, "calibration file"), (gt, "ground-truth file")]
    inputs = [p for p, _ in named if p is not None]
    for p, what in named:
        if p is not None:
            check_input(p, what)   # before any side effect: a missing file, a FIFO or a device is one line at once
    plan = OutputPlan(inputs=inputs)
    folder = plan.dir(out if out is not None else default_out_dir(session), "--out", command="playback")
    rrd = plan.file(rerun, "--rerun", suffixes=(".rrd",), what="a Rerun recording") if rerun is not None else None
    console = Console(stderr=True)
    with plan, ProgressBar(TextColumn("playback"), BarColumn(), MofNCompleteColumn(), TextColumn("ticks"),
                           TimeRemainingColumn(), console=console, quiet=quiet) as bar:
        task = bar.add_task("ticks", total=None)

        def progress(done: int, total: int) -> None:
            if done == 1 or done % 10 == 0 or done == total:
                bar.update(task, completed=done, total=total)

        result = run_playback(session, trackers=tracker, out_dir=folder.tmp, rate_hz=rate,
                              correction_math=correction_math, rerun_path=rrd.tmp if rrd is not None else None,
                              spawn=spawn, start_s=start, end_s=end, realtime=realtime, progress=progress,
                              gt_calibration=gt_calibration, gt_file=gt, gt_format=gt_format)
    print_table(stdout_console(), metrics_table(result.metrics))
    if gt is not None and not result.has_gt:   # asked for, and unusable: a problem, not a fact about the session
        logging.getLogger("phonepose").warning(
            "phonepose: warning: --gt %s: no usable ground truth from it (it needs a --gt-calibration from "
            "`phonepose calibrate-gt SESSION --gt FILE`, or the session's %s, and poses within 0.02 s of the task "
            "window's ticks: not another session's, nor on another clock); accuracy metrics are null in metrics.json",
            gt, Topic.GT_CALIBRATION)
    elif not result.has_gt:
        typer.echo(f"no usable ground truth (needs {Topic.GT_CONTROLLER_POSE} and {Topic.GT_CALIBRATION} within the "
                   "task window): accuracy metrics are unavailable (null in metrics.json)")
    gt_note = result.metrics.get("ground_truth")
    if gt_note is not None and result.has_gt and "calibration_file" in gt_note:
        where = " and display_vio" if gt_note["world_display_vio"] == "calibrated" else ""
        typer.echo(f"ground truth moved into the phone's frame, clock{where} ({gt_note['calibration_file']}: "
                   f"{gt_note['body_rotation_deg']:.2f} deg, ground-truth clock {gt_note['time_offset_s'] * 1e3:+.1f} ms)")
    typer.echo(f"{result.n_ticks} ticks in {result.wall_s:.1f} s -> {folder.path}"
               + (f", rerun: {rrd.path}" if rrd is not None else ""))
