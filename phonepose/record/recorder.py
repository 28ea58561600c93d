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
from phonepose.record.source import Record, Source
from phonepose.schemas.topics import Topic
from phonepose.session import SessionWriter

ProgressCallback = Callable[[int, int | None], None]   # (log time done since start, duration) in ns


@dataclass
class RecordResult:
    path: str
    messages: int
    duration_ns: int          # log time covered (first to last message)
    interrupted: bool         # stopped by SIGINT / SIGTERM before the source ended
    frames: int               # camera images written


class RerunLogger:
    """Logs what is being recorded: camera images (the JPEG bytes as they are), GT and VIO poses, IMU."""

    def __init__(self, rrd_path: str | None = None, spawn: bool = False, application_id: str = "phonepose_record"):
        import rerun as rr

        self.rr = rr
        self.rec = rr.RecordingStream(application_id)
        try:
            if spawn:
                self.rec.spawn()
            elif rrd_path is not None:
                parent = os.path.dirname(os.path.abspath(rrd_path))
                if not os.path.isdir(parent) or not os.access(parent, os.W_OK):
                    raise OutputError(f"cannot write {rrd_path}: directory {parent} does not exist or is not writable")
                self.rec.save(rrd_path)
        except RuntimeError as exc:   # rerun reports sink failures as RuntimeError
            raise OutputError(f"cannot start Rerun logging ({rrd_path or 'viewer'}): {exc}") from None
        self.rec.log("/world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)

    def log(self, r: Record) -> None:
        rr, rec, m = self.rr, self.rec, r.message
        rec.set_time("time", timestamp=np.datetime64(r.log_time_ns, "ns"))
        if r.topic == Topic.CAMERA_IMAGE:
            rec.log("/camera/image", rr.EncodedImage(contents=m.data, media_type="image/jpeg"))
        elif r.topic == Topic.CAMERA_CALIBRATION:
            K = np.array(m.K).reshape(3, 3)
            rec.log("/camera/image", rr.Pinhole(image_from_camera=K, resolution=[m.width, m.height]), static=True)
        elif r.topic in (Topic.GT_CONTROLLER_POSE, Topic.GT_DISPLAY_POSE, Topic.DISPLAY_VIO_POSE,
                         Topic.CONTROLLER_VIO_POSE):
            p, q = m.pose.position, m.pose.orientation
            root = "/world" if m.frame_id == "world" else f"/{m.frame_id}"
            path = f"{root}{r.topic}"
            rec.log(path, rr.Transform3D(translation=[p.x, p.y, p.z], quaternion=[q.x, q.y, q.z, q.w]),
                    rr.TransformAxes3D(0.05))
        elif r.topic == Topic.CONTROLLER_IMU:
            rec.log("/imu/gyro", rr.Scalars([m.gyro_x, m.gyro_y, m.gyro_z]))
            rec.log("/imu/accel", rr.Scalars([m.accel_x, m.accel_y, m.accel_z]))

    def close(self) -> None:
        try:
            self.rec.flush()
        except Exception:  # pragma: no cover - best effort at shutdown
            pass


class Recorder:
    def __init__(self, source: Source, out: str | os.PathLike, *, progress: ProgressCallback | None = None,
                 rerun_path: str | os.PathLike | None = None, spawn: bool = False,
                 progress_every_ns: int = 100_000_000):
        self.source = source
        self.out = os.fspath(out)
        self.progress = progress
        self.progress_every_ns = progress_every_ns
        self.rerun = RerunLogger(os.fspath(rerun_path), False) if rerun_path is not None else \
            (RerunLogger(None, True) if spawn else None)
        self._stop = False

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
        if threading.current_thread() is not threading.main_thread():
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
