"""The tick scheduler: one streaming pass over a session, a :class:`Tick` every 1/rate s.

The tick rule (docs/playback.md):

* Ticks lie on a grid ``t_k = t0 + k / rate`` where ``t0`` is the first camera frame (or the
  first controller VIO sample when the session has no camera). ``--start/--end`` select the
  grid ticks inside ``[start, end]`` (seconds after the session's first message).
* A tick at ``t`` carries every message with ``log_time <= t`` and nothing later: the newest
  camera frame at or before ``t`` (``image_is_new`` if the previous tick did not carry it), the
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
from dataclasses import dataclass
from typing import Any, Iterator

import numpy as np

from phonepose.geometry import Pose, RawPose, raw_compose, raw_interpolate
from phonepose.pipeline.types import SessionContext, Tick
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
    from phonepose.errors import ConfigError
    given = " ".join(f"{name} {v:g}" for name, v in (("--start", start_s), ("--end", end_s)) if v is not None)
    raise ConfigError(f"{given} selects {(first - start_ns) / 1e9:.2f}-{(last - start_ns) / 1e9:.2f} s, which misses "
                      f"the task window {(t0 - start_ns) / 1e9:.2f}-{(t1 - start_ns) / 1e9:.2f} s (where trajectories "
                      "and metrics are computed): choose a range that overlaps it")


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
        if not rate_hz > 0:
            from phonepose.errors import ConfigError
            raise ConfigError(f"--rate must be > 0 (got {rate_hz})")
        self.reader = reader
        self.context = context
        self.rate_hz = float(rate_hz)
        self.period_ns = int(round(1e9 / self.rate_hz))
        self.gt_tol_ns = int(round(gt_tolerance_s * 1e9))
        self.max_gap_ns = int(round(max_gap_s * 1e9))
        summary = reader.summary()
        self.has_camera = summary.has(Topic.CAMERA_IMAGE)
        cal = gt_calibration
        T_world_dvio = context.T_world_display_vio
        if cal is not None and cal.T_world_display_vio is not None:
            T_world_dvio = cal.T_world_display_vio
        self._gt_series = gt_series
        self.has_gt = (gt_series is not None or summary.has(Topic.GT_CONTROLLER_POSE)) and T_world_dvio is not None
        self._T_dvio_world = T_world_dvio.inv().as_raw() if T_world_dvio is not None else None
        self._T_mocap_controller = cal.T_controller_gt.inv().as_raw() if cal is not None else None
        self._gt_shift_ns = int(round(cal.time_offset_s * 1e9)) if cal is not None else 0
        self._gt_wait_ns = self.gt_tol_ns + max(self._gt_shift_ns, 0)   # how far past a tick its GT may lie in the file
        origin_topic = Topic.CAMERA_IMAGE if self.has_camera else Topic.CONTROLLER_VIO_POSE
        # (topic, reason) -> samples skipped in the pass; reported as one warning line each
        self.skipped: Counter = Counter()
        start_ns, end_ns = self._span(reader, summary)
        self.span_ns = (start_ns, end_ns)
        t0 = None
        for _schema, _channel, m in reader.raw_messages([origin_topic], start_ns=start_ns, end_ns=end_ns + 1):
            t0 = m.log_time
            break
        if t0 is None:
            from phonepose.errors import SessionContentError
            raise SessionContentError(f"{reader.path}: {origin_topic} has no messages")
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
            from phonepose.errors import ConfigError
            raise ConfigError(f"--start/--end select no tick: the session runs {(end_ns - start_ns) / 1e9:.2f} s and its "
                              f"first tick is at {(t0 - start_ns) / 1e9:.2f} s")
        if start_s is not None or end_s is not None:
            _check_task_overlap(context, start_ns, first, last, start_s, end_s)
        self.info = ScheduleInfo(t0_ns=t0, first_tick_ns=first, last_tick_ns=last, period_ns=self.period_ns,
                                 session_start_ns=start_ns)
        self.idle_gap_ns = int(IDLE_GAP_S * 1e9)
        self.ticks_skipped = 0      # grid ticks inside stretches of more than IDLE_GAP_S without data

    def _span(self, reader: SessionReader, summary) -> tuple[int, int]:
        """The session's time span without time outliers (counted into ``skipped``): a far-future or
        far-past log time would otherwise set the span the ticks and --start/--end are planned on."""
        times = reader.log_times()
        span = main_span([t for ts in times.values() for t in ts])
        if span is None:
            return summary.start_ns, summary.end_ns
        for topic, ts in times.items():
            n = sum(1 for t in ts if not span[0] <= t <= span[1])
            if n:
                self.skipped[(topic, OUTLIER)] += n
        return span
    def __len__(self) -> int:
        return self.info.n_ticks

    # ------------------------------------------------------------------ the pass
    def __iter__(self) -> Iterator[Tick]:
        info = self.info
        if info.n_ticks == 0:
            return
        display = PoseStream()
        controller = PoseStream()
        gt = PoseStream()
        if self.has_gt and self._gt_series is not None:    # a sidecar file: all of it, on the recorder's clock
            for t_ns, raw in zip(*self._gt_series.raw_samples(), strict=True):
                gt.add(int(t_ns) - self._gt_shift_ns, raw)
        images: deque = deque()            # (log_time, CompressedImage), newest at or before next tick kept
        d_anchor: deque = deque()           # (log_time, Pose)
        c_anchor: deque = deque()
        imu: list = []                      # (log_time, row)
        cvio_samples: list = []             # (log_time, capture_ns, raw): controller VIO with its capture stamp
        events: list = []                   # (log_time, CalibrationEvent)
        state: dict[str, Any] = {"image": None, "image_t": None, "display_cache": (None, None), "d_anchor": None,
                                 "c_anchor": None}
        next_t = info.first_tick_ns
        index = 0
        # Nothing after this is needed: the last tick plus the look-ahead.
        read_end = info.last_tick_ns + max(self.max_gap_ns, self._gt_wait_ns) + 1
        need_display = self.has_camera

        def ready(t: int, now: int) -> bool:
            if not controller.has_after(t) and now - t <= self.max_gap_ns:
                return False
            if need_display and not display.has_after(t) and now - t <= self.max_gap_ns:
                return False
            if self.has_gt and not gt.has_after(t) and now - t <= self._gt_wait_ns:
                return False
            return True

        def build(t: int, idx: int, prev_t: int | None) -> Tick:
            # newest image at or before t
            new_image = False
            while images and images[0][0] <= t:
                lt, img = images.popleft()
                state["image"], state["image_t"] = img, lt
                new_image = True
            while d_anchor and d_anchor[0][0] <= t:
                state["d_anchor"] = d_anchor.popleft()[1]
            while c_anchor and c_anchor[0][0] <= t:
                state["c_anchor"] = c_anchor.popleft()[1]
            k = 0
            while k < len(imu) and imu[k][0] <= t:
                k += 1
            rows = np.array([r for _, r in imu[:k]], dtype=float).reshape(-1, 7)
            del imu[:k]
            k = 0
            while k < len(events) and events[k][0] <= t:
                k += 1
            evs = [e for _, e in events[:k]]
            del events[:k]
            k = 0
            while k < len(cvio_samples) and cvio_samples[k][0] <= t:
                k += 1
            vio_samples = [(c, Pose.from_raw(r)) for _, c, r in cvio_samples[:k]]
            del cvio_samples[:k]
            image_t = state["image_t"]
            T_dvio_display = None
            if need_display:
                q = image_t if image_t is not None else t
                cached_t, cached = state["display_cache"]
                if cached_t == q and cached is not None:
                    T_dvio_display = cached
                else:
                    T_dvio_display = display.at(q, self.max_gap_ns)
                    state["display_cache"] = (q, T_dvio_display)
            else:
                T_dvio_display = display.at(t, self.max_gap_ns)
            gt_pose = None
            if self.has_gt:
                T_world_ctrl = gt.raw_associate(t, self.gt_tol_ns)
                if T_world_ctrl is not None:
                    if self._T_mocap_controller is not None:
                        T_world_ctrl = raw_compose(T_world_ctrl, self._T_mocap_controller)
                    assert self._T_dvio_world is not None   # has_gt needs it
                    gt_pose = Pose.from_raw(raw_compose(self._T_dvio_world, T_world_ctrl))
            ctx = self.context
            in_task = True
            if ctx.task_start_ns is not None and t < ctx.task_start_ns:
                in_task = False
            if ctx.task_end_ns is not None and t > ctx.task_end_ns:
                in_task = False
            tick = Tick(
                index=idx, t_ns=t, image=state["image"], image_t_ns=image_t, image_is_new=new_image,
                T_dvio_display=T_dvio_display, T_cvio_controller=controller.at(t, self.max_gap_ns),
                T_dvio_anchor=state["d_anchor"], T_cvio_anchor=state["c_anchor"], imu=rows, events=evs,
                gt_T_dvio_controller=gt_pose, in_task=in_task, controller_vio_samples=vio_samples,
            )
            # forget what no later tick can use
            controller.prune(t)
            gt.prune(t)
            display.prune(image_t if (need_display and image_t is not None) else t)
            return tick

        prev_t = None
        last_stamp: dict[str, tuple[int, int]] = {}   # topic -> (log_time, header stamp) of the last sample used
        last_message_ns = None
        for m in self.reader.messages(SCHEDULED_TOPICS, start_ns=self.span_ns[0],
                                      end_ns=min(read_end, self.span_ns[1] + 1)):
            now = m.log_time_ns
            if last_message_ns is not None and now - last_message_ns > self.idle_gap_ns:
                # the ticks the data before the gap supports, then none until the data resumes
                hold = last_message_ns + max(self.max_gap_ns, self._gt_wait_ns)
                while next_t <= info.last_tick_ns and next_t <= hold:
                    yield build(next_t, index, prev_t)
                    prev_t = next_t
                    next_t += self.period_ns
                    index += 1
                resume = info.t0_ns + -(-(now - info.t0_ns) // self.period_ns) * self.period_ns
                if resume > next_t:
                    self.ticks_skipped += (min(resume, info.last_tick_ns + self.period_ns) - next_t) // self.period_ns
                    next_t = resume
            last_message_ns = now
            while next_t <= info.last_tick_ns and next_t < now and ready(next_t, now):
                yield build(next_t, index, prev_t)
                prev_t = next_t
                next_t += self.period_ns
                index += 1
            topic, msg = m.topic, m.msg
            if topic != Topic.CALIBRATION_EVENTS:
                # duplicate or backwards timestamps on one stream: skipped and reported, never used
                stamp = msg.timestamp.ToNanoseconds()
                prev = last_stamp.get(topic)
                # Judged by the header stamp only: controller streams carry the receipt time as
                # log_time, so several samples of one network packet share it legitimately.
                if prev is not None and stamp and prev[1] and stamp <= prev[1]:
                    self.skipped[(topic, "duplicate or non-monotonic timestamp")] += 1
                    continue
                last_stamp[topic] = (now, stamp)
            raw = None
            if topic in _POSE_TOPICS:
                try:
                    raw = codec.raw_pose(msg.pose)
                except codec.BrokenPose as exc:
                    self.skipped[(topic, exc.reason)] += 1
                    continue
            if topic == Topic.CAMERA_IMAGE:
                images.append((now, msg))
            elif topic == Topic.DISPLAY_VIO_POSE:
                display.add(now, raw)
            elif topic == Topic.CONTROLLER_VIO_POSE:
                controller.add(now, raw)
                if now > info.first_tick_ns - self.period_ns:   # else before the first tick's interval
                    cvio_samples.append((now, codec.stamp_ns(msg, now), raw))
            elif topic == Topic.GT_CONTROLLER_POSE:
                if self.has_gt and self._gt_series is None:
                    gt.add(now - self._gt_shift_ns, raw)
            elif topic == Topic.DISPLAY_ANCHOR:
                assert raw is not None   # a pose topic: read above
                d_anchor.append((now, Pose.from_raw(raw)))
            elif topic == Topic.CONTROLLER_ANCHOR:
                assert raw is not None   # a pose topic: read above
                c_anchor.append((now, Pose.from_raw(raw)))
            elif topic == Topic.CONTROLLER_IMU:
                if now <= info.first_tick_ns - self.period_ns:
                    continue  # before the first tick's interval (--start): nobody will read it
                row = codec.imu_row(msg, now)
                problem = codec.imu_problem(row)
                if problem is not None:
                    self.skipped[(topic, problem)] += 1
                    continue
                imu.append((now, row))
            elif topic == Topic.CALIBRATION_EVENTS:
                events.append((now, msg))
            # bound the image queue: only the newest frame at or before the next tick matters
            while len(images) >= 2 and images[1][0] <= next_t:
                images.popleft()
        while next_t <= info.last_tick_ns:
            yield build(next_t, index, prev_t)
            prev_t = next_t
            next_t += self.period_ns
            index += 1
        for (topic, reason), n in sorted(self.skipped.items()):
            log.warning("phonepose: warning: %s: %d sample(s) skipped: %s", topic, n, reason)
