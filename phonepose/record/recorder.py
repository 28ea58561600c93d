"""Recorder: pulls records from a :class:`~phonepose.record.source.Source` and writes one session.

It writes the source's static part first, then the stream, through
:class:`~phonepose.session.SessionWriter` (the writer flushes about once a second of log
time, so a SIGKILL loses at most ~1 s). SIGINT / SIGTERM set a flag: the loop stops after the
current message and the ``with`` block finishes a valid file. Optionally everything recorded
is also logged to Rerun (saved to an .rrd file or streamed to a spawned viewer).
"""

from __future__ import annotations

import os
import signal
import threading
from dataclasses import dataclass
from typing import Callable

import numpy as np

from phonepose.errors import OutputError, SessionContentError
from phonepose.geometry import Pose
from phonepose.record.source import Record, Source
from phonepose.schemas.topics import Topic
from phonepose.session import SessionWriter, codec

ProgressCallback = Callable[[int, int | None], None]   # (log time done since start, duration) in ns


@dataclass
class RecordResult:
    path: str
    messages: int
    duration_ns: int          # log time covered (first to last message)
    interrupted: bool         # stopped by SIGINT / SIGTERM before the source ended
    frames: int               # camera images written


class RerunLogger:
    """Logs what is being recorded: camera images (the JPEG bytes as they are), true and VIO poses, IMU.

    Entities: ``/world/display`` (mocap pose of the display) with ``camera`` under it (static
    extrinsics, pinhole, images), ``/world/controller`` (mocap pose of the controller),
    ``/world/display_vio`` (placed by ``/gt/calibration``) holding the display's VIO pose and the
    controller's VIO pose mapped through the anchors, ``/imu/gyro`` and ``/imu/accel``.
    """

    def __init__(self, rrd_path: str | None = None, spawn: bool = False, application_id: str = "phonepose_record"):
        import rerun as rr

        self.rr = rr
        self.rec = rr.RecordingStream(application_id)
        try:
            if spawn:
                self.rec.spawn()
            elif rrd_path is not None:    # checked before (phonepose.files): the temporary the caller owns
                self.rec.save(rrd_path)
        except (RuntimeError, OSError) as exc:   # rerun reports sink failures as RuntimeError
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            hint = "; save a recording with --rerun FILE.rrd instead" if spawn else ""
            raise OutputError(f"cannot start Rerun logging ({rrd_path or 'viewer'}): {first}{hint}") from None
        self.rec.log("/world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self._anchors: dict[str, Pose] = {}
        # High-rate streams (poses, IMU) are sent as columns every BATCH_NS of log time: one
        # Rerun call per entity per batch instead of one per sample (the viewer lags by <= 0.2 s).
        self._poses: dict[str, tuple[list, list, list]] = {}
        self._imu: tuple[list, list, list] = ([], [], [])
        self._batch_start: int | None = None

    def _transform(self, path: str, pose: Pose, axes: float | None = 0.05, static: bool = False,
                   t_ns: int | None = None) -> None:
        rr = self.rr
        if not static:
            if path not in self._poses:
                self._poses[path] = ([], [], [])
                if axes:
                    self.rec.log(path, rr.TransformAxes3D(axes), static=True)
            times, trans, quats = self._poses[path]
            times.append(t_ns)
            trans.append(pose.translation)
            quats.append(pose.quat_xyzw)
            return
        x, y, z, w = (float(v) for v in pose.quat_xyzw)
        self.rec.log(path, rr.Transform3D(translation=[float(v) for v in pose.translation], quaternion=[x, y, z, w]),
                     static=True)

    def _flush(self) -> None:
        rr = self.rr
        for path, (times, trans, quats) in self._poses.items():
            if times:
                self.rec.send_columns(path, indexes=[rr.TimeColumn("time", timestamp=np.array(times, "datetime64[ns]"))],
                                      columns=rr.Transform3D.columns(translation=np.array(trans),
                                                                     quaternion=np.array(quats)))
                times.clear(), trans.clear(), quats.clear()
        times, gyro, accel = self._imu
        if times:
            index = [rr.TimeColumn("time", timestamp=np.array(times, "datetime64[ns]"))]
            self.rec.send_columns("/imu/gyro", indexes=index, columns=rr.Scalars.columns(scalars=np.array(gyro)))
            self.rec.send_columns("/imu/accel", indexes=index, columns=rr.Scalars.columns(scalars=np.array(accel)))
            times.clear(), gyro.clear(), accel.clear()

    def log(self, r: Record) -> None:
        rr, rec, m, topic = self.rr, self.rec, r.message, r.topic
        if self._batch_start is None:
            self._batch_start = r.log_time_ns
        elif r.log_time_ns - self._batch_start >= BATCH_NS:
            self._flush()
            self._batch_start = r.log_time_ns
        if topic == Topic.CAMERA_IMAGE:
            rec.set_time("time", timestamp=np.datetime64(r.log_time_ns, "ns"))
            rec.log("/world/display/camera/image", rr.EncodedImage(contents=m.data, media_type="image/jpeg"))
        elif topic == Topic.CAMERA_CALIBRATION:
            K = np.array(m.K).reshape(3, 3)
            rec.log("/world/display/camera/image", rr.Pinhole(image_from_camera=K, resolution=[m.width, m.height],
                                                                image_plane_distance=0.1), static=True)
        elif topic in (Topic.CAMERA_EXTRINSICS, Topic.GT_CALIBRATION):
            try:
                pose = codec.transform_of(m)
            except codec.BrokenPose:
                return
            path = "/world/display/camera" if topic == Topic.CAMERA_EXTRINSICS else "/world/display_vio"
            self._transform(path, pose, axes=None, static=True)
        elif topic in _POSE_PATHS:
            try:
                pose = codec.pose_of(m.pose)
            except codec.BrokenPose:
                return   # shown as recorded or not at all: a broken pose is not logged
            if topic in (Topic.DISPLAY_ANCHOR, Topic.CONTROLLER_ANCHOR):
                self._anchors[topic] = pose
                return
            self._transform(_POSE_PATHS[topic], pose, t_ns=r.log_time_ns)
            if topic == Topic.CONTROLLER_VIO_POSE and len(self._anchors) == 2:
                mapped = self._anchors[Topic.DISPLAY_ANCHOR] @ self._anchors[Topic.CONTROLLER_ANCHOR].inv() @ pose
                self._transform("/world/display_vio/controller_mapped", mapped, t_ns=r.log_time_ns)
        elif topic == Topic.CONTROLLER_IMU:
            times, gyro, accel = self._imu
            times.append(r.log_time_ns)
            gyro.append((m.gyro_x, m.gyro_y, m.gyro_z))
            accel.append((m.accel_x, m.accel_y, m.accel_z))

    def close(self) -> None:
        """Send what is batched and close the sink: a .rrd gets its footer now, before the caller
        renames it into place (rerun writes the footer only when the sink is dropped)."""
        try:
            self._flush()
            self.rec.flush()
            self.rec.disconnect()
        except Exception:  # pragma: no cover - best effort at shutdown
            pass


BATCH_NS = 200_000_000

_POSE_PATHS = {
    Topic.GT_DISPLAY_POSE: "/world/display",
    Topic.GT_CONTROLLER_POSE: "/world/controller",
    Topic.DISPLAY_VIO_POSE: "/world/display_vio/display",
    Topic.CONTROLLER_VIO_POSE: "/controller_vio/controller",
    Topic.DISPLAY_ANCHOR: None,
    Topic.CONTROLLER_ANCHOR: None,
}


class Recorder:
    def __init__(self, source: Source, out: str | os.PathLike, *, progress: ProgressCallback | None = None,
                 rerun_path: str | os.PathLike | None = None, spawn: bool = False,
                 progress_every_ns: int = 100_000_000, stop_on_signals: bool = True):
        self.source = source
        self.out = os.fspath(out)
        self.progress = progress
        self.progress_every_ns = progress_every_ns
        self.rerun = RerunLogger(os.fspath(rerun_path), False) if rerun_path is not None else \
            (RerunLogger(None, True) if spawn else None)
        self._stop = False
        self.stop_on_signals = stop_on_signals   # False: Ctrl-C / SIGTERM stop the caller (an experiment), not just this

    def stop(self) -> None:
        """Ask the recorder to finish after the current message (signal handlers call this)."""
        self._stop = True

    def run(self) -> RecordResult:
        handlers = self._install_signal_handlers()
        try:
            return self._run()
        finally:
            for sig, old in handlers.items():
                signal.signal(sig, old)
            if self.rerun is not None:
                self.rerun.close()
            self.source.close()

    def _install_signal_handlers(self) -> dict:
        if not self.stop_on_signals or threading.current_thread() is not threading.main_thread():
            return {}
        old = {}
        for sig in (signal.SIGINT, signal.SIGTERM):
            old[sig] = signal.getsignal(sig)
            signal.signal(sig, lambda *_: self.stop())
        return old

    def _run(self) -> RecordResult:
        start = self.source.start_ns
        duration = self.source.duration_ns
        last_per_topic: dict[str, int] = {}
        frames = 0
        first = last = None
        next_progress = start
        with SessionWriter(self.out) as writer:
            for rec in self.source.static():
                self._write(writer, rec, last_per_topic)
            iterator = iter(self.source)
            for rec in iterator:
                if self._stop:
                    break
                self._write(writer, rec, last_per_topic)
                if rec.topic == Topic.CAMERA_IMAGE:
                    frames += 1
                first = rec.log_time_ns if first is None else first
                last = rec.log_time_ns
                if self.progress is not None and rec.log_time_ns >= next_progress:
                    self.progress(rec.log_time_ns - start, duration)
                    next_progress = rec.log_time_ns + self.progress_every_ns
            interrupted = self._stop
            count = writer.message_count
        if self.progress is not None and not interrupted and duration is not None:
            self.progress(duration, duration)
        return RecordResult(self.out, count, (last - first) if first is not None else 0, interrupted, frames)

    def _write(self, writer: SessionWriter, rec: Record, last_per_topic: dict[str, int]) -> None:
        prev = last_per_topic.get(rec.topic)
        if prev is not None and rec.log_time_ns < prev:
            raise SessionContentError(f"source produced {rec.topic} out of log-time order "
                                      f"({rec.log_time_ns} < {prev})")
        last_per_topic[rec.topic] = rec.log_time_ns
        writer.write(rec.topic, rec.message, rec.log_time_ns, rec.publish_time_ns)
        if self.rerun is not None:
            self.rerun.log(rec)
