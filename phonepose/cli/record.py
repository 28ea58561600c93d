"""``phonepose record``: record a session (``record sim``: from the built-in simulated world)."""

from __future__ import annotations

import math
import time
from pathlib import Path

import typer
from rich.progress import BarColumn, TextColumn, TimeElapsedColumn

from phonepose.cli import app
from phonepose.cli.options import QUIET, SECONDS, SEED, Scenario, SimPath, number
from phonepose.cli.output import ProgressBar, progress_lines
from phonepose.errors import ConfigError
from phonepose.numbers import RATE_MAX_HZ, RATE_MIN_HZ

record_app = typer.Typer(
    help="Record a session to an MCAP file.\n\nExample: [bold]phonepose record sim --out s.mcap[/bold]",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode="rich",
)
app.add_typer(record_app, name="record")


@record_app.command("sim")
def sim(
    out: Path = typer.Option(..., "--out", "-o", help="Session file to write (.mcap)."),
    scenario: Scenario = typer.Option(Scenario.exp2, "--scenario", case_sensitive=False,
                                      help="exp1 (16 targets, 5 s each) or exp2 (follow a path)."),
    path: SimPath = typer.Option(SimPath.TRI1, "--path", case_sensitive=False,
                                 help="exp2 path: TRI1, REC1 (entirely in view), TRI2, REC2 (partly outside)."),
    trial: int = typer.Option(1, "--trial", callback=number(1, 3, integer=True),
                              help="Trial 1..3 (the paper's Table 4 frame counts differ per trial)."),
    seed: int = typer.Option(0, "--seed", **SEED, help="Random seed: same seed and config give a byte-identical file."),
    config: Path | None = typer.Option(None, "--config", help="TOML file overriding any subset of the simulator's "
                                          "parameters (see docs/simulation.md)."),
    rerun: Path | None = typer.Option(None, "--rerun", help="Also log what is recorded to this Rerun .rrd file."),
    spawn: bool = typer.Option(False, "--spawn", help="Also stream what is recorded to a Rerun viewer."),
    quiet: bool = typer.Option(False, "--quiet", "-q", **QUIET),
    force: bool = typer.Option(False, "--force", help="Replace --out if it exists (without it, an existing file "
                               "is an error and stays untouched)."),
    motion: Path | None = typer.Option(None, "--motion", help="A recorded 6DoF trajectory (TUM, or EuRoC .csv) "
                                          "as the task's hand motion, instead of --path (docs/simulation.md)."),
    motion_start: float = typer.Option(0.0, "--motion-start", **SECONDS, help="--motion window start, s after the "
                                       "file's first pose."),
    motion_duration: float = typer.Option(20.0, "--motion-duration", callback=number(1, 600, unit="s"),
                                          help="--motion window length."),
    motion_scale: float = typer.Option(1.0, "--motion-scale", callback=number(0, 10, lo_open=True),
                                       help="--motion: scale the window's displacements (1: as recorded)."),
    motion_centre: str = typer.Option("0,0.03,0.32", "--motion-centre", help="--motion: where the window's mean "
                                      "position goes, x,y,z m in the display camera's frame (z: away from it)."),
) -> None:
    """Simulate the paper's setup (display phone on a tripod filming the controller phone's
    marker, shared anchor, VIO drift, IMU, motion-capture ground truth) and record it.

    Example: [bold]phonepose record sim --scenario exp2 --path TRI2 --trial 1 --seed 0 --out s.mcap[/bold]

    Ctrl-C or SIGTERM stop the recording and still leave a valid file.
    """
    if rerun is not None and spawn:
        raise ConfigError("use either --rerun FILE or --spawn, not both")
    if motion is not None:          # the options' own mistakes before the simulator's imports (~1 s)
        from phonepose.files import check_input
        check_input(motion, "trajectory file")
        centre = _centre(motion_centre)
    from phonepose.record.sim import load_config, record_sim  # here: keeps `phonepose --help` fast

    cfg = load_config(config)       # a bad config fails before anything is written
    spec = None
    if motion is not None:
        from phonepose.record.sim.recorded import MotionSpec, load_window
        spec = MotionSpec(str(motion), motion_start, motion_duration, motion_scale, centre)
        load_window(spec)           # a bad file or window fails before anything is written
    t0 = time.perf_counter()
    with ProgressBar(TextColumn("[bold]recording[/bold] {task.description}"), BarColumn(),
                     TextColumn("{task.fields[seconds]}"), TimeElapsedColumn(), quiet=quiet) as bar:
        task = bar.add_task(str(out), total=None, seconds="")

        def progress(done_ns: int, total_ns: int | None) -> None:
            total = None if total_ns is None else total_ns / 1e9
            bar.update(task, completed=done_ns / 1e9, total=total,
                       seconds=f"{done_ns / 1e9:.1f}" + ("" if total is None else f"/{total:.1f}") + " s")

        result = record_sim(out, scenario=scenario.value, path=path.value, trial=trial, seed=seed, config=cfg,
                            config_file=config, progress=progress, rerun_path=rerun, spawn=spawn, force=force,
                            stop_on_signals=True, motion=spec)
    wall = time.perf_counter() - t0
    what = f"exp2 {path.value} trial {trial}" if scenario == Scenario.exp2 else f"exp1 trial {trial}"
    if spec is not None:
        what = f"motion {spec.name} {motion_start:g}-{motion_start + motion_duration:g} s"
    status = "interrupted, file is valid" if result.interrupted else "done"
    typer.echo(f"{out}: {what}, seed {seed}: {result.duration_ns / 1e9:.1f} s, {result.frames} frames, "
               f"{result.messages} messages in {wall:.1f} s ({result.duration_ns / 1e9 / max(wall, 1e-9):.1f}x real time), "
               f"{status}")


@record_app.command("rehearse")
def rehearse(
    out: Path = typer.Option(..., "--out", "-o", help="Folder to write (the source session, the video, the "
                             "rehearsed recording live.mcap, the calibration, rehearsal.json)."),
    scenario: Scenario = typer.Option(Scenario.exp2, "--scenario", case_sensitive=False,
                                      help="The simulated session rehearsed (as record sim)."),
    path: SimPath = typer.Option(SimPath.REC1, "--path", case_sensitive=False, help="exp2 path (as record sim)."),
    trial: int = typer.Option(1, "--trial", callback=number(1, 3, integer=True), help="Trial 1..3."),
    seed: int = typer.Option(0, "--seed", **SEED, help="Random seed of the simulated session."),
    config: Path | None = typer.Option(None, "--config", help="TOML file overriding the simulator's parameters "
                                          "(the rehearsal then sets the live path's own: docs/recording-real-sessions.md)."),
    lead_in: float | None = typer.Option(None, "--lead-in", callback=number(2, 120, unit="s"), show_default="20",
                                         help="Still frames before the motion, while the browser starts (s)."),
    headset: bool = typer.Option(True, "--headset/--no-headset", help="Also open the headset page (the ground truth; "
                                 "without it: no calibrate-gt, p_ATE against the true pose)."),
    iwer: Path | None = typer.Option(None, "--iwer", help="iwer.min.js (default: the repository's tests/js/node_modules)."),
    tracker: list[str] = typer.Option([], "--tracker", "-t", help="Run this tracker live during the rehearsed "
                                      "recording (repeatable; as record live -t)."),
    rate: float = typer.Option(20.0, "--rate", callback=number(RATE_MIN_HZ, RATE_MAX_HZ, unit="Hz"),
                               help="Live trackers' ticks per second."),
    pose_port: int = typer.Option(0, "--pose-port", help="Port of the live trackers' pose stream on loopback "
                                  "(0: any free port)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", **QUIET),
) -> None:
    """Rehearse a real recording with no hardware: a simulated session's frames played as a video by
    [bold]record live[/bold], the real phone and headset pages in headless Chromium with emulated WebXR
    devices (IWER) driven by the simulated motion, then calibrate-gt and playback against the source.

    Example: [bold]phonepose record rehearse --out rehearsal[/bold] (1.5 min; exit 1 if a goal is missed)
    """
    from rich.table import Table

    from phonepose.cli.live import live_tracking
    from phonepose.cli.output import print_table, stdout_console
    from phonepose.record.rehearse import LEAD_IN_S, rows
    from phonepose.record.rehearse import rehearse as run_rehearsal

    tracking = live_tracking(tracker, rate, "paper", "127.0.0.1", pose_port)
    result = run_rehearsal(out, scenario=scenario.value, path=path.value if scenario == Scenario.exp2 else None,
                           trial=trial, seed=seed, config=config, lead_in_s=LEAD_IN_S if lead_in is None else lead_in,
                           headset=headset, iwer=iwer, echo=progress_lines(quiet),
                           tracking=tracking)
    table = Table(title=f"{out}: the rehearsed recording against its source session", title_justify="left")
    for col in ("", "measured", "goal", "met"):
        table.add_column(col)
    for r in rows(result.scores):
        table.add_row(r.what, r.value, r.goal, "" if r.met is None else ("yes" if r.met else "NO"))
    print_table(stdout_console(), table)
    for line in result.tracking:
        typer.echo(line)
    missed = [r.what for r in rows(result.scores) if r.met is False]
    if missed:
        typer.echo(f"phonepose: rehearsal: {len(missed)} goal(s) missed: {'; '.join(missed)}", err=True)
        raise typer.Exit(1)


def _centre(text: str) -> tuple[float, float, float]:
    try:
        x, y, z = (float(v) for v in text.split(","))
    except ValueError:
        raise ConfigError(f"--motion-centre {text!r}: expected x,y,z in metres, e.g. 0,0.03,0.32") from None
    if not all(map(math.isfinite, (x, y, z))) or not 0.1 <= z <= 3.0:
        raise ConfigError(f"--motion-centre {text!r}: z (the distance from the camera) must be 0.1..3 m")
    return (x, y, z)
