"""``phonepose experiment exp1|exp2``: the paper's experiments on simulated sessions."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.progress import BarColumn, TextColumn, TimeElapsedColumn
from rich.table import Table

from phonepose.cli import app
from phonepose.cli.options import QUIET, SEED, CorrectionMath, number
from phonepose.cli.output import ProgressBar, print_table, stdout_console
from phonepose.errors import ConfigError
from phonepose.numbers import WORKERS_MAX

# --tracker/-t selects the trackers elsewhere (playback, batch, record live); the experiments always run T1-T8
USER_TRACKER_HELP = ("Add your own tracker to T1-T8 (repeat): package.module:ClassName or an installed "
                     "phonepose.trackers entry point (docs/writing-a-tracker.md); its rows join the tables.")

experiment_app = typer.Typer(help="Reproduce the paper's experiments on simulated data.\n\n"
                             "Example: [bold]phonepose experiment exp2 --out exp2-out[/bold]", no_args_is_help=True,
                             add_completion=False, pretty_exceptions_enable=False, rich_markup_mode="rich")
app.add_typer(experiment_app, name="experiment")


def _f(v, scale=1.0, digits=1) -> str:
    return "–" if v is None else f"{v * scale:.{digits}f}"


def exp2_summary_tables(result) -> list[Table]:
    """The averages of Tables 5 and 6, ours next to the paper's (cm / deg)."""
    t5 = Table(title="Table 5 (TRI1 + REC1, inside the view): ours / paper")
    t5.add_column("tracker", style="bold")
    for label in ("p_ATE cm", "r_ATE deg", "p_RE cm"):
        t5.add_column(label, justify="right")
    by: dict[str, dict] = {}
    for r in result.table5:
        by.setdefault(r["tracker"], {})[r["key"]] = r
    for tracker, d in by.items():
        t5.add_row(tracker, *[f"{_f(d[k]['average'], d[k]['scale'])} / {d[k]['paper']}"
                              for k in ("p_ate_m", "r_ate_deg", "p_re_m")])
    t6 = Table(title="Table 6 (TRI2 + REC2, average of the sequences): ours / paper")
    t6.add_column("tracker", style="bold")
    t6.add_column("scope")
    for label in ("p_ATE cm", "r_ATE deg", "p_RE cm"):
        t6.add_column(label, justify="right")
    t6.add_column("jump max / RMS cm", justify="right")
    rows6: dict[str, dict] = {}
    for r in result.table6:
        rows6.setdefault(r["tracker"], {})[(r["scope"], r["key"])] = r
    for tracker, d in rows6.items():
        for i, scope in enumerate(("inside", "outside", "total")):
            cells = [f"{_f(d[(scope, k)]['average'], d[(scope, k)]['scale'])} / {d[(scope, k)]['paper']}"
                     for k in ("p_ate_m", "r_ate_deg", "p_re_m")]
            jump = ""
            if scope == "total" and ("total", "boundary_jump_max_m") in d:
                jm, jr = d[("total", "boundary_jump_max_m")], d[("total", "boundary_jump_rms_m")]
                jump = f"{_f(jm['average'], 100)} / {_f(jr['average'], 100)}"
            t6.add_row(tracker if i == 0 else "", scope, *cells, jump, end_section=scope == "total")
    return [t5, t6]


def _check_config(config: Path | None) -> None:
    """A bad --config fails before the output folder is touched or a sequence starts."""
    if config is not None:
        from phonepose.record.sim import load_config
        load_config(config)


@experiment_app.command("exp2")
def exp2(
    out: Path = typer.Option(Path("exp2-out"), "--out", "-o", help="Output directory (replaced whole when it is an "
                             "earlier phonepose output)."),
    trials: int = typer.Option(3, "--trials", callback=number(1, 3, integer=True),
                               help="Trials per path, 1..3 (the paper has 3)."),
    seed: int = typer.Option(0, "--seed", **SEED, help="Base seed; each sequence derives its own from it."),
    config: Path | None = typer.Option(None, "--config", help="Simulator TOML overrides (docs/simulation.md)."),
    correction_math: CorrectionMath = typer.Option(CorrectionMath.paper, "--correction-math", case_sensitive=False,
                                                   help="paper (eq. 1-6) or se3."),
    workers: int | None = typer.Option(None, "--workers", "-j", callback=number(1, WORKERS_MAX, integer=True),
                                       help="Worker processes: sequences in parallel (default: up to 2)."),
    hand_eye: bool = typer.Option(False, "--calibrate-hand-eye", help="Calibrate each session's mocap hand-eye and clock "
                                  "offset from itself and score in the phone's frame (r_ATE without the 11 deg "
                                  "offset; docs/evaluation.md)."),
    exact_gt: bool = typer.Option(False, "--exact-gt", help="Simulate with [mocap] exact = true: the same sensor "
                                  "data, scored against the phone's true pose (no mocap error at all)."),
    calibrate_gt: bool = typer.Option(False, "--calibrate-gt", help="Calibrate each session's ground truth from itself "
                                      "(`phonepose calibrate-gt`: clock, world and rigid body; docs/calibration.md)."),
    tracker: list[str] = typer.Option([], "--add-tracker", help=USER_TRACKER_HELP),
    quiet: bool = typer.Option(False, "--quiet", "-q", **QUIET),
) -> None:
    """Experiment 2 (continuous data): 12 sequences TRI1/TRI2/REC1/REC2 x 3 trials, Tables 5-6, Fig. 11.

    Writes sessions/, playback/ (TUM trajectories and metrics per sequence), table5.md/.csv,
    table6.md/.csv, fig11_TRI2_01.png and exp2.json into --out, all at once when complete.

    Example: [bold]phonepose experiment exp2 --trials 1 --calibrate-hand-eye --out exp2-he[/bold]
    """
    from phonepose.experiments.exp2 import run_exp2

    _check_config(config)
    if hand_eye and calibrate_gt:
        raise ConfigError("--calibrate-hand-eye and --calibrate-gt are exclusive: calibrate-gt estimates the hand-eye too")
    console = stdout_console()
    done = []

    def progress(name: str) -> None:
        done.append(name)
        if not quiet:
            console.print(f"  [green]done[/green] {name} ({len(done)}/{4 * trials})")

    console.print(f"[bold]experiment 2[/bold]: {4 * trials} sequences, seed {seed} -> {out}")
    result = run_exp2(out, trials=trials, seed=seed, config=str(config) if config else None,
                      correction_math=correction_math.value, jobs=workers, progress=progress, hand_eye=hand_eye,
                      exact_gt=exact_gt, calibrate_gt=calibrate_gt, trackers=tracker)
    if calibrate_gt:
        console.print("ground truth calibrated from each session itself (clock, world, rigid body: calibrate-gt)")
    if exact_gt:
        console.print("exact ground truth: the phone's true pose (\\[mocap] exact = true)")
    if hand_eye:
        console.print("ground truth in the phone's frame and clock: each session's hand-eye calibrated from itself")
    for table in exp2_summary_tables(result):
        print_table(console, table)
    for name, path in result.files.items():
        console.print(f"  {name}: {path}")


@experiment_app.command("exp1")
def exp1(
    out: Path = typer.Option(Path("exp1-out"), "--out", "-o", help="Output directory (replaced whole when it is an "
                             "earlier phonepose output)."),
    seed: int = typer.Option(0, "--seed", **SEED, help="Random seed."),
    config: Path | None = typer.Option(None, "--config", help="Simulator TOML overrides (docs/simulation.md)."),
    correction_math: CorrectionMath = typer.Option(CorrectionMath.paper, "--correction-math", case_sensitive=False,
                                                   help="paper (eq. 1-6) or se3."),
    quiet: bool = typer.Option(False, "--quiet", "-q", **QUIET),
    tracker: list[str] = typer.Option([], "--add-tracker", help=USER_TRACKER_HELP),
) -> None:
    """Experiment 1 (discrete data): 16 targets at 25 and 35 cm, Tables 2 and 3 and target selection.

    Example: [bold]phonepose experiment exp1 --seed 1 --out exp1-s1[/bold]
    """
    from phonepose.experiments.exp1 import exp1_tables, run_exp1

    _check_config(config)
    console = stdout_console()
    console.print(f"[bold]experiment 1[/bold]: 16 targets, seed {seed} -> {out}")
    with ProgressBar(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.fields[done]}"),
                     TimeElapsedColumn(), quiet=quiet) as bar:
        record = bar.add_task("recording the session", total=None, done="")
        play = bar.add_task("playing it back", total=None, done="", visible=False)

        def recorded(done_ns: int, total_ns: int | None) -> None:
            total = None if total_ns is None else total_ns / 1e9
            bar.update(record, completed=done_ns / 1e9, total=total,
                       done=f"{done_ns / 1e9:.0f}" + ("" if total is None else f"/{total:.0f}") + " s")

        def played(done: int, total: int) -> None:
            if done == 1 or done % 20 == 0 or done == total:
                bar.update(play, completed=done, total=total, done=f"{done}/{total} ticks", visible=True)

        result = run_exp1(out, seed=seed, config=str(config) if config else None,
                          correction_math=correction_math.value, record_progress=recorded, playback_progress=played,
                          trackers=tracker)
    for table in exp1_tables(result):
        print_table(console, table)
    for name, path in result.files.items():
        console.print(f"  {name}: {path}")
