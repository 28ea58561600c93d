"""The API's verbs: record a simulated session, play a session through trackers, evaluate two trajectories,
calibrate. Each takes the options of its CLI command as keywords (same defaults, same checks, same
exception classes: phonepose.errors) and returns a typed result; heavy modules load when a verb is called.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from phonepose.api.results import Evaluation, PlaybackRun, TrackerMetrics, TrackerRun
from phonepose.errors import ConfigError
from phonepose.numbers import RATE_MAX_HZ, RATE_MIN_HZ, SECONDS_MAX, check_number

if TYPE_CHECKING:
    from phonepose.calibration.calibrate import CalibrationResult
    from phonepose.calibration.gt_calibration import GtCalibration
    from phonepose.calibration.hand_eye import HandEye
    from phonepose.evaluation.trajectory import Trajectory
    from phonepose.pipeline.types import Tracker
    from phonepose.record.recorder import RecordResult
    from phonepose.record.sim.config import SimConfig

PathLike = str | os.PathLike


def _path(value: PathLike | None) -> Path | None:
    return None if value is None else Path(value)


# ----------------------------------------------------------------------------- record
def record_sim(out: PathLike, *, scenario: str = "exp2", path: str = "TRI1", trial: int = 1, seed: int = 0,
               config: SimConfig | PathLike | None = None, overrides: dict | None = None,
               rerun: PathLike | None = None, spawn: bool = False, force: bool = False,
               motion: PathLike | None = None, motion_start: float = 0.0, motion_duration: float = 20.0,
               motion_scale: float = 1.0, motion_centre: Sequence[float] = (0.0, 0.03, 0.32),
               progress: Callable[[int, int | None], None] | None = None) -> RecordResult:
    """``phonepose record sim``: simulate the paper's setup and record it to ``out`` (.mcap).

    ``config``: a TOML file or a SimConfig (docs/simulation.md); ``overrides``: keys changed on top of it, in
    the TOML's nesting (``{"render": {"noise_sigma_dn": 0}}``). ``motion``: a recorded trajectory (TUM, or EuRoC
    .csv) as the task's motion, with its window options. ``progress(done_ns, total_ns)``: about every 0.1 s of
    session time. Returns the recorder's RecordResult (``path``, ``frames``, ``messages``, ``duration_ns``)."""
    from phonepose.record.sim import SimConfig, load_config
    from phonepose.record.sim import record_sim as run

    if rerun is not None and spawn:
        raise ConfigError("use either rerun=FILE or spawn=True, not both")
    spec = None
    if motion is not None:
        from phonepose.files import check_input
        from phonepose.record.sim.recorded import MotionSpec, load_window

        check_input(motion, "trajectory file")
        check_number("motion_start", motion_start, 0, SECONDS_MAX, unit="s")
        check_number("motion_duration", motion_duration, 1, 600, unit="s")
        check_number("motion_scale", motion_scale, 0, 10, lo_open=True)
        centre = tuple(motion_centre)
        if len(centre) != 3:
            raise ConfigError(f"motion_centre {motion_centre!r}: expected (x, y, z) in metres")
        for axis, v in zip("xyz", centre, strict=True):
            check_number(f"motion_centre {axis}", v, -1e3, 1e3, unit="m")
        check_number("motion_centre z", centre[2], 0.1, 3.0, unit="m (the distance from the camera)")
        spec = MotionSpec(os.fspath(motion), motion_start, motion_duration, motion_scale,
                          (float(centre[0]), float(centre[1]), float(centre[2])))
        load_window(spec)           # a bad file or window fails before anything is written
    config_file = None if config is None or isinstance(config, SimConfig) else config
    if isinstance(config, SimConfig):
        cfg = config.replace(**overrides) if overrides else config
    else:
        cfg = load_config(config_file, overrides)
    return run(out, scenario=scenario, path=path, trial=trial, seed=seed, config=cfg, config_file=config_file,
               progress=progress, rerun_path=rerun, spawn=spawn, force=force, motion=spec)


# ----------------------------------------------------------------------------- playback
def _trackers(trackers: Any, correction_math: str) -> list[Tracker]:
    """Names (CLI's rules: ``"all"``, ``"T4,T8"``, ``module:Class``, entry points) first, then tracker objects or
    classes in the order given, each checked and guarded as a ``module:Class`` one is."""
    # _user_tracker: the guard a module:Class tracker gets (docs/writing-a-tracker.md), for an object given here
    from phonepose.pipeline.trackers import (
        _class_name,
        _user_tracker,
        check_unique_names,
        make_trackers,
    )

    items = [trackers] if isinstance(trackers, str) or not isinstance(trackers, Iterable) else list(trackers)
    names = [t for t in items if isinstance(t, str)]
    objects = [t for t in items if not isinstance(t, str)]
    built = make_trackers(names, correction_math) if names or not objects else []
    for obj in objects:
        factory = obj if isinstance(obj, type) else (lambda obj=obj: obj)
        built.append(_user_tracker(_class_name(obj), factory))
    check_unique_names([t.name for t in built])
    return built


def play(session: PathLike, trackers: Any = "all", *, out: PathLike | None = None,
         correction_math: str = "paper", rate: float = 20.0, start: float | None = None, end: float | None = None,
         rerun: PathLike | None = None, spawn: bool = False, realtime: bool = False,
         gt_calibration: PathLike | GtCalibration | None = None, gt: PathLike | None = None,
         gt_format: str | None = None, progress: Callable[[int, int], None] | None = None) -> PlaybackRun:
    """``phonepose playback``: replay ``session`` through ``trackers`` at ``rate`` Hz and score them.

    ``trackers``: a name or a list of names (``"T4"``, ``"T4,T8"``, ``"paper"``, ``"all"``, ``"module:Class"``, an
    entry point) and/or tracker objects or classes (docs/writing-a-tracker.md); names first, then the objects.
    ``out``: also write the CLI's folder (trajectories, metrics.json, trackers.mcap) by its output rule;
    None plays in memory. ``gt_calibration``: a file from calibrate-gt or a GtCalibration; ``gt``: a
    trajectory file as the ground truth. ``progress(done, total)`` after every tick."""
    from phonepose.files import OutputPlan, check_input
    from phonepose.playback.engine import run_playback

    if rerun is not None and spawn:
        raise ConfigError("rerun and spawn are exclusive: give one")
    rate = check_number("rate", rate, RATE_MIN_HZ, RATE_MAX_HZ, unit="Hz")
    for name, value in (("start", start), ("end", end)):
        if value is not None:
            check_number(name, value, 0, SECONDS_MAX, unit="s")
    if start is not None and end is not None and end <= start:
        raise ConfigError(f"end ({end}) must be after start ({start})")
    built = _trackers(trackers, correction_math)   # unknown names fail here, before any work
    named = [(session, "session"), (gt_calibration if isinstance(gt_calibration, (str, os.PathLike)) else None,
                                    "calibration file"), (gt, "ground-truth file")]
    for p, what in named:
        if p is not None:
            check_input(p, what)   # a missing file, a FIFO or a device: one line, before any side effect
    options: dict[str, Any] = dict(
        trackers=["all"], tracker_factory=lambda _names, _math: built, rate_hz=rate, correction_math=correction_math,
        spawn=spawn, start_s=start, end_s=end, realtime=realtime, progress=progress, gt_calibration=gt_calibration,
        gt_file=gt, gt_format=gt_format)
    if out is None and rerun is None:
        result = run_playback(session, write_outputs=False, **options)
        folder = rrd_path = None
    else:
        # the CLI's output rule (phonepose.files): written under temporary names, put in place whole when complete
        plan = OutputPlan(inputs=[p for p, _ in named if p is not None])
        out_dir = plan.dir(out, "out", command="playback") if out is not None else None
        rrd = plan.file(rerun, "rerun", suffixes=(".rrd",), what="a Rerun recording") if rerun is not None else None
        with plan:
            result = run_playback(session, write_outputs=out_dir is not None,
                                  out_dir=out_dir.tmp if out_dir is not None else None,
                                  rerun_path=rrd.tmp if rrd is not None else None, **options)
        folder = out_dir.path if out_dir is not None else None
        rrd_path = rrd.path if rrd is not None else None
    doc = result.metrics
    runs = {}
    for name, m in doc["trackers"].items():
        typed = TrackerMetrics.from_json(name, m)
        runs[name] = TrackerRun(name, typed.inside, typed.outside, typed.total, _trajectories=result.trajectories)
    files = {k: os.fspath(folder / k) for k in result.files} if folder is not None else {}
    return PlaybackRun(session=doc["session"], rate_hz=rate, trackers=runs, ground_truth_note=doc.get("ground_truth"),
                       ground_truth=_ground_truth(result), n_ticks=result.n_ticks, n_task_ticks=result.n_task_ticks,
                       frames_decoded=result.frames_decoded, out=folder, rerun=rrd_path, wall_s=result.wall_s,
                       files=files)


def _ground_truth(result) -> Trajectory | None:
    from phonepose.evaluation.trajectory import Trajectory

    if not result.has_gt:
        return None
    return Trajectory(result.gt_stamps_ns / 1e9, result.gt, "groundtruth")


# ----------------------------------------------------------------------------- evaluate
def _trajectory(value: Any, fmt: str, what: str) -> tuple[Trajectory, Path]:
    """A Trajectory given, or one read from a file; and the name the CLI's lines use for it."""
    from phonepose.evaluation.trajectory import Trajectory, load_trajectory
    from phonepose.files import check_input

    if isinstance(value, Trajectory):
        return value, Path(value.source or what)
    if not isinstance(value, (str, os.PathLike)):
        raise ConfigError(f"{what}: expected a trajectory file or a phonepose.Trajectory, got {type(value).__name__}")
    check_input(value, "trajectory file")    # a FIFO or device: refused, never opened
    return load_trajectory(value, fmt), Path(value)


def evaluate(gt: PathLike | Trajectory, est: PathLike | Trajectory, *, metric: str = "rpg", fmt: str = "tum",
             align: str | None = None, align_frames: int = -1, in_view: PathLike | None = None, delta: float = 1.0,
             delta_unit: str = "f", pose_relation: str = "trans", lengths: Sequence[float] | None = None,
             all_pairs: bool = False, pairs_from_reference: bool = False, max_diff: float | None = None,
             rpg_quirks: bool = False, gt_calibration: PathLike | GtCalibration | None = None,
             ) -> Evaluation | TrackerMetrics:
    """``phonepose evaluate``: compare an estimate with ground truth, files or Trajectory objects.

    ``metric``: rpg (ATE + RE), ape, rpe (evo-compatible): an :class:`Evaluation`; paper (p_ATE, r_ATE, p_RE
    inside / outside the view, needs ``in_view``): a :class:`TrackerMetrics` named after the estimate. Defaults
    as the CLI (align posyaw for rpg, none for ape/rpe; max_diff 0.02 s for rpg and paper, 0.01 s for ape/rpe)."""
    # the command's checks and warnings, so that the API says the same lines
    from phonepose.cli import evaluate as cli
    from phonepose.cli.options import Align, DeltaUnit, Metric, PoseRelation, TrajectoryFormat
    from phonepose.evaluation.evo_metrics import evaluate_ape, evaluate_rpe
    from phonepose.evaluation.rpg import evaluate_rpg
    from phonepose.evaluation.trajectory import Trajectory

    metric, fmt, delta_unit, pose_relation = (_choice(n, v, c) for n, v, c in (
        ("metric", metric, Metric), ("fmt", fmt, TrajectoryFormat), ("delta_unit", delta_unit, DeltaUnit),
        ("pose_relation", pose_relation, PoseRelation)))
    align = _choice("align", align, Align) if align is not None else None
    check_number("align_frames", align_frames, 1, integer=True, also=(-1,))
    check_number("delta", delta, 0, 1e9, lo_open=True)
    if max_diff is not None:
        check_number("max_diff", max_diff, 0, SECONDS_MAX, lo_open=True, unit="s")
    lens = None
    if lengths is not None:
        lens = [float(check_number("lengths", v, 0, math.inf, lo_open=True, unit="m")) for v in lengths]
        if not lens:
            raise ConfigError("lengths: expected positive metres, e.g. [1, 2.5, 5]")
    gt_traj, gt_name = _trajectory(gt, fmt, "gt")
    if gt_calibration is not None:
        from phonepose.calibration.gt_calibration import GtCalibration, load_gt_calibration

        cal = gt_calibration if isinstance(gt_calibration, GtCalibration) else load_gt_calibration(gt_calibration)
        gt_traj = Trajectory(*cal.apply(gt_traj.stamps, gt_traj.poses), gt_traj.source)
    est_csv = isinstance(est, (str, os.PathLike)) and Path(est).suffix.lower() == ".csv"
    est_fmt = "kitti" if fmt == "kitti" else ("euroc" if fmt == "euroc" and est_csv else "tum")
    est_traj, est_name = _trajectory(est, est_fmt, "est")
    window = max_diff if max_diff is not None else 0.02
    if metric == "paper" and in_view is not None:
        from phonepose.files import check_input
        check_input(in_view, "trajectory file")
    if isinstance(gt, (str, os.PathLike)) and isinstance(est, (str, os.PathLike)):   # the files' session tags
        cli._warn_on_other_session(gt_name, est_name, _path(in_view) if metric == "paper" else None)
    cli._warn_on_small_overlap(gt_name, est_name, gt_traj, est_traj, window)
    cli._warn_on_other_unit(gt_name, est_name, gt_traj, est_traj, window, align)
    if metric == "paper":
        return TrackerMetrics.from_json(est_name.stem, cli._paper(gt_traj, est_traj, _path(in_view), window))
    if metric == "rpg":
        result = evaluate_rpg(gt_traj, est_traj, align or "posyaw", align_frames, lens, window,
                              index_shift_quirk=rpg_quirks, scale_quirk=rpg_quirks)
    elif metric == "ape":
        result = evaluate_ape(gt_traj, est_traj, pose_relation, align or "none", align_frames,
                              max_diff if max_diff is not None else 0.01)
    else:
        result = evaluate_rpe(gt_traj, est_traj, pose_relation, delta, delta_unit, all_pairs, pairs_from_reference,
                              0.1, align or "none", align_frames, max_diff if max_diff is not None else 0.01)
    cli._check_finite(result, gt_name, est_name)
    return Evaluation.from_json(metric, result)


def _choice(name: str, value: Any, choices: Any) -> str:
    """A choice option's value, checked against the CLI's enum (its values, case-insensitive as the CLI's)."""
    allowed = [c.value for c in choices]
    text = str(value)
    match = next((c for c in allowed if c.lower() == text.lower()), None)
    if match is None:
        raise ConfigError(f"{{{name}}} {value!r}: expected one of {', '.join(allowed)}", parameter=name, value=value,
                          expected=f"one of {', '.join(allowed)}")
    return match


# ----------------------------------------------------------------------------- calibrate
def calibrate_camera(*, images: PathLike | None = None, video: PathLike | None = None, device: int | None = None,
                     board: str | None = None, max_views: int = 40, min_corners: int = 8, seconds: float = 120.0,
                     size: tuple[int, int] | None = None, out: PathLike | None = None,
                     progress: Callable[[str], None] | None = None) -> CalibrationResult:
    """``phonepose calibrate-camera``: intrinsics and plumb_bob distortion from views of the ChArUco board
    (exactly one of ``images``, ``video``, ``device``); ``out``: also write the OpenCV YAML file."""
    from phonepose.calibration.board import parse_board_spec
    from phonepose.calibration.calibrate import calibrate_camera as run
    from phonepose.calibration.camera_file import OPENCV_FORMATS, OPENCV_WHAT, save_calibration
    from phonepose.cli.calibrate import DEFAULT_SPEC, MAX_CAMERA_INDEX
    from phonepose.files import check_output

    b = parse_board_spec(board if board is not None else DEFAULT_SPEC)
    if device is not None:
        check_number("device", device, 0, MAX_CAMERA_INDEX, integer=True)
    check_number("max_views", max_views, 1, 1000, integer=True)
    check_number("min_corners", min_corners, 4, 10_000, integer=True)
    check_number("seconds", seconds, 0, 24 * 3600, lo_open=True, unit="s")
    if size is not None:
        if device is None:
            raise ConfigError("size applies to device only (a video or photos have their own size)")
        if len(size) != 2:
            raise ConfigError(f"size {size!r}: expected (width, height) in pixels")
        for v in size:
            check_number("size", v, 1, 100_000, integer=True, unit="px")
    device_size = (int(size[0]), int(size[1])) if size is not None else None
    inputs = [Path(video)] if video is not None else []
    if out is not None:
        check_output(out, "out", inputs=inputs, suffixes=tuple(OPENCV_FORMATS), what=OPENCV_WHAT)
    result = run(images=_path(images), video=_path(video), device=device, board=b, max_views=max_views,
                 min_corners=min_corners, device_seconds=seconds, device_size=device_size, progress=progress)
    if out is not None:
        save_calibration(Path(out), result.to_file(), inputs=inputs)
    return result


def calibrate_gt(session: PathLike, *, gt: PathLike | None = None, gt_format: str | None = None,
                 max_offset: float = 0.5, bootstrap: int = 200, out: PathLike | None = None) -> GtCalibration:
    """``phonepose calibrate-gt``: the ground truth's clock offset, world and tracked body from one session's
    marker sightings; ``out``: also write the YAML file ``play(gt_calibration=...)`` reads (or pass the result)."""
    from phonepose.calibration.calibrate_gt import calibrate_gt_session
    from phonepose.calibration.ground_truth import gt_format_of
    from phonepose.calibration.gt_calibration import SUFFIXES, WHAT, save_gt_calibration
    from phonepose.files import check_input, check_output

    check_number("max_offset", max_offset, 0, 5, lo_open=True, unit="s")
    check_number("bootstrap", bootstrap, 0, 10_000, integer=True)
    check_input(session, "session")
    inputs = [session] + ([gt] if gt is not None else [])
    if gt is not None:
        check_input(gt, "ground-truth file")
        gt_format_of(gt, gt_format)
    elif gt_format is not None:
        raise ConfigError("gt_format applies to gt=FILE only")
    if out is not None:
        check_output(out, "out", inputs=inputs, suffixes=SUFFIXES, what=WHAT)
    cal = calibrate_gt_session(session, gt, gt_format=gt_format, max_offset_s=max_offset, bootstrap=bootstrap)
    if out is not None:
        save_gt_calibration(out, cal, inputs=inputs)
    return cal


def calibrate_hand_eye(session: PathLike, *, translation: Sequence[float] = (0.0, 0.0, 0.0),
                       out: PathLike | None = None) -> HandEye:
    """``phonepose calibrate-hand-eye``: the mocap rigid body's rotation against the phone and the mocap clock's
    offset (the rigid body's origin in the phone's frame, ``translation`` m, is measured, not estimated)."""
    from phonepose.calibration.gt_calibration import SUFFIXES, WHAT
    from phonepose.calibration.hand_eye import hand_eye_from_session, save_hand_eye
    from phonepose.files import check_input, check_output

    lever = list(translation)
    if len(lever) != 3:
        raise ConfigError(f"translation {translation!r}: expected x, y, z in metres")
    for v in lever:
        check_number("translation", v, -1, 1, unit="m")
    check_input(session, "session")
    if out is not None:
        check_output(out, "out", inputs=[session], suffixes=SUFFIXES, what=WHAT)
    he = hand_eye_from_session(Path(session), translation=[float(v) for v in lever])
    if out is not None:
        save_hand_eye(Path(out), he, inputs=[session], session=Path(session).name)
    return he


def tracker_names() -> list[str]:
    """The built-in trackers (T1-T7, then ours): what ``"all"`` plays."""
    from phonepose.pipeline.trackers import tracker_names as names

    return names()
