"""``phonepose playback``: rerun trackers on a recorded session at a fixed rate (docs/playback.md)."""

from __future__ import annotations

import logging
from pathlib import Path

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeRemainingColumn
from rich.table import Table
from rich.text import Text

from phonepose.cli import app
from phonepose.cli.options import QUIET, SECONDS, TRACKER_HELP, CorrectionMath, number
from phonepose.cli.output import ProgressBar, print_table, stdout_console
from phonepose.errors import ConfigError
from phonepose.numbers import RATE_MAX_HZ, RATE_MIN_HZ, SECONDS_MAX
from phonepose.schemas.topics import Topic

# A tracker step that takes longer is stopped: a real step takes milliseconds, a heavy one on a loaded machine seconds
TICK_TIMEOUT_S = 60.0


def _fmt(v, scale: float = 1.0, digits: int = 2) -> str:
    return "n/a" if v is None else f"{v * scale:.{digits}f}"


SCOPES = ("inside", "outside", "total")
# metrics_table's number columns: header, the numbers of a cell ((metrics.json key, scale, digits) each), the
# scopes that have it, which value is best ("min", "max", "zero": nearest 0) and whether a scope's metrics show
# it (the boundary jump needs a transition, the controller metrics a source that has them, jitter a still phone)
COLUMNS = (
    ("p_ATE cm", [("p_ate_m", 100.0, 2)], SCOPES, "min", lambda d: True),
    ("r_ATE deg", [("r_ate_deg", 1.0, 2)], SCOPES, "min", lambda d: True),
    ("p_RE cm", [("p_re_m", 100.0, 2)], SCOPES, "min", lambda d: True),
    ("jump max / RMS cm", [("boundary_jump_max_m", 100.0, 2), ("boundary_jump_rms_m", 100.0, 2)], ("total",), "min",
     lambda d: bool(d.get("boundary_jumps"))),
    ("lag ms", [("lag_s", 1000.0, 0)], ("total",), "zero", lambda d: "lag_s" in d),
    ("jitter mm / deg", [("jitter_m", 1000.0, 2), ("jitter_deg", 1.0, 2)], ("total",), "min",
     lambda d: "lag_s" in d and d["jitter_m"] is not None),
    ("avail. %", [("availability", 100.0, 1)], ("total",), "max", lambda d: "lag_s" in d),
)
BEST_MARK = "*"
# the lines under the demo's table: what the marks and the columns beyond the paper's three mean
TABLE_LEGEND = (
    f"{BEST_MARK} best of its column in that scope (inside / outside the camera's view, total)",
    "p_ATE, r_ATE: RMS position, rotation error; p_RE: RMS position error of sub-paths",
    "jump: how much more the estimate moved than the phone where the marker enters or leaves the view",
    "lag: the time shift that best fits the estimate to the truth; positive: late, negative: ahead",
    "jitter: the error's tick-to-tick shake while the phone is held still",
    "avail.: the share of the task's ticks at which the tracker has a pose",
    "definitions: docs/evaluation.md",
)


def metrics_table(metrics: dict, mark_best: bool = False, title_ours: bool = False) -> Table:
    """One row per tracker and scope (inside / outside the FoV / total); n/a where not computable.

    ``mark_best``: the best value of each column within its scope in bold after a ``*`` (before the number, so
    that right-aligned digits stay aligned; in a cell of two numbers the first one decides); no mark where every
    tracker shows the same. ``title_ours``: the title says which trackers are the paper's and which ours."""
    from phonepose.viewer.style import PAPER

    rate = metrics.get("rate_hz")
    title = f"{metrics['session']}" + (f" @ {rate} Hz" if rate is not None else "")
    trackers = metrics["trackers"]
    ours = [name for name in trackers if name not in PAPER]
    if title_ours:   # the title wraps where the table is narrow; a longer tracker name would widen every row
        paper = [name for name in trackers if name in PAPER]
        title += ": " + " and ".join(part for part in (f"the paper's {_names(paper)}" if paper else "",
                                                       f"ours ({_names(ours)})" if ours else "") if part)
    table = Table(title=title)
    table.add_column("tracker", style="bold")
    table.add_column("scope")
    table.add_column("frames", justify="right")
    for header, *_ in COLUMNS:
        table.add_column(header, justify="right")
    best = _best_cells(trackers) if mark_best else {}
    for name, m in trackers.items():
        for i, scope in enumerate(SCOPES):
            d = m[scope]
            cells: list[str | Text] = []
            for column in range(len(COLUMNS)):
                shown = _shown(d, column, scope)
                if shown is None:
                    cells.append("")
                elif shown[0] in best.get((column, scope), ()):
                    cells.append(Text.assemble(BEST_MARK, (" / ".join(shown), "bold")))
                else:
                    cells.append(Text(" / ".join(shown)))
            table.add_row(name if i == 0 else "", scope, str(d["frames"]), *cells, end_section=(scope == "total"))
    return table


def _names(names: list[str]) -> str:
    """T1-T7 for the paper's seven in order, else the names one by one."""
    from phonepose.viewer.style import PAPER

    return "T1-T7" if tuple(names) == PAPER else ", ".join(names)


def _shown(d: dict, column: int, scope: str) -> list[str] | None:
    """A cell's numbers as printed, or None where the cell is empty."""
    _, parts, scopes, _, shows = COLUMNS[column]
    if scope not in scopes or not shows(d):
        return None
    return [_fmt(d[key], scale, digits) for key, scale, digits in parts]


def _best_cells(trackers: dict) -> dict[tuple[int, str], set[str]]:
    """The best first numbers as printed (ties: all of them, lag's -15 and 15 alike), per (column, scope),
    where the trackers differ."""
    best = {}
    for column, (_, _, scopes, goal, _) in enumerate(COLUMNS):
        order = {"min": lambda x: x, "max": lambda x: -x, "zero": abs}[goal]
        for scope in scopes:
            values = {v[0] for m in trackers.values()
                      if (v := _shown(m[scope], column, scope)) is not None and v[0] != "n/a"}
            if len({float(v) for v in values}) > 1:
                top = min(order(float(v)) for v in values)
                best[column, scope] = {v for v in values if order(float(v)) == top}
    return best


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
    quiet: bool = typer.Option(False, "--quiet", "-q", **QUIET),
    gt_calibration: Path | None = typer.Option(None, "--gt-calibration",
                                                  help="A file from `phonepose calibrate-gt` (or calibrate-hand-eye): "
                                                  "score against the ground truth in the phone's frame, clock and "
                                                  "display_vio (docs/calibration.md)."),
    gt: Path | None = typer.Option(None, "--gt", help="Ground truth from a trajectory file (TUM, or EuRoC .csv) "
                                      "instead of the session's; use with --gt-calibration from `calibrate-gt --gt`."),
    gt_format: str | None = typer.Option(None, "--gt-format", help="tum or euroc (default: euroc for .csv, else tum)."),
    tick_timeout: float = typer.Option(TICK_TIMEOUT_S, "--tick-timeout", callback=number(0, SECONDS_MAX, lo_open=True, unit="s"),
                                       help="Stop a tracker whose step takes longer than this (seconds): one line "
                                            "naming it and the tick, exit 5, no output."),
    check_live: bool = typer.Option(False, "--check-live", help="Compare the session's live estimates (record live "
                                    "-t) with playback's, tick by tick, bit for bit; writes nothing (exit 1 if any "
                                    "tick differs)."),
) -> None:
    """Replay a session through trackers at a fixed rate; write trajectories, metrics, Rerun.

    Example: [bold]phonepose playback s.mcap -t T1,T4 --rate 20 --out pb --rerun pb.rrd[/bold]
    """
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
    folder = plan.dir(out if out is not None else default_out_dir(session), "out", command="playback")
    rrd = plan.file(rerun, "rerun", suffixes=(".rrd",), what="a Rerun recording") if rerun is not None else None
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
                              gt_calibration=gt_calibration, gt_file=gt, gt_format=gt_format,
                              tick_timeout_s=tick_timeout)
    print_table(stdout_console(), metrics_table(result.metrics))
    if gt is not None and not result.has_gt:   # asked for, and unusable: a problem, not a fact about the session
        logging.getLogger("phonepose").warning(
            "--gt %s: no usable ground truth from it (it needs a --gt-calibration from "
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
