"""A session opened for a notebook: its topics, span, task window, camera and streams as numpy arrays.

A thin layer over :class:`phonepose.session.SessionReader` (which it keeps open as ``reader``) and
:func:`phonepose.session.context.read_context`; poses are decoded by the codec's rules, as playback does.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from phonepose.errors import ConfigError, SessionContentError
from phonepose.geometry import Pose, RawPose
from phonepose.pipeline.types import CameraModel, MarkerModel, SessionContext
from phonepose.schemas.topics import Topic, message_type_for
from phonepose.session import Message, SessionReader, SessionSummary, codec


@dataclass(frozen=True)
class PoseSeries:
    """The poses of one topic at their log times (the time playback associates by); broken ones skipped."""

    topic: str
    t_ns: np.ndarray          # (N,) int64, log time
    poses: Pose               # N poses, in the topic's frame (docs/format.md)
    skipped: int = 0          # samples whose pose is broken (NaN, not unit, absent): playback skips them too

    def __len__(self) -> int:
        return len(self.t_ns)


@dataclass(frozen=True)
class ImuSeries:
    """The controller's IMU: stamps and calibrated gyro (rad/s) and accelerometer (m/s^2) rows."""

    t_s: np.ndarray           # (N,) the samples' stamps (their log time where unset), s
    gyro: np.ndarray          # (N, 3)
    accel: np.ndarray         # (N, 3)

    def __len__(self) -> int:
        return len(self.t_s)


class Session:
    """An open session (``with phonepose.open_session(path) as s: ...``); InputFileError / DamagedFileError
    when the file cannot be read, as every command."""

    def __init__(self, path: str | os.PathLike):
        self.reader = SessionReader(path)
        self.path = self.reader.path

    # ------------------------------------------------------------------ what it holds
    @cached_property
    def summary(self) -> SessionSummary:
        return self.reader.summary()

    @property
    def topics(self) -> list[str]:
        """The topics with at least one message, sorted."""
        return sorted({c.topic for c in self.summary.channels if c.count > 0})

    @property
    def counts(self) -> dict[str, int]:
        """Messages per topic."""
        out: dict[str, int] = {}
        for c in self.summary.channels:
            out[c.topic] = out.get(c.topic, 0) + c.count
        return dict(sorted(out.items()))

    @property
    def span(self) -> tuple[int, int]:
        """The first and last message's log time, ns."""
        return self.summary.start_ns, self.summary.end_ns

    @property
    def duration_s(self) -> float:
        return self.summary.duration_s

    @cached_property
    def task_window(self) -> tuple[int, int] | None:
        """``/session/info``'s task start and end (log-time ns); None when the session does not say."""
        info = self.reader.first(Topic.SESSION_INFO) if self.summary.has(Topic.SESSION_INFO) else None
        if info is None:
            return None
        start, end = info.task_start.ToNanoseconds(), info.task_end.ToNanoseconds()
        return (start, end) if start and end else None

    @cached_property
    def context(self) -> SessionContext:
        """What playback reads before the first tick; SessionContentError when it cannot be played back."""
        from phonepose.session.context import read_context

        return read_context(self.reader)

    @property
    def camera(self) -> CameraModel | None:
        """The display camera's calibration (K, D plumb_bob, size, pose on the display); None without images."""
        from phonepose.session.context import has_camera

        return self.context.camera if has_camera(self.context) else None

    @property
    def marker(self) -> MarkerModel | None:
        return self.context.marker if self.context.marker.id >= 0 else None

    # ------------------------------------------------------------------ streams
    def messages(self, topics: Iterable[str] | None = None, start_ns: int | None = None,
                 end_ns: int | None = None) -> Iterator[Message]:
        """The decoded messages in log-time order (:meth:`SessionReader.messages`)."""
        return self.reader.messages(topics, start_ns, end_ns)

    def log_times(self, topic: str) -> np.ndarray:
        """Every message's log time on ``topic`` (ns, int64, sorted)."""
        self._check_topic(topic)
        return np.sort(self.reader.log_times()[topic].astype(np.int64))

    def poses(self, topic: str = Topic.CONTROLLER_VIO_POSE) -> PoseSeries:
        """A pose topic (``/controller/vio/pose``, ``/gt/controller/pose``, ``/trackers/T8/pose``...) as arrays."""
        self._check_topic(topic)
        if not _is_pose_topic(topic):
            raise ConfigError(f"{topic}: not a pose topic (PoseInFrame); pose topics of {self.path}: "
                              f"{', '.join(t for t in self.topics if _is_pose_topic(t)) or 'none'}")
        t: list[int] = []
        raws: list[RawPose] = []
        skipped = 0
        for m in self.reader.messages([topic]):
            try:
                raws.append(codec.raw_pose(m.msg.pose))
            except codec.BrokenPose:
                skipped += 1
                continue
            t.append(m.log_time_ns)
        if not raws:
            raise SessionContentError(f"{self.path}: no usable pose on {topic} ({skipped} broken)")
        arr = np.asarray(raws, dtype=float)
        return PoseSeries(topic, np.asarray(t, np.int64), Pose.from_xyzw(arr[:, 4:], arr[:, :4]), skipped)

    def imu(self) -> ImuSeries:
        """``/controller/imu`` as arrays (the rows playback hands the trackers, unchecked values included)."""
        self._check_topic(Topic.CONTROLLER_IMU)
        rows = np.asarray([codec.imu_row(m.msg, m.log_time_ns) for m in self.reader.messages([Topic.CONTROLLER_IMU])],
                          dtype=float).reshape(-1, 7)
        return ImuSeries(rows[:, 0].copy(), rows[:, 1:4].copy(), rows[:, 4:7].copy())

    def _check_topic(self, topic: str) -> None:
        if topic not in self.topics:
            raise SessionContentError(f"{self.path}: no {topic}; its topics: {', '.join(self.topics)}")

    # ------------------------------------------------------------------ lifetime
    def close(self) -> None:
        self.reader.close()

    def __enter__(self) -> Session:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"Session({self.path!r}, {len(self.topics)} topics, {self.duration_s:.1f} s)"


def _is_pose_topic(topic: str) -> bool:
    from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame

    try:
        return message_type_for(topic) is PoseInFrame
    except KeyError:    # a topic phonepose does not know
        return False


def open_session(path: str | os.PathLike) -> Session:
    """Open a session (.mcap) for reading; close it with ``close()`` or a ``with`` block."""
    return Session(path)
