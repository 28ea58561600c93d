"""Recorder: pulls records from a :class:`~phonepose.record.source.Source` and writes one session.

It writes the source's static part first, then the stream, through
:class:`~phonepose.session.SessionWriter` (the writer flushes about once a second of log
time, so a SIGKILL loses at most ~1 s). SIGINT / SIGTERM set a flag: the loop stops after the
current message and the ``with`` block finishes a valid file. Optionally everything recorded
is also logged to Rerun (saved to an .rrd file or streamed to a spawned viewer:
:mod:`phonepose.record.rerun_log`). Beside every record it writes the frame-tree messages
:class:`~phonepose.viewer.frames.FrameTree` derives from it (``/tf/...``), so the session shows in
3D in Rerun and Foxglove as it is.
"""

from __future__ import annotations

import os
import signal
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from phonepose.errors import OutputError, SessionContentError
from phonepose.record.source import Record, Source
from phonepose.schemas.topics import Topic
from phonepose.session import SessionWriter
from phonepose.viewer.frames import FrameTree

if TYPE_CHECKING:
    from phonepose.record.rerun_log import RecordRerunLogger

ProgressCallback = Callable[[int, int | None], None]   # (log time done since start, duration) in ns


@dataclass
class RecordResult:
    path: str
    messages: int
    duration_ns: int          # log time covered (first to last message)
    interrupted: bool         # stopped by SIGINT / SIGTERM before the source ended
    frames: int               # camera images written


class Recorder:
    def __init__(self, source: Source, out: str | os.PathLike, *, progress: ProgressCallback | None = None,
                 rerun_path: str | os.PathLike | None = None, spawn: bool = False,
                 progress_every_ns: int = 100_000_000, stop_on_signals: bool = True,
                 flush_every_ns: int | None = None):
        self.source = source
        self.flush_every_ns = flush_every_ns   # None: the writer's default (about once a second of log time)
        self.out = os.fspath(out)
        self.progress = progress
        self.progress_every_ns = progress_every_ns
        self.rerun_path = os.fspath(rerun_path) if rerun_path is not None else None
        self.spawn = spawn
        self.rerun: RecordRerunLogger | None = None   # opened in run(): its recording id is made from the static part
        self.frames = FrameTree()
        self._stop = False
        self.stop_on_signals = stop_on_signals   # False: Ctrl-C / SIGTERM stop the caller (an experiment), not just this

    def stop(self) -> None:
        """Ask the recorder to finish after the current message (signal handlers call this)."""
        self._stop = True

    def run(self) -> RecordResult:
        handlers = self._install_signal_handlers()
        done = False
        try:
            static = list(self.source.static())
            if self.rerun_path is not None or self.spawn:
                from phonepose.record.rerun_log import open_record_logger
                self.rerun = open_record_logger(self.out, static, rrd_path=self.rerun_path, spawn=self.spawn,
                                                source=_source_kind(static))
            result = self._run(static)
            done = True
            return result
        finally:
            for sig, old in handlers.items():
                signal.signal(sig, old)
            try:
                if self.rerun is not None:
                    self._close_rerun(report=done)
            finally:
                self.source.close()

    def _close_rerun(self, report: bool) -> None:
        """A .rrd that could not be written whole is an error of its own (its temporary is removed, never put
        in place); after another error, that one is the line the user reads."""
        assert self.rerun is not None
        try:
            self.rerun.close()
        except OutputError:
            if report:
                raise

    def _install_signal_handlers(self) -> dict:
        if not self.stop_on_signals or threading.current_thread() is not threading.main_thread():
            return {}
        old = {}
        for sig in (signal.SIGINT, signal.SIGTERM):
            old[sig] = signal.getsignal(sig)
            signal.signal(sig, lambda *_: self.stop())
        return old

    def _run(self, static: list[Record]) -> RecordResult:
        start = self.source.start_ns
        duration = self.source.duration_ns
        last_per_topic: dict[str, int] = {}
        frames = 0
        first: int | None = None
        last: int | None = None
        next_progress = start
        flush: dict[str, Any] = {} if self.flush_every_ns is None else {"flush_every_ns": self.flush_every_ns}
        with SessionWriter(self.out, **flush) as writer:
            for rec in static:
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
            metadata = getattr(self.source, "metadata", None)   # a source's figures known only at the end
            for name, data in (metadata() if callable(metadata) else {}).items():
                writer.add_metadata(name, data)
            count = writer.message_count
        if self.progress is not None and not interrupted and duration is not None:
            self.progress(duration, duration)
        return RecordResult(self.out, count, (last - first) if first is not None and last is not None else 0, interrupted, frames)

    def _write(self, writer: SessionWriter, rec: Record, last_per_topic: dict[str, int]) -> None:
        prev = last_per_topic.get(rec.topic)
        if prev is not None and rec.log_time_ns < prev:
            raise SessionContentError(f"source produced {rec.topic} out of log-time order "
                                      f"({rec.log_time_ns} < {prev})")
        last_per_topic[rec.topic] = rec.log_time_ns
        writer.write(rec.topic, rec.message, rec.log_time_ns, rec.publish_time_ns)
        for topic, msg in self.frames.derive(rec.topic, rec.message, rec.log_time_ns):
            writer.write(topic, msg, rec.log_time_ns, rec.publish_time_ns)
        if self.rerun is not None:
            self.rerun.log(rec)


def _source_kind(static: list[Record]) -> str:
    """``sim``, ``phone``, ... from the session info, for the Rerun recording's name."""
    for r in static:
        if r.topic == Topic.SESSION_INFO:
            return r.message.source
    return ""
