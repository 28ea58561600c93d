"""Rerun logging of a playback: one logger per stage, each owning its entity paths.

The engine owns the clock: :class:`PlaybackRerunLogger` sets the timelines ``tick`` (sequence)
and ``time`` (timestamp, display clock) once per tick, then every stage logger logs its part.
A stage with nothing to show clears its path (``rr.Clear``) so the viewer never shows a stale
marker or pose.

Entity paths (``/world`` is display_vio):

    /world                                  view coordinates (static)
    /world/display                          display body pose (Transform3D), axes
    /world/display/camera                   T_display_camera (static)
    /world/display/camera/image             Pinhole (static), EncodedImage (the recorded JPEG bytes)
    /world/display/camera/image/markers     LineStrips2D of the recognised marker, id as label
    /world/gt/pose                          GT controller pose (Transform3D + axes)
    /world/gt/trajectory/{NNNN,open}        GT so far (LineStrips3D: closed parts + the open one)
    /world/trackers/<name>/pose             tracker estimate (Transform3D + axes)
    /world/trackers/<name>/trajectory/...   its trajectory so far (same layout)
    /world/task/targets | /world/task/path  experiment targets (Boxes3D) or path (LineStrips3D), static
    /errors/<name>/position_m, rotation_deg per-tracker error against GT (Scalars)
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from phonepose.errors import OutputError
from phonepose.geometry import Pose
from phonepose.pipeline.types import Observation, SessionContext, Tick

TRAJECTORY_EVERY_TICKS = 20   # trajectories so far are re-logged every 20 ticks (1 s at 20 Hz)
SEGMENT_TICKS = 100           # ... and closed for good every 100 ticks (the size stays linear)
# Buffered rows (images, poses, errors, markers) are sent as columns every this many ticks: to a
# .rrd file in large batches (each send_columns has a fixed cost), to a live viewer promptly.
COLUMNS_EVERY_TICKS_FILE = 100
COLUMNS_EVERY_TICKS_LIVE = 5
AXIS_LENGTH_M = 0.05
# one colour per tracker (T1..T7, then cycling)
PALETTE = [(230, 25, 75), (245, 130, 48), (255, 225, 25), (60, 180, 75), (70, 240, 240), (0, 130, 200),
           (145, 30, 180), (240, 50, 230), (128, 128, 0), (170, 110, 40)]
GT_COLOR = (255, 255, 255)

WORLD = "/world"
DISPLAY = "/world/display"
CAMERA = "/world/display/camera"
IMAGE = "/world/display/camera/image"
MARKERS = "/world/display/camera/image/markers"
GT_POSE = "/world/gt/pose"
GT_TRAJECTORY = "/world/gt/trajectory"
TASK = "/world/task"
ERRORS = "/errors"


def tracker_pose_path(name: str) -> str:
    return f"/world/trackers/{name}/pose"


def tracker_trajectory_path(name: str) -> str:
    return f"/world/trackers/{name}/trajectory"


def _transform(pose: Pose) -> rr.Transform3D:
    return rr.Transform3D(translation=np.asarray(pose.translation, dtype=np.float32),
                          quaternion=rr.Quaternion(xyzw=np.asarray(pose.quat_xyzw, dtype=np.float32)))


def default_blueprint(tracker_names: list[str]) -> rrb.Blueprint:
    """3D scene | camera view over the error time series."""
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(name="3D (display_vio)", origin=WORLD),
            rrb.Vertical(
                rrb.Spatial2DView(name="display camera", origin=IMAGE),
                rrb.TimeSeriesView(name="position error (m)", origin=ERRORS,
                                   contents=[f"{ERRORS}/{n}/position_m" for n in tracker_names]),
                rrb.TimeSeriesView(name="rotation error (deg)", origin=ERRORS,
                                   contents=[f"{ERRORS}/{n}/rotation_deg" for n in tracker_names]),
                row_shares=[3, 2, 2],
            ),
            column_shares=[3, 2],
        ),
        rrb.TimePanel(timeline="time"),
        collapse_panels=False,
    )


def _time_columns(idx: list[int], t_ns: list[int]) -> list:
    return [rr.TimeColumn("tick", sequence=np.asarray(idx, dtype=np.int64)),
            rr.TimeColumn("time", timestamp=np.asarray(t_ns, dtype=np.int64).astype("datetime64[ns]"))]


class CameraLogger:
    """Display pose, camera (static Pinhole), the recorded JPEG bytes (buffered, sent as columns)."""

    def __init__(self, rec: rr.RecordingStream, context: SessionContext):
        self.rec = rec
        cam = context.camera
        self.enabled = cam.width > 0
        if self.enabled:
            rec.log(CAMERA, _transform(cam.T_display_camera), static=True)
            rec.log(IMAGE, rr.Pinhole(image_from_camera=np.asarray(cam.K, dtype=np.float32),
                                      resolution=[cam.width, cam.height], camera_xyz=rr.ViewCoordinates.RDF,
                                      image_plane_distance=0.1), static=True)
        rec.log(DISPLAY, rr.TransformAxes3D(AXIS_LENGTH_M * 1.5), static=True)

        self.img_idx: list[int] = []
        self.img_t: list[int] = []
        self.img_blobs: list[np.ndarray] = []
        self.img_media: list[str] = []
        self.pose_idx: list[int] = []
        self.pose_t: list[int] = []
        self.pose_q: list[np.ndarray] = []
        self.pose_p: list[np.ndarray] = []

    def log(self, tick: Tick) -> None:
        # the display pose is the one at the frame's stamp: it changes with the frame
        if tick.T_dvio_display is not None and (tick.image_is_new or not self.enabled or tick.image is None):
            self.pose_idx.append(tick.index)
            self.pose_t.append(tick.t_ns)
            self.pose_q.append(tick.T_dvio_display.quat_xyzw)
            self.pose_p.append(np.asarray(tick.T_dvio_display.translation, dtype=float))
        if self.enabled and tick.image is not None and tick.image_is_new:
            fmt = (tick.image.format or "jpeg").lower()
            self.img_idx.append(tick.index)
            self.img_t.append(tick.t_ns)
            self.img_blobs.append(np.frombuffer(tick.image.data, dtype=np.uint8))   # the recorded bytes, as they are
            self.img_media.append("image/png" if "png" in fmt else "image/jpeg")

    def flush(self) -> None:
        if self.pose_idx:
            self.rec.send_columns(DISPLAY, indexes=_time_columns(self.pose_idx, self.pose_t),
                                  columns=rr.Transform3D.columns(translation=np.vstack(self.pose_p).astype(np.float32),
                                                                 quaternion=np.vstack(self.pose_q).astype(np.float32)))
            self.pose_idx, self.pose_t, self.pose_q, self.pose_p = [], [], [], []
        if self.img_idx:
            self.rec.send_columns(IMAGE, indexes=_time_columns(self.img_idx, self.img_t),
                                  columns=rr.EncodedImage.columns(blob=self.img_blobs, media_type=self.img_media))
            self.img_idx, self.img_t, self.img_blobs, self.img_media = [], [], [], []


class MarkerLogger:
    """The recognised marker's corners as a closed 2D strip labelled with its id (sent as columns).

    Logged once per new camera frame; a frame without the marker clears the path.
    """

    def __init__(self, rec: rr.RecordingStream):
        self.rec = rec
        self.shown = False
        self.idx: list[int] = []
        self.t: list[int] = []
        self.strips: list[np.ndarray] = []
        self.labels: list[str] = []

    def log(self, tick: Tick, obs: Observation) -> None:
        if tick.image is None or not tick.image_is_new:
            return
        m = obs.marker
        if m is None:
            if self.shown:
                self.flush()
                self.rec.log(MARKERS, rr.Clear(recursive=True))
                self.shown = False
            return
        c = np.asarray(m.corners_px, dtype=np.float32).reshape(4, 2)
        self.idx.append(tick.index)
        self.t.append(tick.t_ns)
        self.strips.append(np.vstack([c, c[:1]]))
        self.labels.append(f"id {m.id}")
        self.shown = True

    def flush(self) -> None:
        if not self.idx:
            return
        n = len(self.idx)
        self.rec.send_columns(MARKERS, indexes=_time_columns(self.idx, self.t),
                              columns=rr.LineStrips2D.columns(strips=self.strips, labels=self.labels,
                                                              colors=np.tile(np.array([[0, 255, 0]], np.uint8), (n, 1)),
                                                              radii=np.full(n, 1.5, np.float32)))
        self.idx, self.t, self.strips, self.labels = [], [], [], []


class _PoseTrackLogger:
    """A pose with axes and its trajectory so far (one tracker, or the GT).

    Poses are buffered and sent as columns (``send_columns``) by the owner, which is many times
    cheaper than one ``log`` per tick; a missing pose clears the entity at once.

    The trajectory so far is kept linear in size: the points of the last ``SEGMENT_TICKS`` ticks
    are re-logged at ``<trajectory>/open`` (every ``TRAJECTORY_EVERY_TICKS``); then they are
    logged once, for good, as ``<trajectory>/NNNN`` and the open part starts again from the last
    point. At any time the viewer's latest-at shows the closed parts logged so far plus the open
    one: the trajectory so far, without re-sending it all every second.
    """

    def __init__(self, rec: rr.RecordingStream, pose_path: str, trajectory_path: str, color, label: str):
        self.rec = rec
        self.pose_path = pose_path
        self.trajectory_path = trajectory_path
        self.color = color
        self.label = label
        self.segments: list[list[np.ndarray]] = [[]]   # the open part: strips broken where the pose was missing
        self.open_ticks = 0
        self.closed = 0
        self.shown = False
        self.dirty = 0
        self.rows_idx: list[int] = []
        self.rows_t: list[int] = []
        self.rows_q: list[np.ndarray] = []
        self.rows_p: list[np.ndarray] = []

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
        self.rows_idx.append(tick.index)
        self.rows_t.append(tick.t_ns)
        self.rows_q.append(pose.quat_xyzw)
        self.rows_p.append(p)
        self.shown = True
        self.segments[-1].append(p)
        self.dirty += 1

    def flush_poses(self) -> None:
        if not self.rows_idx:
            return
        n = len(self.rows_idx)
        self.rec.send_columns(
            self.pose_path, indexes=_time_columns(self.rows_idx, self.rows_t),
            columns=[*rr.Transform3D.columns(translation=np.vstack(self.rows_p).astype(np.float32),
                                             quaternion=np.vstack(self.rows_q).astype(np.float32)),
                     *rr.TransformAxes3D.columns(axis_length=np.full(n, AXIS_LENGTH_M, dtype=np.float32))])
        self.rows_idx, self.rows_t, self.rows_q, self.rows_p = [], [], [], []

    def _strips(self) -> rr.LineStrips3D | None:
        strips = [np.asarray(s, dtype=np.float32) for s in self.segments if len(s) >= 2]
        if not strips:
            return None
        return rr.LineStrips3D(strips, colors=[self.color], radii=0.002, labels=[self.label] * len(strips))

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
        targets = context.targets
        if targets is not None and len(targets.targets):
            centers = np.array([[t.pose.position.x, t.pose.position.y, t.pose.position.z] for t in targets.targets],
                               dtype=np.float32)
            quats = [rr.Quaternion(xyzw=[t.pose.orientation.x, t.pose.orientation.y, t.pose.orientation.z,
                                         t.pose.orientation.w]) for t in targets.targets]
            half = float(targets.cube_size_m or 0.02) / 2
            rec.log(f"{TASK}/targets", rr.Boxes3D(centers=centers, half_sizes=[[half, half, half]] * len(centers),
                                                 quaternions=quats, labels=[str(t.index) for t in targets.targets],
                                                 colors=[(200, 200, 200)]), static=True)
        path = context.path
        if path is not None and len(path.waypoints):
            pts = np.array([[w.x, w.y, w.z] for w in path.waypoints], dtype=np.float32)
            if path.closed:
                pts = np.vstack([pts, pts[:1]])
            rec.log(f"{TASK}/path", rr.LineStrips3D([pts], colors=[(200, 200, 200)], radii=0.001,
                                                     labels=[path.name or "path"]), static=True)


class ErrorLogger:
    """Per-tracker position (m) and rotation (deg) error against GT, as scalars (sent in columns)."""

    def __init__(self, rec: rr.RecordingStream, names: list[str]):
        self.rec = rec
        self.rows: dict[str, list] = {name: [] for name in names}
        for i, name in enumerate(names):
            color = PALETTE[i % len(PALETTE)]
            rec.log(f"{ERRORS}/{name}/position_m", rr.SeriesLines(colors=[color], names=[name]), static=True)
            rec.log(f"{ERRORS}/{name}/rotation_deg", rr.SeriesLines(colors=[color], names=[name]), static=True)

    def log(self, tick: Tick, gt: Pose | None, poses: dict[str, Pose | None]) -> None:
        if gt is None:
            return
        gq, gp = gt.quat_xyzw, np.asarray(gt.translation, dtype=float)
        for name, pose in poses.items():
            if pose is not None:
                self.rows[name].append((tick.index, tick.t_ns, gq, gp, pose.quat_xyzw, np.asarray(pose.translation)))

    def flush(self) -> None:
        for name, rows in self.rows.items():
            if not rows:
                continue
            idx = [r[0] for r in rows]
            t = [r[1] for r in rows]
            gq = np.vstack([r[2] for r in rows])
            eq = np.vstack([r[4] for r in rows])
            pos = np.linalg.norm(np.vstack([r[3] for r in rows]) - np.vstack([r[5] for r in rows]), axis=1)
            dot = np.clip(np.abs(np.sum(gq * eq, axis=1)), 0.0, 1.0)
            rot = np.degrees(2.0 * np.arccos(dot))
            self.rec.send_columns(f"{ERRORS}/{name}/position_m", indexes=_time_columns(idx, t),
                                  columns=rr.Scalars.columns(scalars=pos))
            self.rec.send_columns(f"{ERRORS}/{name}/rotation_deg", indexes=_time_columns(idx, t),
                                  columns=rr.Scalars.columns(scalars=rot))
            rows.clear()


class PlaybackRerunLogger:
    """Owns the RecordingStream and the clock; wires the stage loggers."""

    def __init__(self, context: SessionContext, tracker_names: list[str], *, session_name: str = "session",
                 rrd_path: str | os.PathLike | None = None, spawn: bool = False,
                 trajectory_every: int = TRAJECTORY_EVERY_TICKS, columns_every: int | None = None,
                 recording: rr.RecordingStream | None = None):
        self.blueprint = default_blueprint(tracker_names)
        if recording is not None:
            self.rec = recording
        else:
            self.rec = rr.RecordingStream("phonepose_playback", recording_id=f"playback-{session_name}")
            if spawn:
                try:
                    self.rec.spawn(default_blueprint=self.blueprint)
                except Exception as exc:  # no viewer binary, no display, port in use, ...
                    raise OutputError(f"cannot spawn the Rerun viewer ({exc}); save a recording with --rerun FILE.rrd "
                                      "instead") from None
            elif rrd_path is not None:
                try:
                    Path(rrd_path).parent.mkdir(parents=True, exist_ok=True)
                except OSError as exc:
                    raise OutputError(f"cannot write {rrd_path}: {exc.strerror or exc}") from None
                if Path(rrd_path).is_dir():
                    raise OutputError(f"cannot write {rrd_path}: is a directory")
                self.rec.save(os.fspath(rrd_path), default_blueprint=self.blueprint)
        rec = self.rec
        rec.log(WORLD, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self.camera = CameraLogger(rec, context)
        self.markers = MarkerLogger(rec)
        self.task = TaskLogger(rec, context)
        self.gt = _PoseTrackLogger(rec, GT_POSE, GT_TRAJECTORY, GT_COLOR, "GT")
        self.trackers = {
            name: _PoseTrackLogger(rec, tracker_pose_path(name), tracker_trajectory_path(name),
                                   PALETTE[i % len(PALETTE)], name)
            for i, name in enumerate(tracker_names)
        }
        self.errors = ErrorLogger(rec, tracker_names)
        if columns_every is None:
            columns_every = COLUMNS_EVERY_TICKS_LIVE if spawn else COLUMNS_EVERY_TICKS_FILE
        self.columns_every = max(1, int(columns_every))
        self.trajectory_every = max(1, int(trajectory_every))
        self._since_columns = 0
        self._since_trajectory = 0

    def set_time(self, tick: Tick) -> None:
        self.rec.set_time("tick", sequence=tick.index)
        self.rec.set_time("time", timestamp=np.datetime64(int(tick.t_ns), "ns"))

    def log_tick(self, tick: Tick, obs: Observation, poses: dict[str, Pose | None]) -> None:
        self.set_time(tick)
        self.camera.log(tick)
        self.markers.log(tick, obs)
        self.gt.log(tick, tick.gt_T_dvio_controller)
        for name, pose in poses.items():
            self.trackers[name].log(tick, pose)
        self.errors.log(tick, tick.gt_T_dvio_controller, poses)
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

    def close(self) -> None:
        self.flush()
        self.rec.flush()
