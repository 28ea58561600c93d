"""``phonepose demo``: the whole tool end to end with no arguments (the README's first command)."""

from __future__ import annotations

from pathlib import Path

import typer

from phonepose.cli import app
from phonepose.cli.options import QUIET, SEED
from phonepose.cli.output import print_table, stdout_console


@app.command()
def demo(
    out: Path = typer.Option(Path("phonepose-demo"), "--out", "-o", help="Output directory (replaced whole when it "
                             "is an earlier phonepose output)."),
    seed: int = typer.Option(0, "--seed", **SEED, help="Random seed of the simulated session."),
    quiet: bool = typer.Option(False, "--quiet", "-q", **QUIET),
) -> None:
    """Record a simulated TRI2 session, replay it through T1-T7 and ours (T7L, T8), print the metrics, save a plot and a .rrd.

    The session follows the paper's path TRI2 (partly outside the display camera's view). Outputs
    go to --out, all at once when complete: the session, playback/ (TUM trajectories and
    metrics.json), a Fig. 11-style plot, demo.rrd.

    Example: [bold]phonepose demo --out phonepose-demo[/bold]
    """
    from phonepose.cli.playback import TABLE_LEGEND, metrics_table
    from phonepose.experiments.common import sequence_arrays
    from phonepose.experiments.exp2 import plot_sequence
    from phonepose.files import OutputPlan
    from phonepose.playback.engine import run_playback
    from phonepose.record.sim import record_sim

    console = stdout_console()
    plan = OutputPlan()
    folder = plan.dir(out, "out", command="demo")
    with plan:
        work = folder.tmp
        assert work is not None   # the plan's block made it
        session = work / "TRI2_01.mcap"
        with _status(console, "recording a simulated session (exp2, path TRI2, trial 1)...", quiet):
            rec = record_sim(session, scenario="exp2", path="TRI2", trial=1, seed=seed)
        console.print(f"[green]1/3[/green] recorded {folder.final(session)} ({_describe(rec)})")
        with _status(console, "playing it back through T1-T7, T7L and T8 at 20 Hz...", quiet):
            result = run_playback(session, trackers="all", out_dir=work / "playback", rerun_path=work / "demo.rrd")
        console.print(f"[green]2/3[/green] played back {result.n_ticks} ticks in {result.wall_s:.1f} s")
        print_table(console, metrics_table(result.metrics, mark_best=True, title_ours=True))
        for line in TABLE_LEGEND:
            console.print(line, highlight=False)
        final = folder.final(session)
        console.print("r_ATE is ~11-13 deg for every tracker, as in the paper: the simulated motion capture measures "
                      "a rigid body turned 11 deg from the phone. To score without it:\n"
                      f"  [bold]phonepose calibrate-hand-eye {final} -o he.yaml && "
                      f"phonepose playback {final} --gt-calibration he.yaml[/bold]")
        seq = {"name": "TRI2_01", **sequence_arrays(result, session)}
        png = plot_sequence(seq, work / "fig11_TRI2_01.png")
        png = folder.final(png) if png is not None else None
    rrd = out / "demo.rrd"
    console.print(f"[green]3/3[/green] plot: {png}")
    console.print(f"trajectories and metrics: {out / 'playback'}  (metrics.json, trajectories/*.tum)")
    console.print(f"Rerun recording: {rrd}\n  open it with:  [bold]rerun {rrd}[/bold]")
    console.print("next: [bold]phonepose experiment exp2[/bold] reproduces the paper's Tables 5 and 6.")


def _status(console, text: str, quiet: bool):
    """The spinner of a step, none with --quiet."""
    import contextlib

    return contextlib.nullcontext() if quiet else console.status(text)


def _describe(rec) -> str:
    return f"{rec.duration_ns / 1e9:.1f} s, {rec.frames} camera frames, {rec.messages} messages"
