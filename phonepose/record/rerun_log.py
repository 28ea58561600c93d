"""Rerun logging of what is being recorded (``record sim|live --rerun FILE`` / ``--spawn``).

The entity tree is :mod:`phonepose.viewer.entities`, the same as playback's: ``/world`` is
display_vio; the display's VIO pose places ``/world/display`` and its camera (extrinsics,
pinhole, the JPEG bytes as they are); the controller's VIO pose is mapped into display_vio
through the two anchors (``/world/controller``); motion capture is mapped through
``/gt/calibration`` (``/world/gt/controller``, ``/world/gt/display``); the task is drawn as in
playback; the IMU goes to ``/imu/gyro`` and ``/imu/accel``. Timeline: ``time`` (log time).

High-rate streams are buffered and sent as columns every ``BATCH_NS`` of log time: one Rerun
call per entity per batch instead of one per sample (the viewer lags by <= 0.2 s).
"""

from __future__ import annotations

import hashlib
import os
import re
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr

from phonepose.geometry import Pose
from phonepose.record.source import Record
from phonepose.schemas.topics import Topic
from phonepose.session import codec
from phonepose.session.context import task_path, task_targets
from phonepose.viewer import entities as E
from phonepose.viewer.scene import log_body_marker, log_camera, log_task
from phonepose.viewer.sink import Columns, close_recording, open_recording, transform_columns
from phonepose.viewer.style import GT_COLOR, TRACKER_COLORS

APPLICATION_ID = "phonepose_record"
BATCH_NS = 200_000_000
AXIS_LENGTH_M = 0.05
VIO_COLOR = TRACKER_COLORS["T1"]   # the controller's VIO through the anchors is what T1 reports


def record_recording_id(out: str | os.PathLike, static: list[Record]) -> str:
    """``record-<stem>-<16 hex>`` from the session's static part (session info with the source,
    seed and full configuration; calibrations) and its file name: the same simulated session
    gives the same id, any other recording another."""
    h = hashlib.sha256(Path(out).name.encode())
    for r in static:
        h.update(r.topic.encode())
        h.update(r.log_time_ns.to_bytes(8, "little", signed=True))
        h.update(r.message.SerializeToString(deterministic=True))
    stem = re.sub(r"[^A-Za-z0-9_-]+", "_", Path(out).stem)[:60]
    return f"record-{stem}-{h.hexdigest()[:16]}"


class RecordRerunLogger:
    """Logs every record written; :func:`open_record_logger` makes one."""

    def __init__(self, rec: rr.RecordingStream, rrd_path: str | os.PathLike | None = None):
        self.rec = rec
        self.rrd_path = rrd_path
        rec.log(E.WORLD, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        for path, width in ((E.DISPLAY, 1.5), (E.CONTROLLER_VIO, 1.0), (E.GT_CONTROLLER, 1.0), (E.GT_DISPLAY, 1.0)):
            rec.log(path, rr.TransformAxes3D(AXIS_LENGTH_M * width), static=True)
        log_body_marker(rec, E.CONTROLLER_VIO, "controller (VIO)", VIO_COLOR)
        log_body_marker(rec, E.GT_CONTROLLER, "GT", GT_COLOR)
        for path, unit in ((E.IMU_GYRO, "rad/s"), (E.IMU_ACCEL, "m/s²")):
            rec.log(path, rr.SeriesLines(names=[f"{a} ({unit})" for a in "xyz"],
                                         colors=[(214, 39, 40), (44, 160, 44), (31, 119, 180)]), static=True)
        self._T_dvio_world: Pose | None = None
        self._anchors: dict[str, Pose] = {}
        self._poses = {path: Columns(rec, path, transform_columns, with_ticks=False)
                       for path in (E.DISPLAY, E.CONTROLLER_VIO, E.GT_CONTROLLER, E.GT_DISPLAY)}
        self._images = Columns(rec, E.IMAGE, lambda f: rr.EncodedImage.columns(blob=f["blob"], media_type=f["media"]),
                               with_ticks=False)
        self._gyro = Columns(rec, E.IMU_GYRO, lambda f: rr.Scalars.columns(scalars=np.asarray(f["v"])), with_ticks=False)
        self._accel = Columns(rec, E.IMU_ACCEL, lambda f: rr.Scalars.columns(scalars=np.asarray(f["v"])),
                              with_ticks=False)
        self._batch_start: int | None = None
        self._T_display_camera: Pose | None = None

    def _pose(self, path: str, pose: Pose, t_ns: int) -> None:
        self._poses[path].add(t_ns, translation=np.asarray(pose.translation, float).reshape(3),
                              quaternion=np.asarray(pose.quat_xyzw, float).reshape(4))

    def log(self, r: Record) -> None:
        """Show one record; a broken pose (codec.BrokenPose) is not shown."""
        try:
            self._log(r)
        except codec.BrokenPose:
            pass

    def _log(self, r: Record) -> None:
        m: Any = r.message
        topic, t = r.topic, r.log_time_ns
        if self._batch_start is None:
            self._batch_start = t
        elif t - self._batch_start >= BATCH_NS:
            self.flush()
            self._batch_start = t
        if topic == Topic.CAMERA_IMAGE:
            fmt = (m.format or "jpeg").lower()
            self._images.add(t, blob=np.frombuffer(m.data, dtype=np.uint8),
                             media="image/png" if "png" in fmt else "image/jpeg")
        elif topic == Topic.CAMERA_CALIBRATION:
            log_camera(self.rec, K=np.array(m.K).reshape(3, 3), width=m.width, height=m.height)
        elif topic == Topic.CAMERA_EXTRINSICS:
            log_camera(self.rec, T_display_camera=codec.transform_of(m))
        elif topic == Topic.GT_CALIBRATION:
            self._T_dvio_world = codec.transform_of(m).inv()
        elif topic == Topic.EXPERIMENT_TARGETS:
            log_task(self.rec, targets=task_targets(m))
        elif topic == Topic.EXPERIMENT_PATH:
            log_task(self.rec, path=task_path(m))
        elif topic == Topic.DISPLAY_VIO_POSE:
            self._pose(E.DISPLAY, codec.pose_of(m.pose), t)
        elif topic in (Topic.DISPLAY_ANCHOR, Topic.CONTROLLER_ANCHOR):
            self._anchors[topic] = codec.pose_of(m.pose)
        elif topic == Topic.CONTROLLER_VIO_POSE:
            if len(self._anchors) == 2:
                mapped = self._anchors[Topic.DISPLAY_ANCHOR] @ self._anchors[Topic.CONTROLLER_ANCHOR].inv() \
                    @ codec.pose_of(m.pose)
                self._pose(E.CONTROLLER_VIO, mapped, t)
        elif topic in (Topic.GT_CONTROLLER_POSE, Topic.GT_DISPLAY_POSE):
            if self._T_dvio_world is not None:
                path = E.GT_CONTROLLER if topic == Topic.GT_CONTROLLER_POSE else E.GT_DISPLAY
                self._pose(path, self._T_dvio_world @ codec.pose_of(m.pose), t)
        elif topic == Topic.CONTROLLER_IMU:
            self._gyro.add(t, v=(m.gyro_x, m.gyro_y, m.gyro_z))
            self._accel.add(t, v=(m.accel_x, m.accel_y, m.accel_z))

    def flush(self) -> None:
        for c in (*self._poses.values(), self._images, self._gyro, self._accel):
            c.flush()

    def close(self) -> None:
        """Send what is buffered and close the sink: a .rrd gets its footer only when the sink is
        dropped, so before the caller renames it into place."""
        self.flush()
        close_recording(self.rec, self.rrd_path)


def open_record_logger(out: str | os.PathLike, static: list[Record], *, rrd_path: str | os.PathLike | None = None,
                       spawn: bool = False, source: str = "") -> RecordRerunLogger:
    """The recorder's Rerun logger, for ``record sim`` and ``record live`` alike: a file or a
    spawned viewer, the recording id from :func:`record_recording_id`, named after the session."""
    name = f"{Path(out).name} · recording" + (f" ({source})" if source else "")
    start = min((r.log_time_ns for r in static), default=None)
    rec = open_recording(APPLICATION_ID, record_recording_id(out, static), name=name, rrd_path=rrd_path, spawn=spawn,
                         start_time_ns=start)
    return RecordRerunLogger(rec, rrd_path)
