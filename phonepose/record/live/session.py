"""``record live``: a webcam (the display camera) and a phone page (the controller) into one session.

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
- ``/session/info`` and ``/log`` (connections, clock offsets, anchors, refused requests,
  malformed messages, the closing summary).

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
from collections import Counter, deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

import cv2
import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.Log_pb2 import Log

from phonepose import __version__
from phonepose.calibration.camera_file import CameraCalibrationFile, load_calibration
from phonepose.errors import ConfigError
from phonepose.geometry import Pose
from phonepose.pipeline.markers import MarkerRecognizer, aruco_dictionary
from phonepose.pipeline.types import CameraModel, MarkerModel
from phonepose.record.live.camera import Camera, Frame
from phonepose.record.live.clock import RecorderClock
from phonepose.record.recorder import Recorder, RecordResult
from phonepose.record.source import Record
from phonepose.schemas import phonepose_pb2 as pb
from phonepose.schemas.topics import Frame as F
from phonepose.schemas.topics import Topic
from phonepose.session.codec import encode_pose, frame_transform, pose_in_frame

HOLD_NS = 1_000_000_000              # reorder buffer (> the server's 0.5 s wait for a first pong)
ANCHOR_MAX_DT_NS = 100_000_000       # the anchor's camera frame lies within this of the tap
ANCHOR_WAIT_NS = 1_500_000_000       # how long the anchor waits for frames after the tap
ANCHOR_MAX_TRIES = 6                 # frames (closest first) tried for the marker
RING_NS = 3_000_000_000              # camera frames kept for anchors
MARKER_SEEN_EVERY_NS = 250_000_000   # how often a frame is checked for the marker (page status)
MARKER_SEEN_FOR_NS = 1_000_000_000
MARKER_PNG_SIDE_PX = 480
SIZE_MISMATCH = 0.02                 # a later marker size further off than this is reported

# display body: x forward, y left, z up; camera (OpenCV optical): x right, y down, z forward
T_DISPLAY_CAMERA = Pose.from_matrix(np.array([[0.0, 0.0, 1.0, 0.0],
                                              [-1.0, 0.0, 0.0, 0.0],
                                              [0.0, -1.0, 0.0, 0.0],
                                              [0.0, 0.0, 0.0, 1.0]]))
T_BODY_MARKER = Pose.identity()       # marker frame = controller body (see the module docstring)


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


class LiveRecording:
    """What the server and the camera thread report, turned into records (thread-safe enough:
    records go through a ``queue.Queue``; server calls all come from the one asyncio thread)."""

    def __init__(self, clock: RecorderClock, put: Callable[[Record], None], camera: CameraModel, dictionary: str,
                 marker_id: int, marker_size_m: float | None, echo: Callable[[str], None]):
        self.clock = clock
        self._put = put
        self.camera = camera
        self.marker_dictionary = dictionary
        self.marker_id = marker_id
        self.marker_size_m = marker_size_m
        self.marker_size_from_cli = marker_size_m is not None
        self.marker_spec_written = self.marker_size_from_cli    # written in static() then
        self.echo = echo
        self.stats: Counter = Counter()
        self.malformed_kinds: Counter = Counter()
        self.repeats: Counter = Counter()            # kind -> harmless repeated messages (see repeated())
        self.backwards: Counter = Counter()          # topic -> samples whose capture time did not increase
        self._last_capture: dict[str, int] = {}
        self.anchor_set = False
        self.recording = True
        self.offsets: list[tuple[str, float, float]] = []
        self._frames: deque[Frame] = deque()
        self._frames_lock = threading.Lock()
        self.latest_frame_ns: int | None = None
        self.camera_ended = False
        self._marker_seen_ns: int | None = None
        self._next_check_ns = 0
        self._detector = cv2.aruco.ArucoDetector(aruco_dictionary(dictionary), cv2.aruco.DetectorParameters())

    # ------------------------------------------------------------------ output
    def emit(self, topic: str, msg, log_time_ns: int | None = None) -> None:
        t = self.clock.now_ns() if log_time_ns is None else int(log_time_ns)
        self._put(Record(topic, msg, t, t))

    def log(self, text: str, level: str = "info", echo: bool = True) -> None:
        lvl = {"info": Log.INFO, "warning": Log.WARNING, "error": Log.ERROR}[level]
        msg = Log(level=lvl, message=text, name="phonepose.live")
        t = self.clock.now_ns()
        msg.timestamp.FromNanoseconds(t)
        self.emit(Topic.LOG, msg, t)
        if echo:
            self.echo(("warning: " if level != "info" else "") + text)

    def status(self) -> dict:
        seen = (self._marker_seen_ns is not None and self.latest_frame_ns is not None
                and self.latest_frame_ns - self._marker_seen_ns <= MARKER_SEEN_FOR_NS)
        return {"type": "status", "recording": self.recording, "anchor": self.anchor_set, "marker_seen": bool(seen)}

    # ------------------------------------------------------------------ camera thread
    def add_frame(self, frame: Frame) -> None:
        msg = CompressedImage(frame_id=F.DISPLAY_CAMERA, format="jpeg", data=frame.jpeg)
        msg.timestamp.FromNanoseconds(frame.t_ns)
        self.emit(Topic.CAMERA_IMAGE, msg, frame.t_ns)
        self.emit(Topic.DISPLAY_VIO_POSE, pose_in_frame(Pose.identity(), F.DISPLAY_VIO, frame.t_ns), frame.t_ns)
        with self._frames_lock:
            self._frames.append(frame)
            while self._frames and frame.t_ns - self._frames[0].t_ns > RING_NS:
                self._frames.popleft()
            self.latest_frame_ns = frame.t_ns
        if frame.t_ns >= self._next_check_ns:   # is the marker in view? (for the page's status line)
            self._next_check_ns = frame.t_ns + MARKER_SEEN_EVERY_NS
            gray = cv2.imdecode(np.frombuffer(frame.jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
            if gray is not None:
                _, ids, _ = self._detector.detectMarkers(gray)
                if ids is not None and self.marker_id in ids.reshape(-1).tolist():
                    self._marker_seen_ns = frame.t_ns

    # ------------------------------------------------------------------ page messages
    def on_hello(self, who: str, msg: dict) -> None:
        ua = msg["user_agent"] or "unknown browser"
        if msg["webxr"]:
            self.log(f"{who}: {ua}; WebXR immersive-ar available")
        else:
            self.log(f"{who}: {ua}; no WebXR immersive-ar ({msg['message'] or 'no reason given'}): no 6DoF pose "
                     f"will come, only IMU", level="warning")

    def on_marker(self, who: str, msg: dict) -> str | None:
        if msg["dictionary"] != self.marker_dictionary or msg["id"] != self.marker_id:
            text = (f"the page shows {msg['dictionary']} id {msg['id']}, the recorder looks for "
                    f"{self.marker_dictionary} id {self.marker_id}: reload the page")
            self.log(f"{who}: {text}", level="error")
            return text
        size = msg["size_m"]
        detail = f"{size * 1000:.1f} mm (ppi {msg['ppi']:g}, device pixel ratio {msg['device_pixel_ratio']:g})"
        if not self.marker_spec_written:      # the size in effect until the anchor fixes it
            if size != self.marker_size_m:    # logged when it changes, not at every message (a reconnect repeats it)
                self.log(f"{who}: marker side {detail}")
            self.marker_size_m = size
            return None
        assert self.marker_size_m is not None   # the spec is written with the size
        if abs(size - self.marker_size_m) <= SIZE_MISMATCH * self.marker_size_m:
            return None
        self.stats["marker size changes ignored"] += 1
        if self.marker_size_from_cli:
            self.log(f"{who}: the page reports a marker side of {detail}; the session uses --marker-size "
                     f"{self.marker_size_m * 1000:.1f} mm", level="warning")
            return None
        text = (f"the marker's size changed to {size * 1000:.1f} mm after the anchor; the session keeps "
                f"{self.marker_size_m * 1000:.1f} mm, so marker poses from now on are off: restore the layout "
                f"(controls, rotation) the phone had when anchoring")
        self.log(f"{who}: {text}", level="warning")
        return text

    def write_marker_spec(self, t_ns: int | None = None) -> None:
        """Fix the session's marker size (the one in effect now): at the first anchor, or at the end."""
        if self.marker_spec_written or self.marker_size_m is None:
            return
        t = self.clock.now_ns() if t_ns is None else t_ns
        spec = pb.MarkerSpec(dictionary=self.marker_dictionary, id=self.marker_id, size_m=self.marker_size_m)
        spec.timestamp.FromNanoseconds(t)
        encode_pose(T_BODY_MARKER, spec.pose_in_body)
        self.emit(Topic.CONTROLLER_MARKER, spec, t)
        self.marker_spec_written = True

    def _check_order(self, topic: str, capture_ns: int) -> None:
        last = self._last_capture.get(topic)
        if last is not None and capture_ns <= last:
            if not self.backwards[topic]:
                self.log(f"{topic}: a sample's capture time does not increase ({(capture_ns - last) / 1e6:+.1f} ms); "
                         f"written as received, playback skips such samples (count in the closing summary)",
                         level="warning")
            self.backwards[topic] += 1
        else:
            self._last_capture[topic] = capture_ns

    def on_pose(self, capture_ns: int, receipt_ns: int, p, q) -> None:
        self._check_order(Topic.CONTROLLER_VIO_POSE, capture_ns)
        self.stats["poses"] += 1
        self.emit(Topic.CONTROLLER_VIO_POSE, pose_in_frame(Pose.from_xyzw(p, q), F.CONTROLLER_VIO, capture_ns),
                  receipt_ns)

    def on_imu(self, capture_ns: int, receipt_ns: int, gyro, accel) -> None:
        self._check_order(Topic.CONTROLLER_IMU, capture_ns)
        self.stats["imu"] += 1
        msg = pb.Imu(frame_id=F.CONTROLLER, gyro_x=gyro[0], gyro_y=gyro[1], gyro_z=gyro[2],
                     accel_x=accel[0], accel_y=accel[1], accel_z=accel[2])
        msg.timestamp.FromNanoseconds(capture_ns)
        self.emit(Topic.CONTROLLER_IMU, msg, receipt_ns)

    def repeated(self, kind: str, who: str) -> None:
        """A harmless message the page should not repeat: logged the first time, counted (closing summary)."""
        self.repeats[kind] += 1
        if self.repeats[kind] == 1:
            self.log(f"{who}: {kind}: ignored; further ones are only counted (closing summary)", level="warning")

    def refused(self, remote: str, path: str, had_token: bool) -> None:
        self.stats["refused"] += 1
        if self.stats["refused"] <= 10:
            self.log(f"refused {path} from {remote}: {'wrong' if had_token else 'no'} token"
                     + (" (further refusals are only counted)" if self.stats["refused"] == 10 else ""),
                     level="warning")

    # ------------------------------------------------------------------ anchor
    def _frames_near(self, t_ns: int) -> list[Frame]:
        with self._frames_lock:
            near = [f for f in self._frames if abs(f.t_ns - t_ns) <= ANCHOR_MAX_DT_NS]
        near.sort(key=lambda f: abs(f.t_ns - t_ns))
        return near[:ANCHOR_MAX_TRIES]

    def find_marker(self, t_ns: int):
        """(frame, MarkerObservation) of the frame closest to ``t_ns`` that shows the marker, or (n tried, None)."""
        assert self.marker_size_m is not None   # resolve_anchor refuses before the size is known
        recognizer = MarkerRecognizer(self.camera, MarkerModel(self.marker_dictionary, self.marker_id,
                                                               self.marker_size_m, T_BODY_MARKER))
        frames = self._frames_near(t_ns)
        for frame in frames:
            gray = cv2.imdecode(np.frombuffer(frame.jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
            if gray is None:
                continue
            recognizer.reset()
            obs = recognizer.recognize(gray, Pose.identity(), frame.t_ns)
            if obs is not None and obs.T_dvio_controller is not None:
                return frame, obs
        return len(frames), None

    async def resolve_anchor(self, capture_ns: int, p, q) -> tuple[bool, str]:
        """Anchor at the tap: the viewer pose (controller_vio) and the marker's pose (display_vio)."""
        if self.marker_size_m is None:
            text = "anchor refused: the page has not reported the marker size yet"
            self.log(text, level="warning")
            return False, text
        waited = 0
        while not self.camera_ended and (self.latest_frame_ns is None
                                         or self.latest_frame_ns < capture_ns + ANCHOR_MAX_DT_NS):
            if waited >= ANCHOR_WAIT_NS:
                break
            await asyncio.sleep(0.02)
            waited += 20_000_000
        loop = asyncio.get_running_loop()
        frame, obs = await loop.run_in_executor(None, self.find_marker, capture_ns)
        if obs is None:
            text = (f"anchor refused: the marker was not recognised in the camera within "
                    f"{ANCHOR_MAX_DT_NS / 1e6:.0f} ms of the tap ({frame} frames looked at); hold the phone's screen "
                    f"in the camera's view and tap again")
            self.log(text, level="warning")
            return False, text
        T_dvio_controller = obs.T_dvio_controller
        t = self.clock.now_ns()
        self.write_marker_spec(t)
        self.emit(Topic.CONTROLLER_ANCHOR, pose_in_frame(Pose.from_xyzw(p, q), F.CONTROLLER_VIO, capture_ns), t)
        self.emit(Topic.DISPLAY_ANCHOR, pose_in_frame(T_dvio_controller, F.DISPLAY_VIO, frame.t_ns), t)
        self.anchor_set = True
        self.stats["anchors"] += 1
        dist = float(np.linalg.norm(obs.T_camera_marker.translation))
        self.log(f"anchor set: camera frame {(frame.t_ns - capture_ns) / 1e6:+.0f} ms from the tap, marker "
                 f"{dist:.2f} m from the camera, reprojection error {obs.reprojection_error_px:.2f} px")
        return True, "anchor set"


class LiveSource:
    """The recorder's :class:`~phonepose.record.source.Source` for a live recording."""

    def __init__(self, clock: RecorderClock, camera: Camera, calibration: CameraCalibrationFile, calibration_path: str,
                 *, host: str, port: int, ssl_context, token: str, dictionary: str, marker_id: int,
                 marker_size_m: float | None, duration_s: float | None, echo: Callable[[str], None],
                 static_dir: Path | None = None):
        from phonepose.record.live.server import STATIC_DIR, LiveServer

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
        self.recording = LiveRecording(clock, self._queue.put, cam_model, dictionary, marker_id, marker_size_m, echo)
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

    # ------------------------------------------------------------------ start
    def start(self) -> int:
        """Bind the server (its own thread and asyncio loop); returns the port."""
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
                              f"(choose another --port)") from None

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
        info = pb.SessionInfo(source="live", scenario="live", phonepose_version=__version__,
                              config_toml=self._config_toml(),
                              description=f"live recording: camera {self.camera.spec} ({c.width}x{c.height}), "
                                          f"marker {rec.marker_dictionary} id {rec.marker_id}")
        info.timestamp.FromNanoseconds(t0)
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
        return out

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
                 f"host = {q(self.host)}", f"port = {self.server.port}"]
        return "\n".join(lines) + "\n"

    def request_stop(self, reason: str = "interrupted") -> None:
        """Finish: may be called from a signal handler or any thread (only sets a flag)."""
        if not self._stop.is_set():
            self.stop_reason = reason
            self._stop.set()

    def __iter__(self) -> Iterator[Record]:
        self.camera.restart_clock()
        t_begin = self.clock.now_ns()
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
                self.request_stop(f"--duration {self.max_duration_ns / 1e9:g} s reached")
            if self._stop.is_set():
                break
            watermark = now - HOLD_NS
            while heap and heap[0][0] <= watermark:
                yield out(heapq.heappop(heap)[2])
        self._shutdown()
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
        if rec.stats["marker size changes ignored"]:
            assert rec.marker_size_m is not None   # counted only once the size was fixed
            lines.append(f"the page reported another marker size {rec.stats['marker size changes ignored']} time(s) after "
                         f"the session's size ({rec.marker_size_m * 1000:.1f} mm) was fixed")
        if rec.stats["refused"]:
            lines.append(f"requests refused without the right token: {rec.stats['refused']}")
        if self.camera.reencoded:
            lines.append(f"camera frames encoded as JPEG by the recorder: {self.camera.reencoded} of {self.camera.frames}")
        if rec.marker_size_m is None:
            lines.append("no marker size: the page never reported it and --marker-size was not given; playback needs it "
                         "(record again, or pass --marker-size)")
        if not rec.anchor_set:
            lines.append("no anchor was set: trackers cannot map the phone's VIO into the display's frame")
        self.summary = lines
        t = self.clock.now_ns()
        out = []
        for i, text in enumerate(lines):
            level = Log.INFO if i == 0 else Log.WARNING
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


class LiveSession:
    """One live recording: ``start()`` (binds the server, gives the URL), ``run()`` (blocks), ``stop()``."""

    def __init__(self, out: "str | os.PathLike", camera: "str | int", calibration: "str | os.PathLike", *,
                 host: str = "0.0.0.0", port: int = 8443, tls_dir: "str | os.PathLike | None" = None,
                 dictionary: str = "DICT_4X4_50", marker_id: int = 7, marker_size_m: float | None = None,
                 duration_s: float | None = None, pace: bool = True, rerun_path=None, spawn: bool = False,
                 echo: Callable[[str], None] = print, static_dir: Path | None = None):
        from phonepose.record.live.tls import ensure_certificate

        aruco_dictionary(dictionary)
        if marker_size_m is not None and not 0.0 < marker_size_m < 1.0:
            raise ConfigError(f"--marker-size {marker_size_m:g}: expected the marker's side in metres, in (0, 1)")
        if duration_s is not None and not duration_s > 0:
            raise ConfigError(f"--duration {duration_s:g}: expected > 0 s")
        if not 0 <= port <= 65535:
            raise ConfigError(f"--port {port}: expected 0..65535")
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
                                     duration_s=duration_s, echo=echo, static_dir=static_dir)
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
        shown = self.host if self.host not in ("0.0.0.0", "::", "") else (self.lan[0] if self.lan else "localhost")
        return f"https://{shown}:{self.port}/?token={self.token}"

    def run(self) -> LiveResult:
        try:
            recorder = LiveRecorder(self.source, self.out, rerun_path=self.rerun_path, spawn=self.spawn)
        except BaseException:
            self.source.close()
            raise
        self.source.start_ns = self.source.clock.now_ns()   # the session starts now (static part's stamp)
        result = recorder.run()
        result.interrupted = self.source.interrupted
        return LiveResult(result, dict(self.source.counts), self.source.summary, self.source.stop_reason)

    def stop(self, reason: str = "stopped") -> None:
        self.source.request_stop(reason)
