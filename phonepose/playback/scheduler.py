"""The tick scheduler: one streaming pass over a session, a :class:`Tick` every 1/rate s.

The tick rule (docs/playback.md):

* Ticks lie on a grid ``t_k = t0 + k / rate`` where ``t0`` is the first camera frame (or the
  first controller VIO sample when the session has no camera). ``--start/--end`` select the
  grid ticks inside ``[start, end]`` (seconds after the session's first message).
* A tick at ``t`` carries every message with ``log_time <= t`` and nothing later: the newest
  camera frame at or before ``t`` (a :class:`Frame`, ``is_new`` if the previous tick did not carry it), the
  display VIO pose interpolated at that frame's stamp, the controller VIO pose interpolated at
  ``t``, the latest anchors, the IMU rows and calibration events with ``t_prev < log_time <= t``,
  and the ground truth associated as the TUM benchmark does: interpolated at ``t`` from the two
  mocap samples around it when both lie within ``gt_tolerance_s`` (0.02 s) of ``t``, else None.
* Interpolating at ``t`` needs the first sample *after* ``t``. So the scheduler reads slightly
  past a tick before emitting it: the tick at ``t`` is emitted once every interpolated stream
  has shown a sample with ``log_time > t``, or the file has been read ``max_gap_s`` past ``t``
  (``gt_tolerance_s`` for GT), or the file ended. Trackers still see nothing from the future:
  the only later sample used is the one that bounds the interpolation interval around ``t``.
* When a VIO stream has a gap longer than ``max_gap_s`` around ``t``, the last sample at or
  before ``t`` is held if it is at most ``max_gap_s`` old; otherwise the pose is None.

Memory stays small: per pose stream only the samples from the last one at or before the
oldest pending query onwards, and the messages between the last emitted tick and the read
position (at most ``max_gap_s`` of data).
"""

from __future__ import annotations

import bisect
import logging
from collections import Counter, deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from phonepose.errors import ConfigError, SessionContentError
from phonepose.geometry import Pose, RawPose, raw_compose, raw_interpolate
from phonepose.pipeline.types import CalibrationEvent, CalibrationKind, Frame, SessionContext, Tick
from phonepose.schemas.topics import Topic
from phonepose.session import SessionReader, codec
from phonepose.session.index import main_span

log = logging.getLogger("phonepose")

DEFAULT_RATE_HZ = 20.0
GT_TOLERANCE_S = 0.02
MAX_GAP_S = 0.5
# A stretch this long without any message gets no ticks: every stream's pose is None there and no
# tracker has input, so planning its ticks would only bound the work by the clock instead of the data.
IDLE_GAP_S = 10.0
OPEN_END_NS = 2**62        # the last tick of a live feed's grid: none (finish() names the real end)
OUTLIER = "log time more than an hour away from the rest of the session"

SCHEDULED_TOPICS = (
    Topic.CAMERA_IMAGE, Topic.DISPLAY_VIO_POSE, Topic.CONTROLLER_VIO_POSE, Topic.DISPLAY_ANCHOR,
    Topic.CONTROLLER_ANCHOR, Topic.CONTROLLER_IMU, Topic.CALIBRATION_EVENTS, Topic.GT_CONTROLLER_POSE,
)


def _pose(raw: RawPose | None) -> Pose | None:
    return None if raw is None else Pose.from_raw(raw)


class PoseStream:
    """Stamped raw poses of one stream, kept from the last sample at or before the oldest query on."""

    def __init__(self) -> None:
        self.times: deque[int] = deque()
        self.poses: deque = deque()

    def add(self, t_ns: int, pose) -> None:
        if isinstance(pose, Pose):
            pose = pose.as_raw()
        if self.times and t_ns < self.times[-1]:
            return  # out of order on this stream: drop (the reader orders by log_time, so never here)
        self.times.append(t_ns)
        self.poses.append(pose)

    @property
    def last_ns(self) -> int | None:
        return self.times[-1] if self.times else None

    def has_after(self, t_ns: int) -> bool:
        return bool(self.times) and self.times[-1] > t_ns

    def prune(self, t_ns: int) -> None:
        """Forget samples that no query at or after ``t_ns`` can use."""
        while len(self.times) >= 2 and self.times[1] <= t_ns:
            self.times.popleft()
            self.poses.popleft()

    def raw_at(self, t_ns: int, max_gap_ns: int):
        """Interpolated at ``t`` between the samples around it; hold the last one across gaps."""
        times = self.times
        if not times or times[0] > t_ns:
            return None
        i = bisect.bisect_right(times, t_ns) - 1          # last sample at or before t
        t0 = times[i]
        if t0 == t_ns:
            return self.poses[i]
        if i + 1 < len(times):
            t1 = times[i + 1]
            if t1 - t0 <= max_gap_ns:
                return raw_interpolate(self.poses[i], self.poses[i + 1], (t_ns - t0) / (t1 - t0))
        if t_ns - t0 <= max_gap_ns:
            return self.poses[i]
        return None

    def raw_associate(self, t_ns: int, tol_ns: int):
        """TUM-style association: interpolate only if samples lie within ``tol`` on both sides."""
        times = self.times
        if not times:
            return None
        i = bisect.bisect_right(times, t_ns) - 1
        if i < 0:
            return None
        t0 = times[i]
        if t0 == t_ns:
            return self.poses[i]
        if i + 1 >= len(times):
            return None
        t1 = times[i + 1]
        if t_ns - t0 > tol_ns or t1 - t_ns > tol_ns:
            return None
        return raw_interpolate(self.poses[i], self.poses[i + 1], (t_ns - t0) / (t1 - t0))

    def at(self, t_ns: int, max_gap_ns: int) -> Pose | None:
        return _pose(self.raw_at(t_ns, max_gap_ns))

    def associate(self, t_ns: int, tol_ns: int) -> Pose | None:
        return _pose(self.raw_associate(t_ns, tol_ns))


@dataclass
class ScheduleInfo:
    t0_ns: int              # grid origin (first camera frame or first controller VIO)
    first_tick_ns: int
    last_tick_ns: int
    period_ns: int
    session_start_ns: int

    @property
    def n_ticks(self) -> int:
        if self.last_tick_ns < self.first_tick_ns:
            return 0
        return (self.last_tick_ns - self.first_tick_ns) // self.period_ns + 1


_POSE_TOPICS = frozenset((Topic.DISPLAY_VIO_POSE, Topic.CONTROLLER_VIO_POSE, Topic.GT_CONTROLLER_POSE,
                          Topic.DISPLAY_ANCHOR, Topic.CONTROLLER_ANCHOR))


def _check_task_overlap(context: SessionContext, start_ns: int, first: int, last: int, start_s: float | None,
                        end_s: float | None) -> None:
    """--start/--end that miss the task window score nothing and write empty trajectories: one line
    naming both ranges (seconds after the session start), before any work."""
    t0, t1 = context.task_start_ns, context.task_end_ns
    if t0 is None or t1 is None or (last >= t0 and first <= t1):
        return
    named = [(name, v) for name, v in (("start", start_s), ("end", end_s)) if v is not None]
    given = " ".join(f"{{{name}}} {v:g}" for name, v in named)
    raise ConfigError(f"{given} selects {(first - start_ns) / 1e9:.2f}-{(last - start_ns) / 1e9:.2f} s, which misses "
                      f"the task window {(t0 - start_ns) / 1e9:.2f}-{(t1 - start_ns) / 1e9:.2f} s (where trajectories "
                      "and metrics are computed): choose a range that overlaps it", parameter=named[0][0],
                      value=named[0][1], also=[name for name, _ in named[1:]])


class TickScheduler:
    """Iterate ``Tick`` objects over one pass of ``reader`` (see the module docstring)."""

    def __init__(self, reader: SessionReader, context: SessionContext, *, rate_hz: float = DEFAULT_RATE_HZ,
                 start_s: float | None = None, end_s: float | None = None,
                 gt_tolerance_s: float = GT_TOLERANCE_S, max_gap_s: float = MAX_GAP_S, gt_calibration=None,
                 gt_series=None):
        """``gt_calibration`` (a calibration.gt_calibration.GtCalibration) re-expresses the ground truth in
        the phone's frame and on its clock: T_world_grip · X⁻¹, read ``time_offset_s`` later, and in
        display_vio by its T_world_display_vio when it has one (else the session's /gt/calibration).
        ``gt_series`` (a calibration.ground_truth.GroundTruthSeries, ``--gt FILE``) replaces the session's
        /gt/controller/pose."""
        self.reader: SessionReader | None = reader
        summary = reader.summary()
        self._configure(context, rate_hz=rate_hz, gt_tolerance_s=gt_tolerance_s, max_gap_s=max_gap_s,
                        gt_calibration=gt_calibration, gt_series=gt_series,
                        has_camera=summary.has(Topic.CAMERA_IMAGE), gt_topic=summary.has(Topic.GT_CONTROLLER_POSE))
        origin_topic = Topic.CAMERA_IMAGE if self.has_camera else Topic.CONTROLLER_VIO_POSE
        start_ns, end_ns = self._span(reader, summary)
        self.span_ns = (start_ns, end_ns)
        t0 = None
        for _schema, _channel, m in reader.raw_messages([origin_topic], start_ns=start_ns, end_ns=end_ns + 1):
            t0 = m.log_time
            break
        if t0 is None:
            raise SessionContentError(f"{reader.path}: {origin_topic} has no messages")
        first, last = self._grid(t0, start_ns, end_ns, start_s, end_s)
        self.info = ScheduleInfo(t0_ns=t0, first_tick_ns=first, last_tick_ns=last, period_ns=self.period_ns,
                                 session_start_ns=start_ns)

    def _configure(self, context: SessionContext, *, rate_hz: float, gt_tolerance_s: float, max_gap_s: float,
                   gt_calibration, gt_series, has_camera: bool, gt_topic: bool) -> None:
        """What a pass needs besides the grid: the same for a file and for a live feed."""
        if not rate_hz > 0:
            raise ConfigError(f"{{rate}} must be > 0 (got {rate_hz})", parameter="rate", value=rate_hz, expected="> 0")
        self.context = context
        self.rate_hz = float(rate_hz)
        self.period_ns = int(round(1e9 / self.rate_hz))
        self.gt_tol_ns = int(round(gt_tolerance_s * 1e9))
        self.max_gap_ns = int(round(max_gap_s * 1e9))
        self.has_camera = has_camera
        cal = gt_calibration
        T_world_dvio = context.T_world_display_vio
        if cal is not None and cal.T_world_display_vio is not None:
            T_world_dvio = cal.T_world_display_vio
        self._gt_series = gt_series
        self.has_gt = (gt_series is not None or gt_topic) and T_world_dvio is not None
        self._T_dvio_world = T_world_dvio.inv().as_raw() if T_world_dvio is not None else None
        self._T_mocap_controller = cal.T_controller_gt.inv().as_raw() if cal is not None else None
        self._gt_shift_ns = int(round(cal.time_offset_s * 1e9)) if cal is not None else 0
        self._gt_wait_ns = self.gt_tol_ns + max(self._gt_shift_ns, 0)   # how far past a tick its GT may lie in the file
        # (topic, reason) -> samples skipped in the pass; reported as one warning line each
        self.skipped: Counter = Counter()
        self.idle_gap_ns = int(IDLE_GAP_S * 1e9)
        self.ticks_skipped = 0      # grid ticks inside stretches of more than IDLE_GAP_S without data

    @classmethod
    def streaming(cls, context: SessionContext, t0_ns: int, *, has_camera: bool, gt_topic: bool = False,
                  rate_hz: float = DEFAULT_RATE_HZ, gt_tolerance_s: float = GT_TOLERANCE_S,
                  max_gap_s: float = MAX_GAP_S) -> TickScheduler:
        """A scheduler fed message by message (:meth:`feed`) instead of reading a file: the grid starts at
        ``t0_ns`` (the first camera frame, or the first controller VIO sample without camera) and is open-ended."""
        self = cls.__new__(cls)
        self.reader = None
        self._configure(context, rate_hz=rate_hz, gt_tolerance_s=gt_tolerance_s, max_gap_s=max_gap_s,
                        gt_calibration=None, gt_series=None, has_camera=has_camera, gt_topic=gt_topic)
        self.span_ns = (t0_ns, OPEN_END_NS)
        self.info = ScheduleInfo(t0_ns=t0_ns, first_tick_ns=t0_ns, last_tick_ns=OPEN_END_NS, period_ns=self.period_ns,
                                 session_start_ns=t0_ns)
        return self

    def feed(self) -> TickFeed:
        """The pass as a push interface: give it the scheduled messages in log-time order."""
        return TickFeed(self)

    def _grid(self, t0: int, start_ns: int, end_ns: int, start_s: float | None,
              end_s: float | None) -> tuple[int, int]:
        """The first and last tick of the grid ``t0 + k / rate`` inside ``[start, end]``."""
        first = t0
        if start_s is not None:
            lo = start_ns + int(round(start_s * 1e9))
            if lo > first:
                first = t0 + -(-(lo - t0) // self.period_ns) * self.period_ns
        last_limit = end_ns
        if end_s is not None:
            last_limit = min(last_limit, start_ns + int(round(end_s * 1e9)))
        last = first + max(-1, (last_limit - first) // self.period_ns) * self.period_ns
        if last < first and (start_s is not None or end_s is not None):
            raise ConfigError(f"{{start}}/{{end}} select no tick: the session runs {(end_ns - start_ns) / 1e9:.2f} s and "
                              f"its first tick is at {(t0 - start_ns) / 1e9:.2f} s", parameter="start", value=start_s,
                              also=["end"])
        if start_s is not None or end_s is not None:
            _check_task_overlap(self.context, start_ns, first, last, start_s, end_s)
        return first, last

    def _span(self, reader: SessionReader, summary) -> tuple[int, int]:
        """The session's time span without time outliers (counted into ``skipped``): a far-future or
        far-past log time would otherwise set the span the ticks and --start/--end are planned on."""
        times = reader.log_times()
        span = main_span(np.concatenate(list(times.values()))) if times else None
        if span is None:
            return summary.start_ns, summary.end_ns
        for topic, ts in times.items():
            n = int(np.count_nonzero((ts < span[0]) | (ts > span[1])))
            if n:
                self.skipped[(topic, OUTLIER)] += n
        return span

    def __len__(self) -> int:
        return self.info.n_ticks

    # ------------------------------------------------------------------ the pass
    def __iter__(self) -> Iterator[Tick]:
        """The ticks alone (what trackers may see)."""
        for tick, _gt in self.with_truth():
            yield tick

    def with_truth(self) -> Iterator[tuple[Tick, Pose | None]]:
        """``(tick, ground truth)`` pairs: the GT stays beside the tick, for the engine and the metrics."""
        info = self.info
        if info.n_ticks == 0:
            return
        feed = TickFeed(self)
        # Nothing after this is needed: the last tick plus the look-ahead.
        read_end = info.last_tick_ns + max(self.max_gap_ns, self._gt_wait_ns) + 1
        assert self.reader is not None   # a file's scheduler
        for m in self.reader.messages(SCHEDULED_TOPICS, start_ns=self.span_ns[0],
                                      end_ns=min(read_end, self.span_ns[1] + 1)):
            yield from feed.feed(m.topic, m.msg, m.log_time_ns)
        yield from feed.finish()
        for (topic, reason), n in sorted(self.skipped.items()):
            log.warning("%s: %d sample(s) skipped: %s", topic, n, reason)


class TickFeed:
    """One pass, fed message by message in log-time order: :meth:`feed` returns the ticks that message
    completes (the tick rule of the module docstring), :meth:`finish` the rest. A file's pass and a live
    feed (phonepose.record.live.tracking) both run through it, so both form the very same ticks."""

    def __init__(self, sched: TickScheduler) -> None:
        self.s = sched
        self.state = _PassState(sched)
        self.last_message_ns: int | None = None

    def feed(self, topic: str, msg, now: int) -> list[tuple[Tick, Pose | None]]:
        """The ticks due before ``msg`` (log time ``now``) is taken in, then takes it in."""
        s, state, info = self.s, self.state, self.s.info
        out: list[tuple[Tick, Pose | None]] = []
        if self.last_message_ns is not None and now - self.last_message_ns > s.idle_gap_ns:
            out.extend(self._across_idle_gap(self.last_message_ns, now))
        self.last_message_ns = now
        while state.next_t <= info.last_tick_ns and state.next_t < now and state.ready(state.next_t, now):
            out.append(state.build())
        state.ingest(topic, msg, now)
        return out

    def finish(self, last_tick_ns: int | None = None) -> list[tuple[Tick, Pose | None]]:
        """Every tick left up to the grid's last (``last_tick_ns`` for an open-ended grid)."""
        end = self.s.info.last_tick_ns if last_tick_ns is None else min(last_tick_ns, self.s.info.last_tick_ns)
        out = []
        while self.state.next_t <= end:
            out.append(self.state.build())
        return out

    def _across_idle_gap(self, last_message_ns: int, now: int) -> list[tuple[Tick, Pose | None]]:
        """The ticks the data before a gap of more than IDLE_GAP_S supports, then none until the data resumes."""
        s, state, info = self.s, self.state, self.s.info
        out = []
        hold = last_message_ns + max(s.max_gap_ns, s._gt_wait_ns)
        while state.next_t <= info.last_tick_ns and state.next_t <= hold:
            out.append(state.build())
        resume = info.t0_ns + -(-(now - info.t0_ns) // s.period_ns) * s.period_ns
        if resume > state.next_t:
            s.ticks_skipped += (min(resume, info.last_tick_ns + s.period_ns) - state.next_t) // s.period_ns
            state.next_t = resume
        return out


def _event_pose(fg) -> Pose | None:
    """A CalibrationEvent pose by the codec's rules (docs/format.md), or None if it is unset or broken."""
    try:
        return codec.pose_of(fg)
    except codec.BrokenPose:
        return None


_KINDS = {int(k): k for k in CalibrationKind}


def calibration_event(msg, log_time_ns: int) -> CalibrationEvent:
    """A ``phonepose.CalibrationEvent`` message as the pipeline's :class:`CalibrationEvent`."""
    fix_t = codec.timestamp_ns(msg.fix_timestamp) if msg.HasField("fix_timestamp") else None
    return CalibrationEvent(kind=_KINDS.get(msg.kind, msg.kind), t_ns=codec.stamp_ns(msg, log_time_ns),
                            log_time_ns=log_time_ns, frame_id=msg.frame_id,
                            pose_fix_vio=_event_pose(msg.pose_fix_vio), pose_align_vio=_event_pose(msg.pose_align_vio),
                            fix_t_ns=fix_t)


def _take(queue: list, t_ns: int) -> list:
    """Remove and return the leading ``(log_time, ...)`` items with ``log_time <= t``."""
    k = 0
    while k < len(queue) and queue[k][0] <= t_ns:
        k += 1
    taken = queue[:k]
    del queue[:k]
    return taken


class _PassState:
    """What one pass holds between messages and ticks: ``ingest`` a message, ask whether the next
    tick is ``ready``, ``build`` it (see the module docstring for the rule)."""

    def __init__(self, sched: TickScheduler) -> None:
        self.s = sched
        self.next_t = sched.info.first_tick_ns
        self.index = 0
        self.before_first_ns = sched.info.first_tick_ns - sched.period_ns   # end of the interval before the first tick
        self.display = PoseStream()
        self.controller = PoseStream()
        self.gt = PoseStream()
        if sched.has_gt and sched._gt_series is not None:    # a sidecar file: all of it, on the recorder's clock
            for t_ns, raw in zip(*sched._gt_series.raw_samples(), strict=True):
                self.gt.add(int(t_ns) - sched._gt_shift_ns, raw)
        self.images: deque = deque()        # (log_time, CompressedImage), newest at or before next tick kept
        self.d_anchors: deque = deque()     # (log_time, Pose)
        self.c_anchors: deque = deque()
        self.imu: list = []                 # (log_time, row)
        self.cvio_samples: list = []        # (log_time, capture_ns, raw): controller VIO with its capture stamp
        self.events: list = []              # (log_time, pipeline CalibrationEvent)
        self.image: tuple[bytes, str] | None = None   # the newest frame carried so far (data, format), and its log_time
        self.image_t: int | None = None
        self.display_cache: tuple = (None, None)
        self.d_anchor: Pose | None = None
        self.c_anchor: Pose | None = None
        self.last_stamp: dict[str, tuple[int, int]] = {}   # topic -> (log_time, header stamp) of the last sample used
        # each handler takes (message, log_time, raw pose): the raw pose is None for topics that carry none
        self.handlers: dict[str, Callable[[Any, int, Any], None]] = {
            Topic.CAMERA_IMAGE: self._image, Topic.DISPLAY_VIO_POSE: self._display_vio,
            Topic.CONTROLLER_VIO_POSE: self._controller_vio, Topic.GT_CONTROLLER_POSE: self._gt,
            Topic.DISPLAY_ANCHOR: self._display_anchor, Topic.CONTROLLER_ANCHOR: self._controller_anchor,
            Topic.CONTROLLER_IMU: self._imu, Topic.CALIBRATION_EVENTS: self._event,
        }

    # ---------------------------------------------------------------- ingest
    def ingest(self, topic: str, msg, now: int) -> None:
        """One message of the pass, in log_time order."""
        if topic != Topic.CALIBRATION_EVENTS and self._out_of_order(topic, msg, now):
            return
        raw = None
        if topic in _POSE_TOPICS:
            try:
                raw = codec.raw_pose(msg.pose)
            except codec.BrokenPose as exc:
                self.s.skipped[(topic, exc.reason)] += 1
                return
        self.handlers[topic](msg, now, raw)

    def _out_of_order(self, topic: str, msg, now: int) -> bool:
        """Duplicate or backwards timestamps on one stream: skipped and reported, never used.

        Judged by the header stamp only: controller streams carry the receipt time as log_time,
        so several samples of one network packet share it legitimately."""
        stamp = codec.timestamp_ns(msg.timestamp)
        prev = self.last_stamp.get(topic)
        if prev is not None and stamp and prev[1] and stamp <= prev[1]:
            self.s.skipped[(topic, "duplicate or non-monotonic timestamp")] += 1
            return True
        self.last_stamp[topic] = (now, stamp)
        return False

    def _image(self, msg, now: int, raw: RawPose | None) -> None:
        self.images.append((now, msg))
        # bound the queue: only the newest frame at or before the next tick matters
        while len(self.images) >= 2 and self.images[1][0] <= self.next_t:
            self.images.popleft()

    def _display_vio(self, msg, now: int, raw: RawPose | None) -> None:
        self.display.add(now, raw)

    def _controller_vio(self, msg, now: int, raw: RawPose | None) -> None:
        self.controller.add(now, raw)
        if now > self.before_first_ns:   # else before the first tick's interval
            self.cvio_samples.append((now, codec.stamp_ns(msg, now), raw))

    def _gt(self, msg, now: int, raw: RawPose | None) -> None:
        if self.s.has_gt and self.s._gt_series is None:
            self.gt.add(now - self.s._gt_shift_ns, raw)

    def _display_anchor(self, msg, now: int, raw: RawPose) -> None:
        self.d_anchors.append((now, Pose.from_raw(raw)))

    def _controller_anchor(self, msg, now: int, raw: RawPose) -> None:
        self.c_anchors.append((now, Pose.from_raw(raw)))

    def _imu(self, msg, now: int, raw: RawPose | None) -> None:
        if now <= self.before_first_ns:
            return  # before the first tick's interval (--start): nobody will read it
        row = codec.imu_row(msg, now)
        problem = codec.imu_problem(row)
        if problem is not None:
            self.s.skipped[(Topic.CONTROLLER_IMU, problem)] += 1
            return
        self.imu.append((now, row))

    def _event(self, msg, now: int, raw: RawPose | None) -> None:
        self.events.append((now, calibration_event(msg, now)))

    # ---------------------------------------------------------------- ready / build
    def ready(self, t: int, now: int) -> bool:
        """Every interpolated stream has shown a sample after ``t``, or waiting longer is pointless."""
        s = self.s
        if not self.controller.has_after(t) and now - t <= s.max_gap_ns:
            return False
        if s.has_camera and not self.display.has_after(t) and now - t <= s.max_gap_ns:
            return False
        if s.has_gt and not self.gt.has_after(t) and now - t <= s._gt_wait_ns:
            return False
        return True

    def build(self) -> tuple[Tick, Pose | None]:
        """The tick at ``next_t`` and its ground truth; then forget what no later tick can use."""
        t, s = self.next_t, self.s
        new_image = self._advance_frame(t)
        while self.d_anchors and self.d_anchors[0][0] <= t:
            self.d_anchor = self.d_anchors.popleft()[1]
        while self.c_anchors and self.c_anchors[0][0] <= t:
            self.c_anchor = self.c_anchors.popleft()[1]
        rows = np.array([r for _, r in _take(self.imu, t)], dtype=float).reshape(-1, 7)
        evs = [e for _, e in _take(self.events, t)]
        vio_samples = [(c, Pose.from_raw(r)) for _, c, r in _take(self.cvio_samples, t)]
        T_dvio_display = self._display_pose(t)
        frame = None
        if self.image is not None:
            data, fmt = self.image
            assert self.image_t is not None   # set together with self.image
            frame = Frame(data=data, format=fmt, t_ns=self.image_t, is_new=new_image, T_dvio_display=T_dvio_display)
        tick = Tick(
            index=self.index, t_ns=t, frame=frame,
            T_dvio_display=T_dvio_display, T_cvio_controller=self.controller.at(t, s.max_gap_ns),
            T_dvio_anchor=self.d_anchor, T_cvio_anchor=self.c_anchor, imu=rows, events=evs,
            in_task=self._in_task(t), controller_vio_samples=vio_samples,
        )
        gt = self._truth(t)
        self.controller.prune(t)
        self.gt.prune(t)
        self.display.prune(self.image_t if (s.has_camera and self.image_t is not None) else t)
        self.next_t += s.period_ns
        self.index += 1
        return tick, gt

    def _advance_frame(self, t: int) -> bool:
        """Take the newest image at or before ``t``; True if the previous tick did not carry it."""
        msg = None
        while self.images and self.images[0][0] <= t:
            self.image_t, msg = self.images.popleft()
        if msg is None:
            return False
        self.image = (msg.data, msg.format)   # read once per frame: protobuf copies bytes on every access
        return True

    def _display_pose(self, t: int) -> Pose | None:
        """The display pose at the frame's stamp (at ``t`` without camera), computed once per frame."""
        s = self.s
        if not s.has_camera:
            return self.display.at(t, s.max_gap_ns)
        q = self.image_t if self.image_t is not None else t
        cached_t, cached = self.display_cache
        if cached_t == q and cached is not None:
            return cached
        pose = self.display.at(q, s.max_gap_ns)
        self.display_cache = (q, pose)
        return pose

    def _truth(self, t: int) -> Pose | None:
        s = self.s
        if not s.has_gt:
            return None
        T_world_ctrl = self.gt.raw_associate(t, s.gt_tol_ns)
        if T_world_ctrl is None:
            return None
        if s._T_mocap_controller is not None:
            T_world_ctrl = raw_compose(T_world_ctrl, s._T_mocap_controller)
        assert s._T_dvio_world is not None   # has_gt: the world's calibration is known
        return Pose.from_raw(raw_compose(s._T_dvio_world, T_world_ctrl))

    def _in_task(self, t: int) -> bool:
        ctx = self.s.context
        if ctx.task_start_ns is not None and t < ctx.task_start_ns:
            return False
        return not (ctx.task_end_ns is not None and t > ctx.task_end_ns)
