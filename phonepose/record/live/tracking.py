"""Trackers run live on a recording's streams, forming the very ticks playback forms (docs/recording-real-sessions.md,
"Live tracking").

What the recorder receives is offered to :class:`LiveTracker` (``offer``, never blocking: a bounded queue, drops
counted); its own thread puts the scheduled messages back into log-time order (:class:`StreamMerger`), feeds them
to playback's :class:`~phonepose.playback.scheduler.TickFeed` and steps every tracker on each tick through
playback's shared stages. Each estimate goes into the session as ``/trackers/<name>/pose`` (log time = the tick,
publish time = when it was published) and to the pose stream (phonepose.record.live.posestream).

The hold-back: streams arrive each in log-time order but interleaved as they come. A message at log time ``τ`` is
passed on once every stream that has delivered anything has delivered a message at or after ``τ``, or has
delivered nothing for :data:`HOLD_BACK_NS` of log time while another stream went on (it is silent). The tick at
``t`` is then formed by playback's rule on the messages so passed on, so it sees what playback gives it. Only log
times decide; a message that comes after a later one was passed on is late: it is counted and taken in at once.
"""

from __future__ import annotations

import heapq
import itertools
import json
import queue
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from phonepose.errors import PhoneposeError, keyword
from phonepose.geometry import Pose
from phonepose.pipeline.types import Stages, Tracker
from phonepose.playback.livereport import summary_lines
from phonepose.playback.scheduler import DEFAULT_RATE_HZ, SCHEDULED_TOPICS, TickFeed, TickScheduler
from phonepose.record.source import Record
from phonepose.schemas.topics import Frame, Topic, tracker_pose_topic
from phonepose.session.codec import pose_in_frame
from phonepose.session.context import STATIC_TOPICS, context_from_static

HOLD_BACK_NS = 500_000_000         # a stream that delivered nothing for this long (log time) is not waited for
QUEUE_MAX = 4096                   # messages waiting for the tracking thread (~20 s of a live session's streams)
BACKLOG_MAX_BYTES = 256 << 20      # data kept before the first tick can be formed (waiting for the marker size)
SAMPLES_MAX = 1_000_000            # latency samples kept per figure (a day at 20 Hz is 1.7 M: the first are kept)

_SCHEDULED = frozenset(SCHEDULED_TOPICS)
_STATIC = frozenset(STATIC_TOPICS)

# the live recorder's producers: each one delivers its topics in log-time order
LIVE_STREAMS = {
    Topic.CAMERA_IMAGE: "camera", Topic.DISPLAY_VIO_POSE: "camera",
    Topic.CONTROLLER_VIO_POSE: "phone", Topic.CONTROLLER_IMU: "phone", Topic.CONTROLLER_ANCHOR: "phone",
    Topic.DISPLAY_ANCHOR: "phone", Topic.CALIBRATION_EVENTS: "phone", Topic.GT_CONTROLLER_POSE: "headset",
}


class StreamMerger:
    """Streams each in log-time order, interleaved as they arrive -> one sequence in log-time order (the
    module docstring's hold-back). ``stream_of(topic)`` names a topic's stream (default: the topic)."""

    def __init__(self, stream_of: Callable[[str], str] | None = None, hold_ns: int = HOLD_BACK_NS):
        self.stream_of = stream_of or (lambda topic: topic)
        self.hold_ns = hold_ns
        self._heap: list = []
        self._seq = itertools.count()
        self.watermark: dict[str, int] = {}    # stream -> newest log time delivered
        self._newest: int | None = None
        self.released_ns: int | None = None    # log time of the last message passed on
        self.late: Counter = Counter()         # topic -> messages that came after a later one was passed on

    def push(self, topic: str, msg: Any, t_ns: int, tag: Any = None) -> list[tuple[str, Any, int, Any]]:
        """Take one message; return the ones that can now be passed on, in log-time order."""
        key = self.stream_of(topic)
        w = self.watermark.get(key)
        self.watermark[key] = t_ns if w is None else max(w, t_ns)
        self._newest = t_ns if self._newest is None else max(self._newest, t_ns)
        if self.released_ns is not None and t_ns < self.released_ns:
            self.late[topic] += 1
            return [(topic, msg, t_ns, tag), *self._release()]
        heapq.heappush(self._heap, (t_ns, next(self._seq), topic, msg, tag))
        return self._release()

    def _release(self) -> list[tuple[str, Any, int, Any]]:
        out = []
        heap, newest = self._heap, self._newest
        while heap:
            t = heap[0][0]
            if not all(w >= t or newest - w > self.hold_ns for w in self.watermark.values()):  # type: ignore[operator]
                break
            _, _, topic, msg, tag = heapq.heappop(heap)
            self.released_ns = t
            out.append((topic, msg, t, tag))
        return out

    def flush(self) -> list[tuple[str, Any, int, Any]]:
        """Everything still held (the streams ended), in log-time order."""
        out = []
        while self._heap:
            t, _, topic, msg, tag = heapq.heappop(self._heap)
            self.released_ns = t
            out.append((topic, msg, t, tag))
        return out


def percentiles_ms(samples: Iterable[float]) -> dict[str, float] | None:
    """p50 / p99 / max of durations in seconds, in milliseconds (None without samples)."""
    a = np.fromiter(samples, dtype=float)
    if a.size == 0:
        return None
    return {"n": int(a.size), "p50": round(float(np.percentile(a, 50)) * 1e3, 3),
            "p99": round(float(np.percentile(a, 99)) * 1e3, 3), "max": round(float(a.max()) * 1e3, 3)}


@dataclass
class TrackerLatency:
    compute_s: list[float] = field(default_factory=list)     # the tracker's step per tick
    publish_s: list[float] = field(default_factory=list)     # the tick's last input arriving -> published
    age_s: list[float] = field(default_factory=list)         # the tick's time -> published (hold-back included)
    overruns: int = 0                                        # steps longer than the tick period
    failed: str = ""                                         # what it raised (then it is stepped no more)
    estimates: int = 0

    def add(self, compute: float, publish: float, age: float) -> None:
        if len(self.compute_s) < SAMPLES_MAX:
            self.compute_s.append(compute)
            self.publish_s.append(publish)
            self.age_s.append(age)


def pose_line(name: str, t_ns: int, pose: Pose | None, in_view: bool, published_ns: int) -> str:
    """One line of the pose stream (docs/recording-real-sessions.md, "Live tracking")."""
    doc = {"t_ns": t_ns, "tracker": name,
           "position": None if pose is None else [float(v) for v in pose.translation],
           "quaternion": None if pose is None else [float(v) for v in pose.quat_xyzw],
           "in_view": bool(in_view), "published_ns": published_ns}
    return json.dumps(doc, separators=(",", ":"))


class LiveTracker:
    """Trackers stepped on a live feed at the tick rate, by playback's tick rule (the module docstring).

    ``offer(record)`` from any thread (never blocks); ``start()``; ``finish()`` when no more records come
    (forms the remaining ticks, stops the thread, returns the closing summary's lines). ``publish(record)``
    receives every estimate as a ``/trackers/<name>/pose`` record; ``lines(list)`` (optional) the pose stream's
    JSON lines; ``warn(text)`` one line per problem.
    """

    def __init__(self, trackers: list[Tracker], *, publish: Callable[[Record], None], now_ns: Callable[[], int],
                 warn: Callable[[str], None], rate_hz: float = DEFAULT_RATE_HZ, correction_math: str = "paper",
                 has_camera: bool = True, stream_of: Callable[[str], str] | None = None,
                 hold_ns: int = HOLD_BACK_NS, lines: Callable[[list[str]], None] | None = None,
                 stages_factory: Callable[[Any], Stages] | None = None, queue_max: int = QUEUE_MAX,
                 backlog_max_bytes: int = BACKLOG_MAX_BYTES):
        self.trackers = trackers
        self.publish = publish
        self.now_ns = now_ns
        self.warn = warn
        self.lines = lines
        self.rate_hz = float(rate_hz)
        self.period_s = 1.0 / self.rate_hz
        self.correction_math = correction_math
        self.has_camera = has_camera
        self.stages_factory = stages_factory
        self.backlog_max_bytes = backlog_max_bytes
        self.merger = StreamMerger(stream_of, hold_ns)
        self._queue: queue.Queue = queue.Queue(maxsize=queue_max)
        self._topics = {t.name: tracker_pose_topic(t.name) for t in trackers}
        self.latency = {t.name: TrackerLatency() for t in trackers}
        self.stages_s: list[float] = []
        self.dropped = 0
        self.static: dict[str, Any] = {}
        self._backlog: list[tuple[str, Any, int]] = []
        self._backlog_bytes = 0
        self._t0: int | None = None
        self.feed: TickFeed | None = None
        self.stages: Stages | None = None
        self.stopped = ""                 # why live tracking stopped early (the recording goes on)
        self.first_tick_ns: int | None = None
        self.last_tick_ns: int | None = None
        self.ticks = 0
        self._last_data_ns: int | None = None
        self._arrival = 0.0               # perf_counter when the record being handled was offered
        self._thread: threading.Thread | None = None
        self._finished = False

    # ------------------------------------------------------------------ producers' side
    def offer(self, rec: Record) -> None:
        """A record the recorder received (any thread): queued for the tracking thread, or dropped and counted."""
        if rec.topic not in _SCHEDULED and rec.topic not in _STATIC:
            return
        try:
            self._queue.put_nowait((rec, time.perf_counter()))
        except queue.Full:
            self.dropped += 1
            if self.dropped == 1:
                self.warn("live tracking falls behind the streams: input dropped (counted in the closing summary); "
                          "live estimates from here on may differ from playback's")

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="phonepose-live-tracking", daemon=True)
        self._thread.start()

    def finish(self, timeout_s: float | None = None) -> list[str]:
        """No more records: form the remaining ticks, stop the thread; the closing summary's lines."""
        if not self._finished:
            self._finished = True
            if self._thread is not None:
                self._queue.put((None, time.perf_counter()))   # blocks only while the queue is full: it drains
                self._thread.join(timeout_s)
        return self.summary()

    # ------------------------------------------------------------------ the tracking thread
    def _run(self) -> None:
        while True:
            rec, arrival = self._queue.get()
            if rec is None:
                break
            if self.stopped:
                continue
            try:
                self.handle(rec, arrival)
            except Exception as exc:  # noqa: BLE001 - live tracking stops, the recording goes on
                self._stop(f"{type(exc).__name__}: {exc}")
        if not self.stopped:
            self._arrival = time.perf_counter()
            try:
                self.end()
            except Exception as exc:  # noqa: BLE001 - as above
                self._stop(f"{type(exc).__name__}: {exc}")

    def _stop(self, why: str) -> None:
        self.stopped = why
        self.warn(f"live tracking stopped: {why}; the recording goes on")
        self._backlog.clear()

    def handle(self, rec: Record, arrival: float | None = None) -> None:
        """One record, in arrival order, offered at ``arrival`` (perf_counter; default now): the tracking
        thread's step, which tests call directly."""
        self._arrival = time.perf_counter() if arrival is None else arrival
        if rec.topic in _STATIC:
            self.static.setdefault(rec.topic, rec.message)
            if self.feed is None:
                self._try_start()
            return
        if rec.topic not in _SCHEDULED:
            return
        for topic, msg, t, _ in self.merger.push(rec.topic, rec.message, rec.log_time_ns):
            self._take(topic, msg, t)

    def end(self) -> None:
        """The streams ended: pass on what is held and form every tick up to the last message."""
        for topic, msg, t, _ in self.merger.flush():
            self._take(topic, msg, t)
        if self.feed is None:
            self._try_start(ended=True)
        if self.feed is not None and self._last_data_ns is not None:
            for tick, _gt in self.feed.finish(self._last_data_ns):
                self._step(tick)
        elif not self.stopped and self._backlog:
            self.stopped = f"no tick could be formed ({self._waiting_for()})"

    def _waiting_for(self) -> str:
        if self.has_camera and Topic.CONTROLLER_MARKER not in self.static:
            return f"no marker size yet: give {keyword('marker_size_m')}"
        return "no camera frame" if self.has_camera else "no controller VIO"

    def _take(self, topic: str, msg: Any, t: int) -> None:
        self._last_data_ns = t if self._last_data_ns is None else max(self._last_data_ns, t)
        if self.feed is not None:
            for tick, _gt in self.feed.feed(topic, msg, t):
                self._step(tick)
            return
        if self.stopped:
            return
        self._backlog.append((topic, msg, t))
        self._backlog_bytes += len(msg.data) if topic == Topic.CAMERA_IMAGE else 200
        origin = Topic.CAMERA_IMAGE if self.has_camera else Topic.CONTROLLER_VIO_POSE
        if self._t0 is None and topic == origin:
            self._t0 = t
        if self._backlog_bytes > self.backlog_max_bytes:
            self._stop(f"no tick could be formed within {self.backlog_max_bytes >> 20} MiB of data "
                       f"({self._waiting_for()})")
            return
        self._try_start()

    def _try_start(self, ended: bool = False) -> None:
        """Start forming ticks once the grid's origin and the context are known and the streams have run a
        hold-back past the origin (a stream that starts a little later is still put in order), or at the end."""
        if self._t0 is None or (self.has_camera and (Topic.CONTROLLER_MARKER not in self.static
                                                     or Topic.CAMERA_CALIBRATION not in self.static)):
            return
        newest = self._last_data_ns
        if not ended and (newest is None or newest - self._t0 <= self.merger.hold_ns):
            return
        try:
            context = context_from_static("live", self.has_camera, self.static)
        except PhoneposeError as exc:
            self._stop(str(exc))
            return
        from phonepose.pipeline.shared import SharedStages  # OpenCV: imported when tracking starts

        sched = TickScheduler.streaming(context, self._t0, has_camera=self.has_camera, rate_hz=self.rate_hz,
                                        gt_topic=True)
        self.stages = (self.stages_factory or SharedStages)(context)
        self.stages.map_vio_samples = any(t.uses_vio_samples for t in self.trackers)
        for tr in self.trackers:
            tr.reset()
        self.feed = sched.feed()
        backlog = sorted(self._backlog, key=lambda m: m[2])   # stable: arrival order among equal log times
        self._backlog = []
        self.merger.late.clear()   # the backlog is put in order here: nothing in it came too late
        for topic, msg, t in backlog:
            for tick, _gt in self.feed.feed(topic, msg, t):
                self._step(tick)

    def _step(self, tick) -> None:
        assert self.stages is not None   # set with the feed
        t0 = time.perf_counter()
        obs = self.stages.process(tick)
        if len(self.stages_s) < SAMPLES_MAX:
            self.stages_s.append(time.perf_counter() - t0)
        self.ticks += 1
        self.first_tick_ns = tick.t_ns if self.first_tick_ns is None else self.first_tick_ns
        self.last_tick_ns = tick.t_ns
        lines = []
        for tr in self.trackers:
            lat = self.latency[tr.name]
            if lat.failed:
                continue
            t1 = time.perf_counter()
            try:
                pose = tr.step(obs)
            except Exception as exc:  # noqa: BLE001 - one tracker's failure ends that tracker only
                lat.failed = f"{type(exc).__name__}: {exc}"
                self.warn(f"tracker {tr.name} raised at tick {tick.index} ({lat.failed}); it is stepped no more, "
                          "the recording and the other trackers go on")
                continue
            compute = time.perf_counter() - t1
            if compute > self.period_s:
                lat.overruns += 1
                if lat.overruns == 1:
                    self.warn(f"tracker {tr.name} took {compute * 1e3:.0f} ms for one tick, longer than the tick "
                              f"period {self.period_s * 1e3:.0f} ms: live estimates lag (overruns counted in the "
                              "closing summary)")
            published = self.now_ns()
            if pose is not None:
                lat.estimates += 1
                self.publish(Record(self._topics[tr.name], pose_in_frame(pose, Frame.DISPLAY_VIO, tick.t_ns),
                                    tick.t_ns, published))
            if self.lines is not None:
                lines.append(pose_line(tr.name, tick.t_ns, pose, obs.in_view, published))
            done = time.perf_counter()
            lat.add(compute, done - self._arrival, (published - tick.t_ns) / 1e9)
        if lines and self.lines is not None:
            self.lines(lines)

    # ------------------------------------------------------------------ results
    def report(self) -> dict:
        """The figures stored in the session (MCAP metadata :data:`METADATA_NAME`) and printed by ``info``."""
        return {
            "rate_hz": self.rate_hz, "correction_math": self.correction_math, "hold_back_s": self.merger.hold_ns / 1e9,
            "trackers": [t.name for t in self.trackers], "ticks": self.ticks,
            "first_tick_ns": self.first_tick_ns, "last_tick_ns": self.last_tick_ns,
            "dropped": self.dropped, "late": dict(self.merger.late), "stopped": self.stopped,
            "stages_ms": percentiles_ms(self.stages_s),
            "per_tracker": {name: {"estimates": lat.estimates, "compute_ms": percentiles_ms(lat.compute_s),
                                   "input_to_publish_ms": percentiles_ms(lat.publish_s),
                                   "tick_to_publish_ms": percentiles_ms(lat.age_s), "overruns": lat.overruns,
                                   "failed": lat.failed}
                            for name, lat in self.latency.items()},
        }

    def metadata(self) -> dict[str, str]:
        return {"report": json.dumps(self.report())}

    def summary(self) -> list[str]:
        return summary_lines(self.report())
