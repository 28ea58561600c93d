"""The playback engine: ticks → shared stages (once) → every tracker → outputs.

    result = run_playback("s.mcap", trackers=["all"], out_dir="out", rerun_path="out/s.rrd")
    result = run_playback("s.mcap", PlaybackOptions(trackers=["T1", "T8"], write_outputs=False))

Per tick the shared stages run once (decode, marker recognition, anchor mapping) and every
tracker steps on the same Observation. The engine records per tracker ``(t, pose or None,
in_view)`` and the associated ground truth, then writes (docs/playback.md):

* ``DIR/trajectories/<tracker>.tum``: ticks inside the task window where the tracker has a pose,
  display_vio frame, TUM format;
* ``DIR/groundtruth.tum``: the associated GT at the task-window ticks (display_vio);
* ``DIR/in_view.txt``: at those ticks, whether the marker was recognised (for ``evaluate --metric paper``);
* ``DIR/metrics.json``: per tracker p_ATE / r_ATE / p_RE inside / outside the FoV and total
  (``null`` where not computable, e.g. no GT);
* ``DIR/errors.csv``: per tracker and tick the position and rotation error the metrics are computed from;
* ``DIR/trackers.mcap``: ``/pipeline/markers`` (per new camera frame), ``/trackers/<name>/pose`` and
  ``/tf/trackers`` (each estimate as a FrameTransform, child ``tracker/<name>``).

Nothing depends on the wall clock unless ``realtime`` paces the ticks.
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from phonepose.calibration.gt_calibration import GroundTruthSetup, ground_truth_setup
from phonepose.errors import ConfigError, OutputError, SessionContentError, TrackerError
from phonepose.evaluation.controller import controller_metrics
from phonepose.evaluation.trajectory import write_in_view, write_tum
from phonepose.geometry import Pose
from phonepose.pipeline.corrections import CorrectionMath
from phonepose.pipeline.shared import SharedStages, warn_damaged, warn_wrong_size
from phonepose.pipeline.trackers import NAME_RULE, check_unique_names, is_safe_name, make_trackers, split_names
from phonepose.pipeline.types import Observation, SessionContext, Stages, Tick, Tracker
from phonepose.playback.collector import TrackerTrajectory, Trajectories, TrajectoryCollector
from phonepose.playback.outputs import (
    detections_message,
    metrics_document,
    paper_metrics,
    write_errors,
    write_metrics,
)
from phonepose.playback.scheduler import DEFAULT_RATE_HZ, TickScheduler
from phonepose.playback.watchdog import StepTimeout, StepWatchdog
from phonepose.schemas.topics import Frame, Topic, tracker_pose_topic
from phonepose.session import SessionReader, SessionWriter
from phonepose.session.codec import frame_transform, pose_in_frame
from phonepose.session.context import has_camera, read_context, session_tag
from phonepose.topics import tracker_frame
from phonepose.viewer.annotations import marker_annotations

if TYPE_CHECKING:
    from phonepose.playback.rerun_log import PlaybackRerunLogger  # imported when used: rerun-sdk costs ~0.3 s

log = logging.getLogger("phonepose")


@dataclass
class PlaybackResult:
    session: str
    out_dir: Path | None
    rate_hz: float
    n_ticks: int                          # ticks played
    n_task_ticks: int                     # of which inside the task window
    frames_decoded: int                   # camera frames the shared stages decoded
    trajectories: Mapping[str, TrackerTrajectory]   # each read from its spill file when looked up
    gt_stamps_ns: np.ndarray              # task-window ticks with associated GT
    gt: Pose | None                       # GT controller pose in display_vio at those ticks
    metrics: dict                         # the metrics.json document
    rerun_path: str | None = None
    wall_s: float = 0.0
    files: dict[str, str] = field(default_factory=dict)

    @property
    def has_gt(self) -> bool:
        return self.gt is not None and len(self.gt_stamps_ns) > 0


def _default_stages(context: SessionContext) -> Stages:
    return SharedStages(context)


def _default_trackers(names: list[str], correction_math: str) -> list[Tracker]:
    return make_trackers(names, correction_math)


def _check_camera_trackers(session: str, context: SessionContext, trackers: list[Tracker]) -> None:
    """A session without camera images cannot run marker-based trackers: say so instead of reporting VIO as them."""
    if has_camera(context):
        return
    need = [t.name for t in trackers if t.needs_camera]
    if need:
        able = [t.name for t in trackers if not t.needs_camera]
        raise SessionContentError(
            f"{session}: no camera images ({Topic.CAMERA_IMAGE}): {', '.join(need)} need the camera"
            + (f"; run the VIO-only trackers with {' '.join('-t ' + n for n in able)}" if able else
               "; choose VIO-only trackers (T1, T2)"))


def default_out_dir(session: str | os.PathLike) -> Path:
    return Path(f"playback-{Path(session).stem}")


def _prepare_out_dir(out_dir: Path) -> None:
    try:
        (out_dir / "trajectories").mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create output directory {out_dir}: {exc.strerror or exc}") from None
    if not os.access(out_dir, os.W_OK) or not os.access(out_dir / "trajectories", os.W_OK):
        raise OutputError(f"output directory {out_dir} is not writable")


class PlaybackEngine:
    """Drive one session through the shared stages and trackers, tick by tick."""

    def __init__(self, context: SessionContext, stages: Stages, trackers: list[Tracker], *,
                 writer: SessionWriter | None = None, rerun_logger: PlaybackRerunLogger | None = None):
        # make_trackers checks both (a user's tracker when it is loaded); a tracker_factory may not
        unsafe = [t for t in trackers if not is_safe_name(t.name)]
        if unsafe:   # a name is a file name below: trajectories/<name>.tum
            raise ConfigError(f"tracker {type(unsafe[0]).__name__} is named {unsafe[0].name!r}: a tracker's name is "
                              f"{NAME_RULE}")
        check_unique_names([t.name for t in trackers])
        self.context = context
        self.stages = stages
        self.trackers = trackers
        self.writer = writer
        self.rerun_logger = rerun_logger
        self.watchdog: StepWatchdog | None = None      # bounds each tracker step (playback --tick-timeout)
        self.collectors = {t.name: TrajectoryCollector() for t in trackers}
        self._topics = {t.name: tracker_pose_topic(t.name) for t in trackers}
        self.gt = TrajectoryCollector()
        self.n_ticks = 0
        self.n_task_ticks = 0
        for t in trackers:
            t.reset()

    def step(self, tick: Tick, gt: Pose | None = None) -> tuple[Observation, dict[str, Pose | None]]:
        """One tick through the stages and every tracker; ``gt`` (beside the tick) goes to the metrics only."""
        obs = self.stages.process(tick)
        if self.watchdog is None:
            poses = {tr.name: tr.step(obs) for tr in self.trackers}
        else:
            poses = {tr.name: self._watched_step(tr, obs, tick.index) for tr in self.trackers}
        self.n_ticks += 1
        if tick.in_task:
            self.n_task_ticks += 1
            inside = obs.in_view
            for name, pose in poses.items():
                self.collectors[name].add(tick.t_ns, pose, inside)
            self.gt.add(tick.t_ns, gt, inside)
        if self.writer is not None:
            self._write(tick, obs, poses)
        if self.rerun_logger is not None:
            self.rerun_logger.log_tick(tick, obs, poses, gt)
        return obs, poses

    def _watched_step(self, tracker: Tracker, obs: Observation, tick: int) -> Pose | None:
        """A step under the watchdog's bound: one past it is the tracker's error (exit 5), naming it and the tick."""
        assert self.watchdog is not None
        ref = getattr(tracker, "ref", None)     # a user's tracker: how it was given (-t module:Class)
        who = f"tracker {ref!r} ({tracker.name})" if ref is not None else f"tracker {tracker.name}"
        self.watchdog.arm(who, tick)
        try:
            return tracker.step(obs)
        except StepTimeout as exc:
            raise TrackerError(str(exc), tracker.name, parameter="tick_timeout",
                               value=self.watchdog.timeout_s) from None
        finally:
            self.watchdog.disarm()

    def _write(self, tick: Tick, obs: Observation, poses: dict[str, Pose | None]) -> None:
        assert self.writer is not None
        if tick.new_frame is not None:
            self.writer.write(Topic.PIPELINE_MARKERS, detections_message(obs), tick.t_ns)
            self.writer.write(Topic.PIPELINE_MARKER_ANNOTATIONS, marker_annotations(obs), tick.t_ns)
        encoded: dict[int, tuple] = {}   # trackers often return the very same Pose object (e.g. the marker's)
        for name, pose in poses.items():
            if pose is not None:
                hit = encoded.get(id(pose))
                if hit is None:
                    msg = pose_in_frame(pose, Frame.DISPLAY_VIO, tick.t_ns)
                    hit = encoded[id(pose)] = (msg, msg.SerializeToString())
                self.writer.write_bytes(self._topics[name], hit[0], hit[1], tick.t_ns)
                # the same estimate as a frame, so Foxglove's 3D panel draws every tracker's axes
                self.writer.write(Topic.TF_TRACKERS, frame_transform(pose, Frame.DISPLAY_VIO, tracker_frame(name),
                                                                     tick.t_ns), tick.t_ns)

    def trajectories(self) -> Trajectories:
        """Every tracker's trajectory, each read back from its collector when looked up."""
        return Trajectories(self.collectors)

    def metrics(self, trajectories: Mapping[str, TrackerTrajectory] | None = None,
                gt: tuple[np.ndarray, Pose | None] | None = None) -> dict[str, dict]:
        """Per tracker, over the task-window ticks where both the tracker and the GT have a pose
        (``trajectories``: those of :meth:`trajectories` when the caller has them already; ``gt``:
        the GT's stamps and poses, likewise). One tracker's trajectory is in memory at a time."""
        gt_t, gt_poses = gt if gt is not None else (self.gt.stamps(), self.gt.poses())
        out = {}
        trajs = trajectories if trajectories is not None else self.trajectories()
        for name in trajs:
            traj = trajs[name]
            if gt_poses is None or traj.poses is None:
                out[name] = paper_metrics(np.zeros(0), None, None, np.zeros(0, bool))
                continue
            common, i_est, i_gt = np.intersect1d(traj.stamps_ns, gt_t, assume_unique=True, return_indices=True)
            if common.size == 0:
                out[name] = paper_metrics(np.zeros(0), None, None, np.zeros(0, bool))
                continue
            stamps_s = common / 1e9
            # a tracker with a pose at every GT tick (the usual case) is associated one to one: no copies
            whole = common.size == len(gt_t) == len(traj.stamps_ns)
            out[name] = paper_metrics(stamps_s, gt_poses if whole else gt_poses[i_gt],
                                      traj.poses if whole else traj.poses[i_est], traj.inside[i_est])
            out[name]["total"].update(controller_metrics(gt_t / 1e9, gt_poses, traj.stamps_ns / 1e9, traj.poses,
                                                         stamps_s, i_gt, i_est))
            del traj
        return out


@dataclass(frozen=True)
class PlaybackOptions:
    """Everything a playback can be asked (the CLI's options; ``run_playback(session, **options)`` also works).

    ``progress(done, total)`` is called after every tick. ``rerun_path`` saves a .rrd (with the
    default blueprint); ``spawn`` streams to a new viewer instead. ``write_outputs=False`` keeps
    everything in memory (no files, no trackers.mcap). ``stages_factory``/``tracker_factory``
    replace the pipeline's SharedStages / make_trackers (tests, experiments). ``gt_calibration`` is a
    file from ``phonepose calibrate-gt`` or ``calibrate-hand-eye``: the
    ground truth is moved into the phone's frame, clock and display_vio before any metric
    (docs/calibration.md); metrics.json names it ``gt_calibration_name`` if given (an experiment's file,
    read from the folder before it is renamed into place). ``gt_file`` (TUM or EuRoC, ``gt_format``)
    replaces the session's ground truth (phonepose.calibration.ground_truth).
    """

    trackers: Iterable[str] | str = ("all",)
    out_dir: str | os.PathLike | None = None
    rate_hz: float = DEFAULT_RATE_HZ
    correction_math: str = "paper"
    rerun_path: str | os.PathLike | None = None
    spawn: bool = False
    start_s: float | None = None
    end_s: float | None = None
    realtime: bool = False
    progress: Callable[[int, int], None] | None = None
    write_outputs: bool = True
    stages_factory: Callable[[SessionContext], Stages] | None = None
    tracker_factory: Callable[[list[str], str], list[Tracker]] | None = None
    gt_calibration: Any = None            # a file (str | PathLike) or a GtCalibration in memory
    gt_calibration_name: str | None = None
    gt_file: str | os.PathLike | None = None
    gt_format: str | None = None
    tick_timeout_s: float | None = None    # each tracker step at most this long (phonepose.playback.watchdog)


def _ground_truth(options: PlaybackOptions) -> GroundTruthSetup:
    """The GT calibration and sidecar ground truth to apply."""
    o = options
    return ground_truth_setup(o.gt_calibration, o.gt_calibration_name, o.gt_file, o.gt_format)


def _make_trackers(options: PlaybackOptions) -> tuple[list[Tracker], str]:
    names = split_names(options.trackers)   # --tracker T4,T8 or --tracker T4 --tracker T8
    math = CorrectionMath.parse(options.correction_math).value
    return (options.tracker_factory or _default_trackers)(names, math), math


def _rerun_logger(options: PlaybackOptions, session: str, context: SessionContext, names: list[str],
                  math: str, gt_setup: GroundTruthSetup, start_ns: int) -> PlaybackRerunLogger | None:
    if options.rerun_path is None and not options.spawn:
        return None
    from phonepose.playback.rerun_log import PlaybackRerunLogger
    return PlaybackRerunLogger(context, names, session=session,
                               params={"rate_hz": options.rate_hz, "correction_math": math, "start_s": options.start_s,
                                       "end_s": options.end_s, "hand_eye": gt_setup.calibration_path,
                                       **gt_setup.rerun_params},
                               rrd_path=options.rerun_path, spawn=options.spawn, session_start_ns=start_ns)


# Ticks whose recognition runs ahead of the trackers (SharedStages.prefetch): enough to keep the
# worker busy while the main thread steps the trackers and writes a tick, few enough to hold no
# memory (a tick is its frame's JPEG bytes and a few poses).
LOOKAHEAD_TICKS = 3


def _ticks_ahead(ticks: Iterable[tuple[Tick, Pose | None]], stages: Stages) -> Iterator[tuple[Tick, Pose | None]]:
    """``ticks`` unchanged, with each one's recognition started ``LOOKAHEAD_TICKS`` ticks before it
    is yielded (when the stages can: ``prefetch``); the same ticks otherwise."""
    prefetch = getattr(stages, "prefetch", None)
    if prefetch is None:
        yield from ticks
        return
    queue: deque[tuple[Tick, Pose | None]] = deque()
    for item in ticks:
        prefetch(item[0])
        queue.append(item)
        if len(queue) > LOOKAHEAD_TICKS:
            yield queue.popleft()
    while queue:
        yield queue.popleft()


def _play(scheduler: TickScheduler, engine: PlaybackEngine, options: PlaybackOptions) -> None:
    total = len(scheduler)
    pace0 = None
    ticks = scheduler.with_truth() if options.realtime else _ticks_ahead(scheduler.with_truth(), engine.stages)
    for tick, gt in ticks:
        if options.realtime:
            if pace0 is None:
                pace0 = (time.monotonic(), tick.t_ns)
            delay = pace0[0] + (tick.t_ns - pace0[1]) / 1e9 - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        engine.step(tick, gt)
        if options.progress is not None:
            options.progress(engine.n_ticks, total)


def _write_files(out: Path, trajs: Mapping[str, TrackerTrajectory], gt_stamps: np.ndarray, gt: Pose | None,
                 gt_inside: np.ndarray, files: dict[str, str], tag: str | None) -> None:
    for name in trajs:
        traj = trajs[name]     # one at a time: read from its spill file, written, dropped
        p = out / "trajectories" / f"{name}.tum"
        write_tum(p, traj.stamps_ns, traj.poses, session=tag)
        files[f"trajectories/{name}.tum"] = str(p)
        del traj
    if gt is not None:
        write_tum(out / "groundtruth.tum", gt_stamps, gt, session=tag)
        files["groundtruth.tum"] = str(out / "groundtruth.tum")
        write_in_view(out / "in_view.txt", gt_stamps, gt_inside, session=tag)
        files["in_view.txt"] = str(out / "in_view.txt")


def run_playback(session: str | os.PathLike, options: PlaybackOptions | None = None, **kwargs: Any) -> PlaybackResult:
    """Play ``session`` back and write the outputs (:class:`PlaybackOptions`, given whole or as keywords).

    Everything that can be refused is checked before the first side effect: tracker names,
    correction math, the hand-eye file, the session and its content (camera for the trackers that
    need it, --rate/--start/--end); only then are the output folder, trackers.mcap and the Rerun
    sink opened, and an ``ExitStack`` closes whatever was opened, however the ticks end.
    """
    if options is None:
        options = PlaybackOptions(**kwargs)
    elif kwargs:
        options = replace(options, **kwargs)
    wall0 = time.perf_counter()
    tracker_objs, math = _make_trackers(options)
    gt_setup = _ground_truth(options)
    gt_note = gt_setup.note
    session = os.fspath(session)
    out = None
    if options.write_outputs:
        out = Path(options.out_dir) if options.out_dir is not None else default_out_dir(session)
    files: dict[str, str] = {}
    with contextlib.ExitStack() as stack:
        reader = stack.enter_context(SessionReader(session))
        context = read_context(reader)
        _check_camera_trackers(session, context, tracker_objs)
        scheduler = TickScheduler(reader, context, rate_hz=options.rate_hz, start_s=options.start_s,
                                  end_s=options.end_s, gt_calibration=gt_setup.calibration,
                                  gt_series=gt_setup.series)
        stages = (options.stages_factory or _default_stages)(context)
        stages.map_vio_samples = any(t.uses_vio_samples for t in tracker_objs)
        if hasattr(stages, "close"):
            stack.callback(stages.close)   # the look-ahead's worker thread
        engine = PlaybackEngine(context, stages, tracker_objs)   # refuses a tracker named twice
        if options.tick_timeout_s is not None:
            engine.watchdog = StepWatchdog(options.tick_timeout_s)
            stack.callback(engine.watchdog.close)
        # side effects from here on: the Rerun sink first (a --rerun path that cannot be written fails
        # before any file is opened), then the output folder and trackers.mcap
        engine.rerun_logger = _rerun_logger(options, session, context, [t.name for t in tracker_objs], math, gt_setup,
                                            scheduler.span_ns[0])
        if engine.rerun_logger is not None:
            stack.callback(engine.rerun_logger.close)
        if out is not None:
            _prepare_out_dir(out)
            files["trackers.mcap"] = str(out / "trackers.mcap")
            engine.writer = SessionWriter(out / "trackers.mcap")
            stack.callback(engine.writer.finish)
        _play(scheduler, engine, options)
        trajs = engine.trajectories()
        gt_stamps, gt_poses = engine.gt.stamps(), engine.gt.poses()
        per_tracker = engine.metrics(trajs, (gt_stamps, gt_poses))
        if engine.rerun_logger is not None:   # the recording's metrics panel: before its sink closes
            engine.rerun_logger.log_metrics(metrics_document(Path(session).name, options.rate_hz, per_tracker,
                                                             ground_truth=gt_note))
    if context.session_id is None:    # e.g. a session cut by a tool that keeps only some topics
        log.warning("%s: no %s, so no task window: the metrics cover the whole session",
                    session, Topic.SESSION_INFO)
    if stages.frames_undecodable:
        log.warning("%s: %d camera frame(s) could not be decoded; they count as showing no marker",
                    Topic.CAMERA_IMAGE, stages.frames_undecodable)
    warn_wrong_size(stages.frames_wrong_size, stages.wrong_size)
    warn_damaged(stages.frames_damaged, stages.damaged)
    session_name = Path(session).name
    metrics_doc = metrics_document(session_name, options.rate_hz, per_tracker, ground_truth=gt_note)
    if out is not None:
        _write_files(out, trajs, gt_stamps, gt_poses, engine.gt.inside(), files, session_tag(session, context))
        metrics_doc = write_metrics(out / "metrics.json", session_name, options.rate_hz, per_tracker,
                                    ground_truth=gt_note)
        files["metrics.json"] = str(out / "metrics.json")
        if gt_poses is not None:
            write_errors(out / "errors.csv", trajs, gt_stamps, gt_poses)
            files["errors.csv"] = str(out / "errors.csv")
    rerun_path = options.rerun_path
    return PlaybackResult(
        session=session, out_dir=out, rate_hz=options.rate_hz, n_ticks=engine.n_ticks,
        n_task_ticks=engine.n_task_ticks, frames_decoded=int(stages.frames_decoded), trajectories=trajs,
        gt_stamps_ns=gt_stamps, gt=gt_poses, metrics=metrics_doc,
        rerun_path=os.fspath(rerun_path) if rerun_path is not None else None,
        wall_s=time.perf_counter() - wall0, files=files,
    )
