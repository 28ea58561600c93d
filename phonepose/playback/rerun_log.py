"""Rerun logging of a playback: one logger per stage, each owning its entity paths.

The engine owns the clock: :class:`PlaybackRerunLogger` sets the timelines ``session_time``
(duration since the session's first message, the blueprint's), ``tick`` (sequence) and ``time``
(timestamp, display clock) once per tick, then every stage logger logs its part.
A stage with nothing to show clears its path (``rr.Clear``) so the viewer never shows a stale
marker or pose. Entity paths, colours and the sink are those of :mod:`phonepose.viewer`
(docs/playback.md, "Rerun", shows the tree and the layout).

A recording reads without the docs: its id is derived from the session's content and the
playback's parameters (two different runs never merge in the viewer, the same run twice gives
the same id), its name says session, trackers and rate; every tracker has one colour on its
pose's axes, its dot, its trajectory and its error series, and the metrics panel (the table of
metrics.json, static) names the colours; errors are in cm and degrees over the task window, as
the tables are; the task window and the marker's in/out of view are lanes of a state timeline;
the 3D view is framed on the display camera and the task, and stays put; the camera image is
drawn in the 2D camera view only (the 3D view shows the camera's frustum out to the working depth).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from phonepose import __version__
from phonepose.evaluation.ate import rotation_errors_deg, translation_errors
from phonepose.geometry import Pose
from phonepose.pipeline.types import Observation, SessionContext, Tick
from phonepose.viewer import entities as E
from phonepose.viewer.scene import WORKING_DEPTH_M, log_camera, log_task
from phonepose.viewer.sink import (
    Columns,
    close_recording,
    open_recording,
    time_columns,
    transform_columns,
)
from phonepose.viewer.style import (
    GT_COLOR,
    MARKER_COLOR,
    TASK_COLOR,
    color_name,
    line_width,
    tracker_color,
)

APPLICATION_ID = "phonepose_playback"
TRAJECTORY_EVERY_TICKS = 20   # trajectories so far are re-logged every 20 ticks (1 s at 20 Hz)
SEGMENT_TICKS = 100           # ... and closed for good every 100 ticks (the size stays linear)
# Buffered rows (images, poses, errors, markers) are sent as columns every this many ticks: to a
# .rrd file in large batches (each send_columns has a fixed cost), to a live viewer promptly.
COLUMNS_EVERY_TICKS_FILE = 100
COLUMNS_EVERY_TICKS_LIVE = 5
BLUEPRINT_WAIT_TICKS = 20     # the 3D eye is framed on the display camera: wait this long for its pose
AXIS_LENGTH_M = 0.05
AXIS_RADIUS_M = 0.0012
DOT_RADIUS_M = 0.006          # the dot at each estimate, in its tracker's colour
TRAJECTORY_RADIUS_M = 0.0015
GT_TRAJECTORY_RADIUS_M = 0.003

# state timeline lanes: value -> (label, colour)
TASK_STATES = {"calibration": ("calibration (before the task)", (128, 128, 128)),
               "task": ("task (metrics window)", TASK_COLOR),
               "after": ("after the task", (128, 128, 128))}
MARKER_STATES = {"in_view": ("marker in view", MARKER_COLOR), "out_of_view": ("marker out of view", (214, 39, 40))}


# ------------------------------------------------------------------ recording id and name
def session_fingerprint(path: str | os.PathLike) -> str:
    """A digest of the session's content, cheap for any size: the MCAP summary section (every
    chunk's offset, size and time range, the schemas, channels and message counts) and the file
    size; the whole file for a file without a summary. The summary is a few kB whatever the
    session's size."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        size = f.seek(0, os.SEEK_END)
        h.update(size.to_bytes(8, "little"))
        summary_start = 0
        if size >= 8 + 29 + 8:          # magic, footer record (opcode, length, 20 bytes), magic
            f.seek(size - 8 - 29)
            footer = f.read(29)
            if footer[0] == 0x02:
                summary_start = int.from_bytes(footer[9:17], "little")
        if 0 < summary_start < size:
            f.seek(summary_start)
            h.update(f.read())
        else:
            f.seek(0)
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()


def recording_id(session: str | os.PathLike, params: dict) -> str:
    """``playback-<stem>-<16 hex>``: from the session's content and the playback's parameters
    (``params``: anything that changes the result, e.g. trackers, rate, window, correction math;
    a value naming a file, key ``hand_eye``, counts by its content)."""
    p = dict(params)
    if p.get("hand_eye") is not None:
        p["hand_eye"] = hashlib.sha256(Path(p["hand_eye"]).read_bytes()).hexdigest()
    doc = json.dumps({"session": session_fingerprint(session), "params": p, "phonepose": __version__},
                     sort_keys=True, default=str)
    stem = re.sub(r"[^A-Za-z0-9_-]+", "_", Path(session).stem)[:60]
    return f"playback-{stem}-{hashlib.sha256(doc.encode()).hexdigest()[:16]}"


def recording_name(session: str | os.PathLike, tracker_names: list[str], params: dict) -> str:
    """What the viewer's sources panel shows: ``TRI2_01.mcap · T1 T2 ... T8 · 20 Hz`` (+ options set)."""
    parts = [Path(session).name, " ".join(tracker_names)]
    if params.get("rate_hz") is not None:
        parts.append(f"{params['rate_hz']:g} Hz")
    if params.get("correction_math") not in (None, "paper"):
        parts.append(f"{params['correction_math']} correction")
    if params.get("start_s") is not None or params.get("end_s") is not None:
        parts.append(f"window {params.get('start_s') or 0:g}-{params.get('end_s') or 'end'} s")
    if params.get("hand_eye") is not None:
        parts.append(f"hand-eye {Path(params['hand_eye']).name}")
    return " · ".join(parts)


# ------------------------------------------------------------------ blueprint
def _eye(context: SessionContext, camera_position: np.ndarray | None) -> rrb.EyeControls3D | None:
    """An orbit eye on the task, from behind, above and beside the display camera, so the camera
    frustum, the task and every trajectory are in view; fixed, so scrubbing does not move it."""
    path, targets = context.path, context.targets
    points: list = []
    if path is not None and len(path.waypoints):
        points = list(path.waypoints)
    elif targets is not None and len(targets.targets):
        points = [t.position for t in targets.targets]
    if not points or camera_position is None:
        return None
    pts = np.asarray(points, dtype=float)
    task_center = (pts.min(axis=0) + pts.max(axis=0)) / 2
    camera = np.asarray(camera_position, dtype=float).reshape(3)
    v = camera - task_center                      # from the task to the camera
    dist = max(float(np.linalg.norm(v)), 0.2)
    center = task_center + 0.35 * v               # between the two: both in view
    up = np.array([0.0, 0.0, 1.0])
    side = np.cross(up, v)
    side = side / np.linalg.norm(side) if np.linalg.norm(side) > 1e-9 else np.array([1.0, 0.0, 0.0])
    eye = center + v * 0.9 + up * (0.45 * dist) + side * (0.55 * dist)
    return rrb.EyeControls3D(position=eye.tolist(), look_target=center.tolist(), eye_up=up.tolist())


def default_blueprint(tracker_names: list[str], context: SessionContext | None = None,
                      camera_position: np.ndarray | None = None, start_ns: int = 0) -> rrb.Blueprint:
    """3D scene | camera image over the state timeline; the two error plots and the metrics table
    along the bottom.

    Every tracker is in both plots (a comparison needs one axis), each series in its tracker's
    colour, ours (T7L, T8) drawn thicker; the plots are tall enough (a third of the window's
    height) that the legend lists all nine trackers, the table wide enough for its ten columns. The 3D
    view draws the camera's frustum but not its image (an opaque plane in front of the scene);
    the image is the 2D view's. Times are on ``session_time`` (``start_ns``: the session's start).
    """
    eye = _eye(context, camera_position) if context is not None else None
    task = None
    if context is not None and context.task_start_ns is not None and context.task_end_ns is not None:
        task = (int(context.task_start_ns) - int(start_ns), int(context.task_end_ns) - int(start_ns))
    axis_x = None
    if task is not None:
        axis_x = rrb.TimeAxis(view_range=rrb.TimeRange(start=rrb.TimeRangeBoundary.absolute(nanos=task[0]),
                                                                  end=rrb.TimeRangeBoundary.absolute(nanos=task[1])))
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(
                rrb.Spatial3DView(name="3D (display_vio): GT grey, task teal, trackers in colour", origin=E.WORLD,
                                  eye_controls=eye,
                                  # the camera entity's Pinhole only: its frustum, not the image
                                  overrides={E.IMAGE: rr.Pinhole.from_fields().visualizer()}),
                rrb.Vertical(
                    rrb.Spatial2DView(name="display camera", origin=E.IMAGE),
                    rrb.StateTimelineView(name="task window · marker in view", origin=E.STATUS),
                    row_shares=[5, 2],
                ),
                column_shares=[3, 2],
            ),
            rrb.Horizontal(
                rrb.TimeSeriesView(name="position error vs GT (cm)", origin=E.POSITION_ERRORS,
                                   plot_legend=rrb.PlotLegend(corner="LeftTop"), axis_x=axis_x),
                rrb.TimeSeriesView(name="rotation error vs GT (deg)", origin=E.ROTATION_ERRORS,
                                   plot_legend=rrb.PlotLegend(corner="LeftTop"), axis_x=axis_x),
                rrb.TextDocumentView(name="metrics (metrics.json) · colours", origin=E.METRICS),
                column_shares=[3, 3, 4],
            ),
            row_shares=[3, 2],
        ),
        rrb.TimePanel(timeline=E.SESSION_TIME, state="collapsed",
                      time_selection=rrb.components.AbsoluteTimeRange(*task) if task is not None else None),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
    )


# ------------------------------------------------------------------ the metrics panel
# (column header, metric key, scope, factor to the shown unit)
METRIC_COLUMNS = [(f"{head} {scope_head}", key, scope, factor)
                  for head, key, factor in (("p", "p_ate_m", 100.0), ("r", "r_ate_deg", 1.0), ("RE", "p_re_m", 100.0))
                  for scope_head, scope in (("in", "inside"), ("out", "outside"), ("all", "total"))]


def metrics_markdown(metrics: dict) -> str:
    """The metrics.json document as a markdown table: a row per tracker with its colour, p_ATE and
    p_RE in cm and r_ATE in degrees inside / outside the marker's view and in total; the best
    (smallest) value of each column in bold, ``–`` where metrics.json has ``null``."""
    trackers: dict[str, dict] = metrics.get("trackers", {})
    best = {}
    for _, key, scope, _f in METRIC_COLUMNS:
        values = [m[scope][key] for m in trackers.values() if m.get(scope, {}).get(key) is not None]
        best[(key, scope)] = min(values) if values else None
    lines = [f"**{metrics.get('session', '')}** · {metrics.get('rate_hz', '')} Hz · p: p_ATE (cm), r: r_ATE (deg), "
             "RE: p_RE (cm); in / out: marker in / out of view; **bold**: the best of the column", "",
             "| tracker | colour | " + " | ".join(h for h, *_ in METRIC_COLUMNS) + " |",
             "|---|---|" + "---:|" * len(METRIC_COLUMNS)]
    for name, m in trackers.items():
        cells = []
        for _, key, scope, factor in METRIC_COLUMNS:
            v = m.get(scope, {}).get(key)
            text = "–" if v is None else f"{v * factor:.2f}"
            cells.append(f"**{text}**" if v is not None and v == best[(key, scope)] else text)
        lines.append(f"| {name} | {color_name(name)} | " + " | ".join(cells) + " |")
    lines += ["", "Ground truth: grey (thicker); the task: teal."]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------ stage loggers
class CameraLogger:
    """Display pose, camera (static Pinhole), the recorded JPEG bytes (buffered, sent as columns)."""

    def __init__(self, rec: rr.RecordingStream, context: SessionContext, start_ns: int):
        self.rec = rec
        cam = context.camera
        self.enabled = cam is not None
        if cam is not None:
            log_camera(rec, cam.T_display_camera, cam.K, cam.width, cam.height, image_plane_distance=WORKING_DEPTH_M)
        rec.log(E.DISPLAY, rr.TransformAxes3D(AXIS_LENGTH_M * 1.5), static=True)
        self.poses = Columns(rec, E.DISPLAY, transform_columns, start_ns=start_ns)
        self.images = Columns(rec, E.IMAGE, lambda f: rr.EncodedImage.columns(blob=f["blob"], media_type=f["media"]),
                              start_ns=start_ns)

    def log(self, tick: Tick) -> None:
        # the display pose is the one at the frame's stamp: it changes with the frame
        if tick.T_dvio_display is not None and (tick.new_frame is not None or not self.enabled or tick.frame is None):
            self.poses.add(tick.t_ns, tick.index, translation=tick.T_dvio_display.translation,
                           quaternion=tick.T_dvio_display.quat_xyzw)
        image = tick.new_frame
        if self.enabled and image is not None:
            fmt = (image.format or "jpeg").lower()
            self.images.add(tick.t_ns, tick.index, blob=np.frombuffer(image.data, dtype=np.uint8),  # as recorded
                            media="image/png" if "png" in fmt else "image/jpeg")

    def flush(self) -> None:
        self.poses.flush()
        self.images.flush()


def _marker_columns(f: dict[str, list]) -> list:
    n = len(f["strip"])
    return [*rr.LineStrips2D.columns(strips=f["strip"], labels=f["label"],
                                     colors=np.tile(np.array([MARKER_COLOR], np.uint8), (n, 1)),
                                     radii=np.full(n, 1.5, np.float32)),
            *rr.AnyValues.columns(marker_id=np.asarray(f["id"], np.int64),
                                  reprojection_error_px=np.asarray(f["reprojection"], np.float64),
                                  ambiguity_ratio=np.asarray(f["ambiguity"], np.float64),
                                  chosen_solution=np.asarray(f["solution"], np.int64))]


class MarkerLogger:
    """The recognised marker's corners as a closed 2D strip labelled with its id, with the
    detection's diagnostics as data on the same entity (the selection panel shows why it was
    accepted: RMS reprojection error in px, and the planar-ambiguity ratio, i.e. the other IPPE
    solution's reprojection error over the chosen one's). Logged once per new camera frame; a
    frame without the marker clears the path."""

    def __init__(self, rec: rr.RecordingStream, start_ns: int):
        self.rec = rec
        self.shown = False
        self.rows = Columns(rec, E.MARKER, _marker_columns, start_ns=start_ns)

    def log(self, tick: Tick, obs: Observation) -> None:
        if tick.new_frame is None:
            return
        m = obs.marker
        if m is None:
            if self.shown:
                self.rows.flush()
                self.rec.log(E.MARKER, rr.Clear(recursive=True))
                self.shown = False
            return
        c = np.asarray(m.corners_px, dtype=np.float32).reshape(4, 2)
        ratio = float(m.ambiguity_ratio)
        self.rows.add(tick.t_ns, tick.index, strip=np.vstack([c, c[:1]]), label=f"id {m.id}", id=int(m.id),
                      reprojection=float(m.reprojection_error_px), ambiguity=ratio if np.isfinite(ratio) else np.nan,
                      solution=int(m.chosen_solution))
        self.shown = True

    def flush(self) -> None:
        self.rows.flush()


def axis_colors(color) -> np.ndarray:
    """The x, y, z axes of a pose in its tracker's colour: x as is, y lighter, z darker (told
    apart from each other, never mistaken for another tracker's)."""
    c = np.asarray(color, dtype=float)
    return np.array([c, c + (255.0 - c) * 0.5, c * 0.55], dtype=np.uint8)


class _PoseTrackLogger:
    """A pose (axes and a dot, in its colour) and its trajectory so far (one tracker, or the GT).

    Poses are buffered and sent as columns by the owner, which is many times cheaper than one
    ``log`` per tick; a missing pose clears the entity at once.

    The trajectory so far is kept linear in size: the points of the last ``SEGMENT_TICKS`` ticks
    are re-logged at ``<trajectory>/open`` (every ``TRAJECTORY_EVERY_TICKS``); then they are
    logged once, for good, as ``<trajectory>/NNNN`` and the open part starts again from the last
    point. At any time the viewer's latest-at shows the closed parts logged so far plus the open
    one: the trajectory so far, without re-sending it all every second. The name is the dot's
    label, kept as data (hover, selection) but not drawn: nine estimates lie within centimetres of
    each other and their labels would cover the scene; the metrics panel names the colours.
    """

    def __init__(self, rec: rr.RecordingStream, pose_path: str, trajectory_path: str, color, label: str,
                 radius: float = TRAJECTORY_RADIUS_M, start_ns: int = 0):
        self.rec = rec
        self.pose_path = pose_path
        self.trajectory_path = trajectory_path
        self.color = color
        self.label = label
        self.radius = radius
        self.segments: list[list[np.ndarray]] = [[]]   # the open part: strips broken where the pose was missing
        self.open_ticks = 0
        self.closed = 0
        self.shown = False
        self.dirty = 0
        rgb = np.array([color], np.uint8)
        axes = np.eye(3, dtype=np.float32) * AXIS_LENGTH_M
        shades = axis_colors(color)

        def make(f: dict[str, list]) -> list:
            n = len(f["translation"])
            return [*transform_columns(f),
                    *rr.Arrows3D.columns(vectors=np.tile(axes, (n, 1)), colors=np.tile(shades, (n, 1)),
                                         radii=np.full(3 * n, AXIS_RADIUS_M, np.float32)).partition([3] * n),
                    *rr.Points3D.columns(positions=np.zeros((n, 3), np.float32), colors=np.repeat(rgb, n, axis=0),
                                         radii=np.full(n, DOT_RADIUS_M, np.float32), labels=[label] * n,
                                         show_labels=[False] * n)]

        self.rows = Columns(rec, pose_path, make, start_ns=start_ns)

    def log(self, tick: Tick, pose: Pose | None) -> None:
        self.open_ticks += 1
        if pose is None:
            if self.shown:
                self.flush_poses()
                self.rec.log(self.pose_path, rr.Clear(recursive=True))
                self.shown = False
            if self.segments[-1]:
                self.segments.append([])
            return
        p = np.asarray(pose.translation, dtype=float)
        self.rows.add(tick.t_ns, tick.index, translation=p, quaternion=pose.quat_xyzw)
        self.shown = True
        self.segments[-1].append(p)
        self.dirty += 1

    def flush_poses(self) -> None:
        self.rows.flush()

    def _strips(self) -> rr.LineStrips3D | None:
        strips = [np.asarray(s, dtype=np.float32) for s in self.segments if len(s) >= 2]
        if not strips:
            return None
        return rr.LineStrips3D(strips, colors=[self.color], radii=self.radius)

    def flush_trajectory(self) -> None:
        """The trajectory so far, at the current tick (the engine set the clock)."""
        strips = self._strips()
        if self.open_ticks >= SEGMENT_TICKS:
            if strips is not None:
                self.rec.log(f"{self.trajectory_path}/{self.closed:04d}", strips)
                self.closed += 1
            self.rec.log(f"{self.trajectory_path}/open", rr.Clear(recursive=False))
            last = self.segments[-1]
            self.segments = [[last[-1]] if last else []]
            self.open_ticks = 0
        elif strips is not None:
            self.rec.log(f"{self.trajectory_path}/open", strips)
        self.dirty = 0


class TaskLogger:
    """The experiment's targets (cubes) or path (closed line), static, in display_vio."""

    def __init__(self, rec: rr.RecordingStream, context: SessionContext):
        log_task(rec, context.targets, context.path)


class ErrorLogger:
    """Per-tracker position (cm) and rotation (deg) error against GT, over the task window (the
    metrics' window, no alignment, as p_ATE / r_ATE are computed), as scalars sent in columns."""

    def __init__(self, rec: rr.RecordingStream, names: list[str], start_ns: int):
        self.rec = rec
        self.start_ns = start_ns
        self.rows: dict[str, list] = {name: [] for name in names}
        for name in names:
            style = rr.SeriesLines(colors=[tracker_color(name)], names=[name], widths=[line_width(name)])
            rec.log(E.position_error(name), style, static=True)
            rec.log(E.rotation_error(name), style, static=True)

    def log(self, tick: Tick, gt: Pose | None, poses: dict[str, Pose | None]) -> None:
        if gt is None or not tick.in_task:
            return
        for name, pose in poses.items():
            if pose is not None:
                self.rows[name].append((tick.index, tick.t_ns, gt, pose))

    def flush(self) -> None:
        for name, rows in self.rows.items():
            if not rows:
                continue
            idx = [r[0] for r in rows]
            t = [r[1] for r in rows]
            gt = Pose.from_xyzw(np.vstack([r[2].translation for r in rows]), np.vstack([r[2].quat_xyzw for r in rows]))
            est = Pose.from_xyzw(np.vstack([r[3].translation for r in rows]), np.vstack([r[3].quat_xyzw for r in rows]))
            index = time_columns(t, idx, self.start_ns)
            self.rec.send_columns(E.position_error(name), indexes=index,
                                  columns=rr.Scalars.columns(scalars=translation_errors(gt, est) * 100.0))
            self.rec.send_columns(E.rotation_error(name), indexes=index,
                                  columns=rr.Scalars.columns(scalars=rotation_errors_deg(gt, est)))
            rows.clear()


class StatusLogger:
    """Lanes of the state timeline: where the tick lies against the task window, and whether the
    marker is in view (the paper's practical FoV test: recognised in this frame). Logged on change."""

    def __init__(self, rec: rr.RecordingStream):
        self.rec = rec
        for path, states in ((E.STATUS_TASK, TASK_STATES), (E.STATUS_MARKER, MARKER_STATES)):
            rec.log(path, rr.StateConfiguration(values=list(states), labels=[v[0] for v in states.values()],
                                                colors=[v[1] for v in states.values()]), static=True)
        self.task: str | None = None
        self.marker: str | None = None
        self.seen_task = False

    def log(self, tick: Tick, obs: Observation) -> None:
        self.seen_task |= tick.in_task
        task = "task" if tick.in_task else ("after" if self.seen_task else "calibration")
        if task != self.task:
            self.rec.log(E.STATUS_TASK, rr.StateChange(state=task))
            self.task = task
        marker = "in_view" if obs.in_view else "out_of_view"
        if tick.frame is not None and marker != self.marker:
            self.rec.log(E.STATUS_MARKER, rr.StateChange(state=marker))
            self.marker = marker


# ------------------------------------------------------------------ the playback's logger
class PlaybackRerunLogger:
    """Owns the RecordingStream and the clock; wires the stage loggers.

    ``session`` and ``params`` (the playback's options that change its result: ``rate_hz``,
    ``correction_math``, ``start_s``, ``end_s``, ``hand_eye``) make the recording id and name.
    ``rrd_path`` is written as given (the caller checks it and may pass a temporary name).
    ``session_start_ns``: where ``session_time`` is zero (the session's first message; default the
    task's start).
    """

    def __init__(self, context: SessionContext, tracker_names: list[str], *, session: str | os.PathLike | None = None,
                 params: dict | None = None, session_name: str | None = None, session_start_ns: int | None = None,
                 rrd_path: str | os.PathLike | None = None, spawn: bool = False,
                 trajectory_every: int = TRAJECTORY_EVERY_TICKS, columns_every: int | None = None,
                 recording: rr.RecordingStream | None = None):
        params = dict(params or {}, trackers=list(tracker_names))
        self.context = context
        self.tracker_names = list(tracker_names)
        self.start_ns = int(session_start_ns if session_start_ns is not None else context.task_start_ns or 0)
        self.blueprint_sent = False
        self.rrd_path = rrd_path if recording is None and not spawn else None
        if recording is not None:
            self.rec = recording
        else:
            if session is not None:
                rid, name = recording_id(session, params), recording_name(session, tracker_names, params)
            else:   # tests and tools without a file: still one id per parameter set
                stem = session_name or "session"
                digest = hashlib.sha256(json.dumps(params, sort_keys=True, default=str).encode()).hexdigest()[:16]
                rid, name = f"playback-{stem}-{digest}", f"{stem} · {' '.join(tracker_names)}"
            self.rec = open_recording(APPLICATION_ID, rid, name=name, rrd_path=rrd_path, spawn=spawn,
                                      start_time_ns=context.task_start_ns)
        rec = self.rec
        rec.log(E.WORLD, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        start = self.start_ns
        self.camera = CameraLogger(rec, context, start)
        self.markers = MarkerLogger(rec, start)
        self.task = TaskLogger(rec, context)
        self.status = StatusLogger(rec)
        self.gt = _PoseTrackLogger(rec, E.GT_CONTROLLER, E.GT_TRAJECTORY, GT_COLOR, "GT", radius=GT_TRAJECTORY_RADIUS_M,
                                   start_ns=start)
        self.trackers = {name: _PoseTrackLogger(rec, E.tracker_pose(name), E.tracker_trajectory(name),
                                                tracker_color(name), name, start_ns=start) for name in tracker_names}
        self.errors = ErrorLogger(rec, tracker_names, start)
        if columns_every is None:
            columns_every = COLUMNS_EVERY_TICKS_LIVE if spawn else COLUMNS_EVERY_TICKS_FILE
        self.columns_every = max(1, int(columns_every))
        self.trajectory_every = max(1, int(trajectory_every))
        self._since_columns = 0
        self._since_trajectory = 0
        self._ticks = 0

    @property
    def blueprint(self) -> rrb.Blueprint:
        """The layout without the eye framing (that needs the display's pose, see :meth:`send_blueprint`)."""
        return default_blueprint(self.tracker_names, self.context, start_ns=self.start_ns)

    def send_blueprint(self, T_dvio_display: Pose | None) -> None:
        """The default blueprint, its 3D eye framed on the display camera (at ``T_dvio_display``) and the task."""
        cam_pos = None
        if T_dvio_display is not None and self.context.camera is not None:
            cam_pos = (T_dvio_display @ self.context.camera.T_display_camera).translation
        elif T_dvio_display is not None:
            cam_pos = T_dvio_display.translation
        self.rec.send_blueprint(default_blueprint(self.tracker_names, self.context,
                                                  None if cam_pos is None else np.asarray(cam_pos).reshape(3),
                                                  start_ns=self.start_ns),
                                make_active=True, make_default=True)
        self.blueprint_sent = True

    def set_time(self, tick: Tick) -> None:
        self.rec.set_time(E.TICK, sequence=tick.index)
        self.rec.set_time(E.SESSION_TIME, duration=np.timedelta64(int(tick.t_ns) - self.start_ns, "ns"))
        self.rec.set_time(E.TIME, timestamp=np.datetime64(int(tick.t_ns), "ns"))

    def log_tick(self, tick: Tick, obs: Observation, poses: dict[str, Pose | None], gt: Pose | None = None) -> None:
        """``gt``: the ground truth the scheduler associated with this tick (beside it, never in it)."""
        self.set_time(tick)
        self._ticks += 1
        if not self.blueprint_sent and (tick.T_dvio_display is not None or self._ticks >= BLUEPRINT_WAIT_TICKS):
            self.send_blueprint(tick.T_dvio_display)
        self.camera.log(tick)
        self.markers.log(tick, obs)
        self.status.log(tick, obs)
        self.gt.log(tick, gt)
        for name, pose in poses.items():
            self.trackers[name].log(tick, pose)
        self.errors.log(tick, gt, poses)
        self._since_columns += 1
        self._since_trajectory += 1
        if self._since_columns >= self.columns_every:
            self.flush_columns()
        if self._since_trajectory >= self.trajectory_every:
            self.flush_trajectories()

    def flush_columns(self) -> None:
        """Send the buffered rows (they carry their own tick/time)."""
        self.camera.flush()
        self.markers.flush()
        for t in [self.gt, *self.trackers.values()]:
            t.flush_poses()
        self.errors.flush()
        self._since_columns = 0

    def flush_trajectories(self) -> None:
        """The trajectories so far, at the current tick."""
        for t in [self.gt, *self.trackers.values()]:
            if t.dirty:
                t.flush_trajectory()
        self._since_trajectory = 0

    def flush(self) -> None:
        self.flush_columns()
        self.flush_trajectories()

    def log_metrics(self, metrics: dict) -> None:
        """The metrics table (the metrics.json document) and the colour legend, static at ``/metrics``."""
        self.rec.log(E.METRICS, rr.TextDocument(metrics_markdown(metrics), media_type=rr.MediaType.MARKDOWN),
                     static=True)

    def close(self) -> None:
        if not self.blueprint_sent:
            self.send_blueprint(None)
        self.flush()
        close_recording(self.rec, self.rrd_path)   # the .rrd's footer is written now: before it is renamed into place
