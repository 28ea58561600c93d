"""``record live``: a webcam (the display camera), a phone page (the controller) and a headset page (the
ground truth) into one session.

:class:`LiveSession` ties the parts together: the :class:`~phonepose.record.live.camera.Camera`
runs in a thread, the :class:`~phonepose.record.live.server.LiveServer` in an asyncio loop in
another, and both hand :class:`~phonepose.record.source.Record` objects to :class:`LiveSource`,
the recorder's :class:`~phonepose.record.source.Source`. The existing
:class:`~phonepose.record.recorder.Recorder` writes them (and logs them to Rerun); its SIGINT /
SIGTERM handler here asks the source to stop, which stops the camera and the server and then
drains everything received into the file before it is finished: Ctrl-C loses nothing.

What is written (docs/format.md topics; docs/recording-real-sessions.md for the why):

- ``/display/camera/image`` every frame (log time = capture time); ``/display/vio/pose`` the
  identity at every frame's time (the display has no VIO: it stands still, display_vio = display);
  ``/display/camera/calibration`` from the calibration file; ``/display/camera/extrinsics`` the fixed
  rotation :data:`T_DISPLAY_CAMERA` (display body x forward, y left, z up; a level camera looks
  along +x) so display_vio is roughly z-up in viewers.
- ``/controller/vio/pose``, ``/controller/imu``: the page's samples, ``timestamp`` = capture time
  on the recorder clock (``t - offset``), log time = receipt time. Samples whose capture time does
  not increase on their stream are written as they came (nothing received is dropped), counted,
  and reported in the closing summary and ``/log``; playback skips them with one warning.
- ``/controller/anchor`` (the viewer pose at the tap, controller_vio) and ``/display/anchor`` (the
  controller pose from the marker in the camera frame closest to the tap, within
  :data:`ANCHOR_MAX_DT_NS`; display_vio), both logged when the anchor is resolved. The controller
  body is the WebXR viewer and the marker frame is taken to be that body (``pose_in_body`` =
  identity): the offset between the viewer origin (the phone's camera) and the screen centre is
  unknown to the page; it costs ``|(I - R) x|`` of position error on the VIO path after a rotation
  R since the tap (x: that offset, a few cm), nothing right at the tap.
- ``/controller/marker``: ``--marker-size`` when given (written first); else the page's ``size_m``
  in effect at the first anchor (written then; at the end if no anchor was set). The page reports
  a new size whenever its layout changes; a change after the size is fixed is reported (terminal,
  ``/log``, the page) and counted, since playback has one marker size per session.
- ``/gt/controller/pose``, ``/gt/board_controller/pose``, ``/gt/headset/pose``: a WebXR headset's
  controllers and viewer (phonepose/record/live/headset.py), log time = capture time.
- ``/session/info`` (again when a headset names the ground truth's source: ``ground_truth_source``)
  and ``/log`` (connections, clock offsets, anchors, refused requests, malformed messages, the
  closing summary).

Records go through a reorder buffer of :data:`HOLD_NS`: the file's messages are in log-time order
across topics (its chunks do not overlap in time) although frames, phone samples and anchors come
from different threads, at the price of this much more data lost on a SIGKILL.
"""

from __future__ import annotations

import asyncio
import heapq
import itertools
import json
import os
import queue
import secrets
import socket
import threading
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.Log_pb2 import Log

from phonepose import __version__
from phonepose.calibration.camera_file import CameraCalibrationFile, load_calibration
from phonepose.errors import ConfigError, keyword
from phonepose.pipeline.markers import aruco_dictionary
from phonepose.pipeline.types import CameraModel
from phonepose.playback.livereport import METADATA_NAME as TRACKING_METADATA
from phonepose.record.live.camera import Camera
from phonepose.record.live.clock import RecorderClock
from phonepose.record.live.posestream import PoseStreamServer
from phonepose.record.live.recording import T_BODY_MARKER, T_DISPLAY_CAMERA, LiveRecording
from phonepose.record.live.server import STATIC_DIR, LiveServer
from phonepose.record.live.tracking import LIVE_STREAMS, LiveTracker
from phonepose.record.recorder import Recorder, RecordResult
from phonepose.record.source import Record
from phonepose.schemas import phonepose_pb2 as pb
from phonepose.schemas.topics import Frame as F
from phonepose.schemas.topics import Topic
from phonepose.session.codec import encode_pose, frame_transform

# A SIGKILL loses what waits in the reorder buffer plus what the writer has not flushed yet: at most
# HOLD_NS + FLUSH_NS = 1 s. Samples held longer
# than HOLD_NS (waiting for a first pong) are still written, their log time raised to keep the order.
HOLD_NS = 500_000_000                # reorder buffer across the camera thread and the server
FLUSH_NS = 500_000_000               # the session writer's flush interval (log time)
MARKER_PNG_SIDE_PX = 480

def _marker_png(dictionary: str, marker_id: int) -> bytes:
    try:
        from phonepose.calibration.marker_image import marker_png
    except ImportError:   # pragma: no cover - the calibration module ships with phonepose
        img = cv2.aruco.generateImageMarker(aruco_dictionary(dictionary), marker_id, MARKER_PNG_SIDE_PX)
        img = cv2.copyMakeBorder(img, 80, 80, 80, 80, cv2.BORDER_CONSTANT, value=255)
        return cv2.imencode(".png", img)[1].tobytes()
    return marker_png(dictionary, marker_id, side_px=MARKER_PNG_SIDE_PX)


def lan_addresses() -> list[str]:
    """The machine's outward IPv4 address (the one a phone on the same network reaches), if any."""
    out = []
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.connect(("10.254.254.254", 1))   # no packet is sent: this only picks the route's source address
        ip = s.getsockname()[0]
        if ip and not ip.startswith("127."):
            out.append(ip)
    except OSError:
        pass
    finally:
        s.close()
    return out


class LiveSource:
    """The recorder's :class:`~phonepose.record.source.Source` for a live recording."""

    def __init__(self, clock: RecorderClock, camera: Camera, calibration: CameraCalibrationFile, calibration_path: str,
                 *, host: str, port: int, ssl_context, token: str, dictionary: str, marker_id: int,
                 marker_size_m: float | None, duration_s: float | None, echo: Callable[[str], None],
                 static_dir: Path | None = None, gt_hand: str = "right", tracking: LiveTracking | None = None):
        self.clock = clock
        self.camera = camera
        self.calibration = calibration
        self.calibration_path = calibration_path
        self.token = token
        self.echo = echo
        self.duration_ns = None
        self.max_duration_ns = None if duration_s is None else int(duration_s * 1e9)
        self.start_ns = clock.now_ns()
        self._queue: queue.Queue = queue.Queue()
        self._stop = threading.Event()
        self.stop_reason = ""
        self.interrupted = False
        K, D = calibration.K, calibration.D
        cam_model = CameraModel(K=np.asarray(K, float), D=np.asarray(D, float), width=calibration.width,
                                height=calibration.height, T_display_camera=T_DISPLAY_CAMERA)
        self.tracker: LiveTracker | None = None
        self.pose_server: PoseStreamServer | None = None
        self.tracking_summary: list[str] = []
        self._tracking_done = False
        if tracking is not None:
            self.tracker = LiveTracker(tracking.trackers, publish=self._queue.put, now_ns=clock.now_ns,
                                       warn=lambda text: self.recording.log(text, level="warning"),
                                       rate_hz=tracking.rate_hz, correction_math=tracking.correction_math,
                                       stream_of=lambda topic: LIVE_STREAMS.get(topic, topic))
            if tracking.pose_port is not None:
                self.pose_server = PoseStreamServer(tracking.pose_host, tracking.pose_port, token=token,
                                                    ssl_context=ssl_context,
                                                    warn=lambda text: self.recording.log(text, level="warning"))
                self.tracker.lines = self.pose_server.send
        self.recording = LiveRecording(clock, self._put, cam_model, dictionary, marker_id, marker_size_m, echo,
                                       gt_hand=gt_hand)
        self.recording.ground_truth_source_changed = self._info_again
        self.server = LiveServer(self.recording, token, host=host, port=port, ssl_context=ssl_context,
                                 marker_png=_marker_png(dictionary, marker_id),
                                 static_dir=static_dir if static_dir is not None else STATIC_DIR)
        self.host = host
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server_thread: threading.Thread | None = None
        self._camera_thread: threading.Thread | None = None
        self._closed = False
        self.counts: Counter = Counter()
        self.late = 0
        self.summary: list[str] = []

    def _put(self, rec: Record) -> None:
        """A received record: to the file, and to the live trackers."""
        self._queue.put(rec)
        if self.tracker is not None:
            self.tracker.offer(rec)

    # ------------------------------------------------------------------ start
    def start(self) -> int:
        """Bind the server (its own thread and asyncio loop) and the pose stream; returns the server's port."""
        port = self._start_server()
        if self.pose_server is not None:
            try:
                self.pose_server.start()
            except OSError as exc:
                self._stop_loop()
                raise ConfigError(f"cannot listen on {self.pose_server.host}:{self.pose_server.port} for the pose "
                                  f"stream: {exc.strerror or exc} (choose another {{pose_port}})", parameter="pose_port",
                                  value=self.pose_server.port) from None
        return port

    def _start_server(self) -> int:
        loop = self._loop = asyncio.new_event_loop()
        ready = threading.Event()
        self._server_thread = threading.Thread(target=self._run_loop, args=(ready,), name="phonepose-live-server",
                                               daemon=True)
        self._server_thread.start()
        ready.wait()
        fut = asyncio.run_coroutine_threadsafe(self.server.start(), loop)
        try:
            return fut.result(timeout=10)
        except OSError as exc:
            self._stop_loop()
            raise ConfigError(f"cannot listen on {self.host}:{self.server.port}: {exc.strerror or exc} "
                              "(choose another {port})", parameter="port", value=self.server.port) from None

    def _run_loop(self, ready: threading.Event) -> None:
        loop = self._loop
        assert loop is not None   # start() made it
        asyncio.set_event_loop(loop)
        loop.call_soon(ready.set)
        loop.run_forever()
        loop.close()

    def _stop_loop(self) -> None:
        if self._loop is not None and self._server_thread is not None and self._server_thread.is_alive():
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._server_thread.join(timeout=10)

    def _camera_loop(self) -> None:
        rec = self.recording
        try:
            while not self._stop.is_set():
                frame = self.camera.read()
                if frame is None:
                    break
                rec.add_frame(frame)
        except Exception as exc:   # noqa: BLE001 - a camera failure ends the recording, never the file
            rec.log(f"camera {self.camera.spec} failed: {type(exc).__name__}: {exc}", level="error")
        finally:
            rec.camera_ended = True
            if not self._stop.is_set():
                self.request_stop("the video file ended" if not self.camera.is_device
                                  else f"camera {self.camera.spec} stopped delivering frames")

    # ------------------------------------------------------------------ Source
    def static(self) -> list[Record]:
        t0 = self.start_ns
        c = self.calibration
        rec = self.recording
        info = self._info(t0, "")
        K = np.asarray(c.K, float)
        calib = CameraCalibration(frame_id=F.DISPLAY_CAMERA, width=c.width, height=c.height,
                                  distortion_model="plumb_bob", D=[float(v) for v in c.D],
                                  K=[float(v) for v in K.ravel()], R=[1, 0, 0, 0, 1, 0, 0, 0, 1],
                                  P=[K[0, 0], 0, K[0, 2], 0, 0, K[1, 1], K[1, 2], 0, 0, 0, 1, 0])
        calib.timestamp.FromNanoseconds(t0)
        out = [Record(Topic.SESSION_INFO, info, t0, t0),
               Record(Topic.CAMERA_CALIBRATION, calib, t0, t0),
               Record(Topic.CAMERA_EXTRINSICS, frame_transform(T_DISPLAY_CAMERA, F.DISPLAY, F.DISPLAY_CAMERA, t0), t0, t0)]
        if rec.marker_size_from_cli:
            spec = pb.MarkerSpec(dictionary=rec.marker_dictionary, id=rec.marker_id, size_m=rec.marker_size_m)
            spec.timestamp.FromNanoseconds(t0)
            encode_pose(T_BODY_MARKER, spec.pose_in_body)
            out.append(Record(Topic.CONTROLLER_MARKER, spec, t0, t0))
        if self.tracker is not None:
            for r in out:
                self.tracker.offer(r)
        return out

    def _info(self, t_ns: int, ground_truth_source: str) -> pb.SessionInfo:
        c, rec = self.calibration, self.recording
        info = pb.SessionInfo(source="live", scenario="live", phonepose_version=__version__,
                              config_toml=self._config_toml(),
                              description=f"live recording: camera {self.camera.spec} ({c.width}x{c.height}), "
                                          f"marker {rec.marker_dictionary} id {rec.marker_id}",
                              ground_truth_source=ground_truth_source)
        info.timestamp.FromNanoseconds(t_ns)
        return info

    def _info_again(self, ground_truth_source: str) -> None:
        """The session info once more, now naming the ground truth's source (a headset said hello)."""
        t = self.clock.now_ns()
        self._put(Record(Topic.SESSION_INFO, self._info(t, ground_truth_source), t, t))

    def _config_toml(self) -> str:
        c, rec = self.calibration, self.recording
        q = json.dumps   # a JSON string is a TOML basic string
        lines = ["[live]", f"camera = {q(self.camera.spec)}", f"camera_fps = {self.camera.fps:g}",
                 f"calibration_file = {q(self.calibration_path)}", f"image_width = {c.width}",
                 f"image_height = {c.height}", f"camera_matrix = {[float(v) for v in np.ravel(c.K)]}",
                 f"distortion_coefficients = {[float(v) for v in c.D]}",
                 f"calibration_rms_px = {c.reprojection_error_px if np.isfinite(c.reprojection_error_px) else -1.0}",
                 f"marker_dictionary = {q(rec.marker_dictionary)}", f"marker_id = {rec.marker_id}",
                 f"marker_size_from_cli = {'true' if rec.marker_size_from_cli else 'false'}",
                 f"host = {q(self.host)}", f"port = {self.server.port}",
                 f"gt_controller = {q(rec.headset.gt_hand)}"]
        return "\n".join(lines) + "\n"

    def request_stop(self, reason: str = "interrupted") -> None:
        """Finish: may be called from a signal handler or any thread (only sets a flag)."""
        if not self._stop.is_set():
            self.stop_reason = reason
            self._stop.set()

    def __iter__(self) -> Iterator[Record]:
        self.camera.restart_clock()
        t_begin = self.clock.now_ns()
        if self.tracker is not None:
            self.tracker.start()
        self._camera_thread = threading.Thread(target=self._camera_loop, name="phonepose-live-camera", daemon=True)
        self._camera_thread.start()
        heap: list = []
        seq = itertools.count()
        last: dict[str, int] = {}

        def out(rec: Record) -> Record:
            prev = last.get(rec.topic)
            if prev is not None and rec.log_time_ns < prev:   # a producer was late by more than HOLD_NS
                self.late += 1
                rec = rec._replace(log_time_ns=prev, publish_time_ns=prev)
            last[rec.topic] = rec.log_time_ns
            self.counts[rec.topic] += 1
            return rec

        while True:
            try:
                r = self._queue.get(timeout=0.05)
                heapq.heappush(heap, (r.log_time_ns, next(seq), r))
                while True:   # take everything that is there
                    r = self._queue.get_nowait()
                    heapq.heappush(heap, (r.log_time_ns, next(seq), r))
            except queue.Empty:
                pass
            now = self.clock.now_ns()
            if self.max_duration_ns is not None and now - t_begin >= self.max_duration_ns:
                self.request_stop(f"{keyword('duration_s')} {self.max_duration_ns / 1e9:g} s reached")
            if self._stop.is_set():
                break
            watermark = now - HOLD_NS
            while heap and heap[0][0] <= watermark:
                yield out(heapq.heappop(heap)[2])
        self._shutdown()
        self._finish_tracking()
        for rec in self._closing_logs():
            self._queue.put(rec)
        while True:
            try:
                r = self._queue.get_nowait()
            except queue.Empty:
                break
            heapq.heappush(heap, (r.log_time_ns, next(seq), r))
        while heap:
            yield out(heapq.heappop(heap)[2])

    def _finish_tracking(self) -> None:
        """The last ticks (their estimates into the queue, drained below), then the pose stream ends."""
        if self._tracking_done:
            return
        self._tracking_done = True
        if self.tracker is not None:
            self.tracking_summary = self.tracker.finish()
        if self.pose_server is not None:
            self.pose_server.stop()
            self.tracking_summary += self.pose_server.summary()

    def metadata(self) -> dict[str, dict[str, str]]:
        """MCAP metadata records the recorder writes at the end: the live trackers' figures."""
        return {} if self.tracker is None else {TRACKING_METADATA: self.tracker.metadata()}

    def _shutdown(self) -> None:
        """Stop the camera and the server; afterwards no producer is left."""
        self.recording.recording = False
        if self._camera_thread is not None and self._camera_thread is not threading.current_thread():
            self._camera_thread.join(timeout=10)
        if self._loop is not None and self._server_thread is not None and self._server_thread.is_alive():
            fut = asyncio.run_coroutine_threadsafe(self.server.stop(), self._loop)
            try:
                fut.result(timeout=10)
            except Exception:   # noqa: BLE001 - shutting down; what was received is already queued
                pass
        self._stop_loop()
        self.camera.close()

    def _closing_logs(self) -> list[Record]:
        rec = self.recording
        rec.write_marker_spec()   # no anchor: the last size the page reported
        lines = [f"recording stopped: {self.stop_reason}"]
        if rec.backwards:
            lines.append("samples whose capture time did not increase (written as received; playback skips them): "
                         + ", ".join(f"{t} {n}" for t, n in sorted(rec.backwards.items())))
        if rec.stats["malformed"]:
            lines.append(f"malformed messages ignored: {rec.stats['malformed']} ("
                         + ", ".join(f"{k}: {n}" for k, n in rec.malformed_kinds.most_common()) + ")")
        if rec.repeats:
            lines.append("repeated messages ignored: " + ", ".join(f"{k}: {n}" for k, n in rec.repeats.most_common()))
        if rec.unlogged:
            lines.append("lines not repeated (only counted): " + ", ".join(f"{k}: {n}" for k, n in rec.unlogged.most_common()))
            if rec.unlogged["marker side changes"] and rec.marker_size_m is not None:
                lines.append(f"the session's marker side: {rec.marker_size_m * 1000:.1f} mm")
        if rec.stats["marker size changes ignored"]:
            assert rec.marker_size_m is not None   # counted only once the size was fixed
            lines.append(f"the page reported another marker size {rec.stats['marker size changes ignored']} time(s) after "
                         f"the session's size ({rec.marker_size_m * 1000:.1f} mm) was fixed")
        lines += rec.headset.summary()
        if rec.stats["refused"]:
            lines.append(f"requests refused without the right token: {rec.stats['refused']}")
        if self.camera.reencoded:
            lines.append(f"camera frames encoded as JPEG by the recorder: {self.camera.reencoded} of {self.camera.frames}")
        if rec.marker_size_m is None:
            size = keyword("marker_size_m")
            lines.append(f"no marker size: the page never reported it and {size} was not given; playback needs it "
                         f"(record again, or pass {size})")
        if not rec.anchor_set:
            lines.append("no anchor was set: trackers cannot map the phone's VIO into the display's frame")
        self.summary = lines
        t = self.clock.now_ns()
        out = []
        for i, text in enumerate(lines + self.tracking_summary):
            level = Log.INFO if i == 0 or i >= len(lines) else Log.WARNING
            msg = Log(level=level, message=text, name="phonepose.live")
            msg.timestamp.FromNanoseconds(t)
            out.append(Record(Topic.LOG, msg, t, t))
        return out

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self.request_stop(self.stop_reason or "closed")
        self._shutdown()
        self._finish_tracking()


class LiveRecorder(Recorder):
    """The :class:`Recorder` whose SIGINT/SIGTERM stop the live source, which then drains into the file."""

    source: LiveSource

    def stop(self) -> None:
        self.source.interrupted = True
        self.source.request_stop("interrupted (Ctrl-C / SIGTERM)")


@dataclass
class LiveResult:
    record: RecordResult
    counts: dict
    summary: list[str]
    stop_reason: str
    offsets_ms: list = field(default_factory=list)
    tracking: list[str] = field(default_factory=list)     # the live trackers' closing summary


@dataclass
class LiveTracking:
    """What ``record live -t`` asks: trackers run live, and the pose stream (``pose_port`` None: none)."""
    trackers: list
    rate_hz: float = 20.0
    correction_math: str = "paper"
    pose_host: str = "127.0.0.1"
    pose_port: int | None = 8765


class LiveSession:
    """One live recording: ``start()`` (binds the server, gives the URL), ``run()`` (blocks), ``stop()``."""

    def __init__(self, out: str | os.PathLike, camera: str | int, calibration: str | os.PathLike, *,
                 host: str = "0.0.0.0", port: int = 8443, tls_dir: str | os.PathLike | None = None,
                 dictionary: str = "DICT_4X4_50", marker_id: int = 7, marker_size_m: float | None = None,
                 duration_s: float | None = None, pace: bool = True, rerun_path=None, spawn: bool = False,
                 echo: Callable[[str], None] = print, static_dir: Path | None = None, gt_controller: str = "right",
                 tracking: LiveTracking | None = None):
        from phonepose.record.live.headset import GT_HANDS
        from phonepose.record.live.tls import ensure_certificate

        aruco_dictionary(dictionary)
        if marker_size_m is not None and not 0.0 < marker_size_m < 1.0:
            raise ConfigError(f"{{marker_size_m}} {marker_size_m:g}: expected the marker's side in metres, in (0, 1)",
                              parameter="marker_size_m", value=marker_size_m, expected="in (0, 1) m")
        if duration_s is not None and not duration_s > 0:
            raise ConfigError(f"{{duration_s}} {duration_s:g}: expected > 0 s", parameter="duration_s", value=duration_s,
                              expected="> 0 s")
        if gt_controller not in GT_HANDS:
            raise ConfigError(f"{{gt_controller}} {gt_controller!r}: expected right or left", parameter="gt_controller",
                              value=gt_controller, expected="right or left")
        if not 0 <= port <= 65535:
            raise ConfigError(f"{{port}} {port}: expected 0..65535", parameter="port", value=port, expected="0..65535")
        out = Path(out)
        parent = out.resolve().parent
        if not parent.is_dir() or not os.access(parent, os.W_OK):
            from phonepose.errors import OutputError
            raise OutputError(f"cannot write {out}: directory {parent} does not exist or is not writable")
        self.out = out
        self.echo = echo
        calib = load_calibration(calibration)
        clock = RecorderClock()
        cam = Camera(camera, clock, calib.width, calib.height, pace=pace)
        try:
            hosts = ["localhost", "127.0.0.1", socket.gethostname()]
            self.lan = lan_addresses()
            hosts += self.lan
            if host not in ("0.0.0.0", "::", ""):
                hosts.append(host)
            self.certificate = ensure_certificate(tls_dir, hosts)
            self.token = secrets.token_urlsafe(16)
            self.source = LiveSource(clock, cam, calib, os.fspath(calibration), host=host, port=port,
                                     ssl_context=self.certificate.ssl_context(), token=self.token,
                                     dictionary=dictionary, marker_id=marker_id, marker_size_m=marker_size_m,
                                     duration_s=duration_s, echo=echo, static_dir=static_dir, gt_hand=gt_controller,
                                     tracking=tracking)
        except BaseException:
            cam.close()
            raise
        self.rerun_path, self.spawn = rerun_path, spawn
        self.host = host
        self.port: int | None = None

    def start(self) -> str:
        try:
            self.port = self.source.start()
        except BaseException:
            self.source.camera.close()
            raise
        return self.url

    @property
    def url(self) -> str:
        """The phone page's link."""
        return f"{self._origin}/?token={self.token}"

    @property
    def headset_url(self) -> str:
        """The headset page's link (opened in the headset's browser: the ground truth)."""
        return f"{self._origin}/headset?token={self.token}"

    @property
    def _origin(self) -> str:
        shown = self.host if self.host not in ("0.0.0.0", "::", "") else (self.lan[0] if self.lan else "localhost")
        return f"https://{shown}:{self.port}"

    def run(self) -> LiveResult:
        try:
            recorder = LiveRecorder(self.source, self.out, rerun_path=self.rerun_path, spawn=self.spawn,
                                    flush_every_ns=FLUSH_NS)
        except BaseException:
            self.source.close()
            raise
        self.source.start_ns = self.source.clock.now_ns()   # the session starts now (static part's stamp)
        result = recorder.run()
        result.interrupted = self.source.interrupted
        return LiveResult(result, dict(self.source.counts), self.source.summary, self.source.stop_reason,
                          tracking=self.source.tracking_summary)

    def stop(self, reason: str = "stopped") -> None:
        self.source.request_stop(reason)
