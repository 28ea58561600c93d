"""What a live recording receives, turned into session records: :class:`LiveRecording`.

The server (``server.py``, the pages' messages) and the camera thread (``session.py``) report to it;
it writes the records (camera frames, controller VIO and IMU, anchors, marker size, ``/log``; the
headset's ground truth through its :class:`~phonepose.record.live.headset.HeadsetGroundTruth`) through
the recorder's queue, and resolves anchors against the recent camera frames. It imports neither of
them, so ``server.py`` and ``session.py`` both depend on it and not on each other.
"""

from __future__ import annotations

import asyncio
import threading
from collections import Counter, deque
from collections.abc import Callable

import cv2
import numpy as np
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.Log_pb2 import Log

from phonepose.errors import keyword
from phonepose.geometry import Pose
from phonepose.pipeline.markers import MarkerRecognizer, aruco_dictionary
from phonepose.pipeline.types import CameraModel, MarkerModel
from phonepose.record.live.camera import Frame
from phonepose.record.live.clock import RecorderClock
from phonepose.record.live.headset import TEXT_LIMIT, HeadsetGroundTruth
from phonepose.record.source import Record
from phonepose.schemas import phonepose_pb2 as pb
from phonepose.schemas.topics import Frame as F
from phonepose.schemas.topics import Topic
from phonepose.session.codec import encode_pose, pose_in_frame
from phonepose.text import printable

MARKER_SIDE_LINES = 3   # marker side changes logged per connection before the anchor (then only counted)

ANCHOR_MAX_DT_NS = 100_000_000       # the anchor's camera frame lies within this of the tap
ANCHOR_WAIT_NS = 1_500_000_000       # how long the anchor waits for frames after the tap
ANCHOR_MAX_TRIES = 6                 # frames (closest first) tried for the marker
RING_NS = 3_000_000_000              # camera frames kept for anchors
MARKER_SEEN_EVERY_NS = 250_000_000   # how often a frame is checked for the marker (page status)
MARKER_SEEN_FOR_NS = 1_000_000_000
SIZE_MISMATCH = 0.02                 # a later marker size further off than this is reported

# display body: x forward, y left, z up; camera (OpenCV optical): x right, y down, z forward
T_DISPLAY_CAMERA = Pose.from_matrix(np.array([[0.0, 0.0, 1.0, 0.0],
                                              [-1.0, 0.0, 0.0, 0.0],
                                              [0.0, -1.0, 0.0, 0.0],
                                              [0.0, 0.0, 0.0, 1.0]]))
T_BODY_MARKER = Pose.identity()       # marker frame = controller body (see the module docstring)


class LiveRecording:
    """What the server and the camera thread report, turned into records (thread-safe enough:
    records go through a ``queue.Queue``; server calls all come from the one asyncio thread)."""

    def __init__(self, clock: RecorderClock, put: Callable[[Record], None], camera: CameraModel, dictionary: str,
                 marker_id: int, marker_size_m: float | None, echo: Callable[[str], None], gt_hand: str = "right"):
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
        self.unlogged: Counter = Counter()           # kind -> warnings only counted (see limited())
        self._logged: Counter = Counter()            # (connection, kind) -> lines logged
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
        self.headset = HeadsetGroundTruth(self, gt_hand)
        # called with SessionInfo.ground_truth_source when a headset names it (LiveSource writes the info again)
        self.ground_truth_source_changed: Callable[[str], None] = lambda source: None

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
        ua = printable(msg["user_agent"] or "unknown browser", TEXT_LIMIT)
        reason = printable(msg["message"] or "no reason given", TEXT_LIMIT)
        if msg["webxr"]:
            self.log(f"{who}: {ua}; WebXR immersive-ar available")
        else:
            self.log(f"{who}: {ua}; no WebXR immersive-ar ({reason}): no 6DoF pose "
                     f"will come, only IMU", level="warning")

    def on_marker(self, who: str, msg: dict) -> str | None:
        if msg["dictionary"] != self.marker_dictionary or msg["id"] != self.marker_id:
            text = (f"the page shows {printable(msg['dictionary'], TEXT_LIMIT)} id {msg['id']}, the recorder looks for "
                    f"{self.marker_dictionary} id {self.marker_id}: reload the page")
            self.limited(who, "reports of another marker", text, level="error")
            return text
        size = msg["size_m"]
        detail = f"{size * 1000:.1f} mm (ppi {msg['ppi']:g}, device pixel ratio {msg['device_pixel_ratio']:g})"
        if not self.marker_spec_written:      # the size in effect until the anchor fixes it
            if size != self.marker_size_m:    # logged when it changes, not at every message (a reconnect repeats it)
                self.limited(who, "marker side changes", f"marker side {detail}", limit=MARKER_SIDE_LINES)
            self.marker_size_m = size
            return None
        assert self.marker_size_m is not None   # the spec is written with the size
        if abs(size - self.marker_size_m) <= SIZE_MISMATCH * self.marker_size_m:
            return None
        self.stats["marker size changes ignored"] += 1
        if self.marker_size_from_cli:
            self.limited(who, "other marker sizes", f"the page reports a marker side of {detail}; the session uses "
                         f"{keyword('marker_size_m')} {self.marker_size_m * 1000:.1f} mm", level="warning",
                         count=False)
            return None
        text = (f"the marker's size changed to {size * 1000:.1f} mm after the anchor; the session keeps "
                f"{self.marker_size_m * 1000:.1f} mm, so marker poses from now on are off: restore the layout "
                f"(controls, rotation) the phone had when anchoring")
        self.limited(who, "other marker sizes", text, level="warning", count=False)
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

    def check_order(self, topic: str, capture_ns: int) -> None:
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
        self.check_order(Topic.CONTROLLER_VIO_POSE, capture_ns)
        self.stats["poses"] += 1
        self.emit(Topic.CONTROLLER_VIO_POSE, pose_in_frame(Pose.from_xyzw(p, q), F.CONTROLLER_VIO, capture_ns),
                  receipt_ns)

    def on_imu(self, capture_ns: int, receipt_ns: int, gyro, accel) -> None:
        self.check_order(Topic.CONTROLLER_IMU, capture_ns)
        self.stats["imu"] += 1
        msg = pb.Imu(frame_id=F.CONTROLLER, gyro_x=gyro[0], gyro_y=gyro[1], gyro_z=gyro[2],
                     accel_x=accel[0], accel_y=accel[1], accel_z=accel[2])
        msg.timestamp.FromNanoseconds(capture_ns)
        self.emit(Topic.CONTROLLER_IMU, msg, receipt_ns)

    def limited(self, who: str, kind: str, text: str, level: str = "info", limit: int = 1,
                count: bool = True) -> None:
        """A line a page's message causes, at most ``limit`` times per connection and ``kind`` (a page repeating
        a message must not flood the terminal); the last of them says so, later ones are only counted
        (``unlogged``, closing summary; ``count`` False: the caller counts them itself)."""
        self._logged[(who, kind)] += 1
        n = self._logged[(who, kind)]
        if n < limit:
            self.log(f"{who}: {text}", level=level)
        elif n == limit:
            self.log(f"{who}: {text} (further {kind} from this connection are only counted: closing summary)",
                     level=level)
        elif count:
            self.unlogged[kind] += 1

    def repeated(self, kind: str, who: str) -> None:
        """A harmless message the page should not repeat: logged the first time, counted (closing summary)."""
        self.repeats[kind] += 1
        if self.repeats[kind] == 1:
            self.log(f"{who}: {kind}: ignored; further ones are only counted (closing summary)", level="warning")

    def refused(self, remote: str, path: str, had_token: bool) -> None:
        self.stats["refused"] += 1
        if self.stats["refused"] <= 10:
            self.log(f"refused {printable(path, TEXT_LIMIT)} from {printable(remote, TEXT_LIMIT)}: "
                     f"{'wrong' if had_token else 'no'} token"
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
