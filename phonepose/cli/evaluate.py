"""``phonepose evaluate``: ATE/RE as rpg_trajectory_evaluation, APE/RPE as evo (docs/evaluation.md)."""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import numpy as np
import typer

from phonepose.cli import app
from phonepose.cli.options import Align, DeltaUnit, Metric, PoseRelation, TrajectoryFormat, number
from phonepose.cli.output import print_table, stdout_console
from phonepose.errors import ConfigError, PhoneposeError, SessionContentError
from phonepose.numbers import SECONDS_MAX


def _parse_lengths(text: str | None) -> list[float] | None:
    if text is None:
        return None
    try:
        vals = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise ConfigError(f"--lengths {text!r}: expected comma-separated metres, e.g. 1,2.5,5") from None
    if not vals or any(not (0 < v < float("inf")) for v in vals):
        raise ConfigError(f"--lengths {text!r}: expected positive metres, e.g. 1,2.5,5")
    return vals


def _first_non_finite(doc, where: str = "") -> str | None:
    """The key path of the first NaN/inf number in a result document, or None."""
    items = doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, list) else ()
    for key, value in items:
        path = f"{where}.{key}" if where else str(key)
        if isinstance(value, float) and not math.isfinite(value):
            return path
        found = _first_non_finite(value, path) if isinstance(value, (dict, list)) else None
        if found:
            return found
    return None


def _check_finite(result: dict, gt: Path, est: Path) -> None:
    """Never print or write a NaN/inf metric as if it were one (and ``--json`` never fails on one): the
    readers bound what a trajectory holds, so this is one line for whatever still overflows."""
    bad = _first_non_finite(result)
    if bad is not None:
        raise SessionContentError(f"the errors of {est} against {gt} are not finite numbers ({bad}): check the "
                                  "trajectories' values and units")


def _fmt(v) -> str:
    return "-" if v is None else f"{v:.6g}"


def _stats_row(table, name: str, length: str, unit: str, s: dict, end_section: bool = False) -> None:
    table.add_row(name, length, unit, *(_fmt(s.get(k)) for k in ("rmse", "mean", "median", "std", "min", "max")),
                  str(s.get("num_samples", "")), end_section=end_section)


def _print_table(result: dict, metric: str, gt: Path, est: Path) -> None:
    from rich.table import Table

    console = stdout_console()
    al = result["align"]
    console.print(f"estimate [bold]{est}[/bold]\nvs GT    [bold]{gt}[/bold]", soft_wrap=True)
    console.print(f"{result['n_matched']} matched poses, align {al['method']} "
                  f"(frames {al['num_frames']}, scale {al['scale']:.6g})")
    table = Table("error", "L \\[m]", "unit", "rmse", "mean", "median", "std", "min", "max", "n")
    if metric == "rpg":
        _stats_row(table, "ATE translation", "", "m", result["ate"]["trans_m"])
        _stats_row(table, "ATE rotation", "", "deg", result["ate"]["rot_deg"])
        for length, r in result["re"].items():
            _stats_row(table, "RE translation", length, "m", r["trans_m"])
            _stats_row(table, "RE translation", length, "%", r["trans_perc"])
            _stats_row(table, "RE rotation", length, "deg", r["rot_deg"])
            _stats_row(table, "RE yaw", length, "deg", r["yaw_deg"])
            _stats_row(table, "RE gravity", length, "deg", r["gravity_deg"], end_section=True)
    else:
        s = result[metric]
        unit = {"translation part": "m", "rotation angle in degrees": "deg", "rotation angle in radians": "rad",
                "point distance": "m", "point distance error ratio": "%"}.get(s["pose_relation"], "-")
        name = f"{metric.upper()} {s['pose_relation']}"
        length = ""
        if metric == "rpe":
            length = f"Δ {s['delta']} {s['delta_unit']}{' all' if s['all_pairs'] else ''}"
        _stats_row(table, name, length, unit, s)
    print_table(console, table)


def _paper(gt_traj, est_traj, in_view: Path | None, max_diff: float) -> dict:
    """The paper's metrics as playback computes them, from files: GT, estimate and in-view flags
    associated by timestamp (rpg's greedy association, ``max_diff`` s)."""
    from phonepose.evaluation import associate_rpg, paper_metrics
    from phonepose.evaluation.controller import controller_metrics
    from phonepose.evaluation.trajectory import load_in_view
    from phonepose.playback.outputs import normalise_metrics

    if in_view is None:
        raise ConfigError("--metric paper needs --in-view FILE (playback writes in_view.txt beside groundtruth.tum)")
    if gt_traj.stamps is None or est_traj.stamps is None:
        raise ConfigError("--metric paper needs timestamped trajectories (TUM or EuRoC), not KITTI")
    flag_t, flags = load_in_view(in_view)
    i_est, i_gt = associate_rpg(est_traj.stamps, gt_traj.stamps, max_diff)
    i_est2, i_flag = associate_rpg(est_traj.stamps[i_est], flag_t, max_diff)
    i_est, i_gt = i_est[i_est2], i_gt[i_est2]
    order = np.argsort(est_traj.stamps[i_est], kind="stable")
    i_est, i_gt, i_flag = i_est[order], i_gt[order], i_flag[order]
    if i_est.size == 0:
        raise SessionContentError("no estimate, ground-truth and in-view stamps within --max-diff of each other")
    result = paper_metrics(est_traj.stamps[i_est], gt_traj.poses[i_gt], est_traj.poses[i_est], flags[i_flag])
    # lag, jitter, availability: the GT file's stamps are the task's ticks (playback writes one per tick)
    result["total"].update(controller_metrics(gt_traj.stamps, gt_traj.poses, est_traj.stamps, est_traj.poses,
                                              est_traj.stamps[i_est], i_gt, i_est))
    return normalise_metrics(result)


# Below this, the matched poses are not the two trajectories of one run (a playback's estimate and
# its ground truth match at every tick of the task window; a SLAM estimate covers most of its sequence).
MIN_COVERAGE = 0.5


def _warn_on_small_overlap(gt: Path, est: Path, gt_traj, est_traj, max_diff: float) -> None:
    """One warning line when the matched poses cover a small part of either trajectory."""
    from phonepose.evaluation.association import coverage

    if gt_traj.stamps is None or est_traj.stamps is None:
        return
    est_frac, gt_frac = coverage(est_traj.stamps, gt_traj.stamps, max_diff)
    if est_frac == 0.0 or min(est_frac, gt_frac) >= MIN_COVERAGE:
        return     # no match at all is an error of its own
    logging.getLogger("phonepose").warning(
        "the matched poses cover %.0f%% of %s's poses and %.0f%% of %s's time span: are they "
        "from the same session?", 100 * est_frac, est, 100 * gt_frac, gt)


# A ratio of spreads within 25 % of 100x or 1000x (either way) is two units (cm or mm against m): a tracker's scale
# error is a few percent; one that diverges or sticks rarely lands on a power of ten; a monocular SLAM's arbitrary
# scale is what --align sim3 is for.
UNIT_RATIOS = (100.0, 1000.0)
UNIT_RATIO_TOL = 0.25


def _warn_on_other_unit(gt: Path, est: Path, gt_traj, est_traj, max_diff: float, align: str | None) -> None:
    """One warning line when the matched positions of the two files spread over lengths about 100x or 1000x apart: a
    file in millimetres evaluated against one in metres gives errors in the hundreds of metres, which nothing else
    flags (neither file says its unit). Not with --align sim3, whose scale takes it out."""
    from phonepose.evaluation.evo_metrics import associate

    if align == "sim3":
        return
    try:
        i_est, i_gt = associate(gt_traj, est_traj, max_diff)
    except PhoneposeError:
        return      # no match: an error of its own, later
    spread = [float(np.sqrt(np.mean(np.sum((p - p.mean(0)) ** 2, axis=1)))) if len(p) else 0.0
              for p in (gt_traj.positions[i_gt], est_traj.positions[i_est])]
    if min(spread) <= 1e-3:
        return      # a trajectory that hardly moves has no scale to compare
    ratio = spread[1] / spread[0]
    if not any(abs(r / unit - 1) <= UNIT_RATIO_TOL for unit in UNIT_RATIOS for r in (ratio, 1 / ratio)):
        return
    logging.getLogger("phonepose").warning(
        "%s's positions spread %.3g m, %s's %.3g m (%.3gx): are both in metres? (--align sim3 "
        "estimates a scale)", est, spread[1], gt, spread[0], ratio)


def _warn_on_other_session(gt: Path, est: Path, in_view: Path | None) -> None:
    """One warning line when playback's session tags say the files come from different sessions."""
    from phonepose.evaluation.trajectory import read_session_tag

    tags = {p: read_session_tag(p) for p in (est, gt) + ((in_view,) if in_view is not None else ())}
    known = {p: t for p, t in tags.items() if t}
    if len({t.rsplit(" ", 1)[-1] for t in known.values()}) > 1:
        logging.getLogger("phonepose").warning(
            "these files come from different sessions (%s): the errors compare two recordings",
            "; ".join(f"{p}: {t}" for p, t in known.items()))


@app.command()
def evaluate(
    gt: Path = typer.Option(..., "--gt", help="Ground-truth trajectory file."),
    est: Path = typer.Option(..., "--est", help="Estimated trajectory file (TUM, or KITTI with --gt-format kitti)."),
    fmt: TrajectoryFormat = typer.Option(TrajectoryFormat.tum, "--gt-format", case_sensitive=False,
                                         help="GT format: tum | euroc (ASL csv; the estimate in TUM, or ASL csv if "
                                              "it ends in .csv) | kitti."),
    align: Align | None = typer.Option(None, "--align", case_sensitive=False,
                                          help="posyaw | se3 | sim3 | none (default: posyaw for rpg, none for "
                                               "ape/rpe as evo)."),
    align_frames: int = typer.Option(-1, "--align-frames", callback=number(1, integer=True, also=(-1,)),
                                     help="Align with the first N matched poses (-1: all)."),
    metric: Metric = typer.Option(Metric.rpg, "--metric", case_sensitive=False,
                                  help="rpg (ATE + RE) | ape | rpe (evo-compatible) | paper (p_ATE, r_ATE, p_RE "
                                       "inside / outside the view and the boundary jump; needs --in-view)."),
    in_view: Path | None = typer.Option(None, "--in-view", help="--metric paper: the in_view.txt playback wrote "
                                           "beside groundtruth.tum (timestamp, 0|1 per tick)."),
    delta: float = typer.Option(1.0, "--delta", callback=number(0, 1e9, lo_open=True), help="RPE delta."),
    delta_unit: DeltaUnit = typer.Option(DeltaUnit.f, "--delta-unit",
                                         help="RPE delta unit: f (frames) | m | d (deg) | r (rad)."),
    pose_relation: PoseRelation = typer.Option(PoseRelation.trans, "--pose-relation",
                                               help="APE/RPE relation: trans | angle (deg) | angle_rad | rot_part | "
                                                    "full."),
    lengths: str = typer.Option(None, "--lengths", help="RE sub-trajectory lengths in m, e.g. 1,2,5 "
                                "(default: 10,20,30,40,50 % of the GT path length)."),
    all_pairs: bool = typer.Option(False, "--all-pairs", help="RPE: all (overlapping) pairs instead of consecutive."),
    pairs_from_reference: bool = typer.Option(False, "--pairs-from-reference", help="RPE: pairs from the GT poses."),
    max_diff: float | None = typer.Option(None, "--max-diff", callback=number(0, SECONDS_MAX, lo_open=True, unit="s"),
                                             help="Association window in s (default: 0.02 strict for rpg, 0.01 for "
                                                  "ape/rpe)."),
    rpg_quirks: bool = typer.Option(False, "--rpg-quirks", help="Reproduce rpg's RE index shift and scale-error "
                                    "bugs bit for bit (default: the intended maths, see docs/evaluation.md)."),
    as_json: bool = typer.Option(False, "--json", help="Print machine-readable JSON."),
    gt_calibration: Path | None = typer.Option(None, "--gt-calibration",
                                                  help="A file from `phonepose calibrate-gt` (or calibrate-hand-eye): "
                                                  "move --gt onto the recorder's clock, the phone's frame and display_vio "
                                                  "first, as playback does (docs/calibration.md)."),
) -> None:
    """Compare an estimated trajectory with ground truth: ATE + RE (Zhang & Scaramuzza) or evo's APE/RPE.

    Example: [bold]phonepose evaluate --gt gt.csv --gt-format euroc --est est.tum --metric ape --align se3[/bold]
    """
    from phonepose.evaluation.evo_metrics import evaluate_ape, evaluate_rpe
    from phonepose.evaluation.rpg import evaluate_rpg
    from phonepose.evaluation.trajectory import load_trajectory
    from phonepose.files import check_input

    metric, fmt, delta_unit, pose_relation = metric.value, fmt.value, delta_unit.value, pose_relation.value
    align = align.value if align is not None else None
    lens = _parse_lengths(lengths)
    for path in (gt, est) + ((in_view,) if in_view is not None else ()):
        check_input(path, "trajectory file")    # a FIFO or device: refused, never opened
    gt_traj = load_trajectory(gt, fmt)
    if gt_calibration is not None:
        from phonepose.calibration.gt_calibration import load_gt_calibration
        from phonepose.evaluation.trajectory import Trajectory

        gt_traj = Trajectory(*load_gt_calibration(gt_calibration).apply(gt_traj.stamps, gt_traj.poses), gt_traj.source)
    est_fmt = "kitti" if fmt == "kitti" else ("euroc" if fmt == "euroc" and est.suffix.lower() == ".csv" else "tum")
    est_traj = load_trajectory(est, est_fmt)
    _warn_on_other_session(gt, est, in_view if metric == "paper" else None)
    _warn_on_small_overlap(gt, est, gt_traj, est_traj, 0.02 if max_diff is None else max_diff)
    _warn_on_other_unit(gt, est, gt_traj, est_traj, 0.02 if max_diff is None else max_diff, align)
    if metric == "paper":
        result = _paper(gt_traj, est_traj, in_view, 0.02 if max_diff is None else max_diff)
        if as_json:
            typer.echo(json.dumps(result, indent=2, allow_nan=False))
        else:
            from phonepose.cli.playback import metrics_table
            print_table(stdout_console(), metrics_table({"session": f"{est.name} vs {gt.name}", "rate_hz": None,
                                                           "trackers": {est.stem: result}}))
        return
    if metric == "rpg":
        result = evaluate_rpg(gt_traj, est_traj, align or "posyaw", align_frames, lens,
                              0.02 if max_diff is None else max_diff, index_shift_quirk=rpg_quirks,
                              scale_quirk=rpg_quirks)
    elif metric == "ape":
        result = evaluate_ape(gt_traj, est_traj, pose_relation, align or "none", align_frames,
                              0.01 if max_diff is None else max_diff)
    else:
        result = evaluate_rpe(gt_traj, est_traj, pose_relation, delta, delta_unit, all_pairs, pairs_from_reference,
                              0.1, align or "none", align_frames, 0.01 if max_diff is None else max_diff)
    _check_finite(result, gt, est)
    if as_json:
        typer.echo(json.dumps(result, indent=2, allow_nan=False))
        return
    _print_table(result, metric, gt, est)
