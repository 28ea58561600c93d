"""``record live``: the server, the clock offset, the certificate, and whole recordings driven by a
scripted phone (an aiohttp WebSocket client) with a video file as the camera.

The video shows the marker at a known, slowly moving pose (drawn with a homography from the
camera's intrinsics); the scripted phone sends the VIO poses of that same motion in its own
frame (a fixed transform away from display_vio) on a clock offset by :data:`OFFSET_NS`.
"""

from __future__ import annotations

import asyncio
import errno
import json
import math
import os
import signal
import stat
import subprocess
import sys
import threading
import time
import tomllib

import aiohttp
import cv2
import numpy as np
import pytest
from conftest import DEADLINE_S, require_browser, wait_until, wait_until_async, within
from scipy.spatial.transform import Rotation

from phonepose.calibration.camera_file import CameraCalibrationFile, save_calibration
from phonepose.geometry import Pose
from phonepose.playback.engine import run_playback
from phonepose.record.live import LiveSession
from phonepose.record.live.clock import OffsetEstimator
from phonepose.record.live.recording import T_DISPLAY_CAMERA
from phonepose.record.live.server import Malformed, parse_message
from phonepose.record.live.tls import ensure_certificate
from phonepose.schemas.topics import Frame, Topic
from phonepose.session import SessionReader, codec

W, H, FPS = 640, 480, 30.0
K = np.array([[600.0, 0, 320.0], [0, 600.0, 240.0], [0, 0, 1]])
MARKER_SIZE = 0.06
VIDEO_S = 3.0
OFFSET_NS = 1_234_567_890          # the phone clock runs this far ahead of the recorder's
TAP_S = 1.0                        # when the scripted user taps "anchor" (video time)
T_CVIO_DVIO = Pose.from_rotvec([0.4, -0.2, 1.1], [0.0, 0.0, 0.7])   # phone VIO world vs display_vio
R_CAM_MARKER0 = Rotation.from_euler("x", 180, degrees=True)          # marker facing the camera


def T_camera_marker(t_s: float) -> Pose:
    """The marker's true pose in the camera at video time ``t``: a slow sway, a little rotation."""
    rot = Rotation.from_euler("yx", [12 * math.sin(2 * math.pi * t_s / 2.5), 8 * math.sin(2 * math.pi * t_s / 3.1)],
                              degrees=True)
    pos = np.array([0.03 * math.sin(2 * math.pi * t_s / 2.0), 0.015 * math.cos(2 * math.pi * t_s / 2.7),
                    0.32 + 0.02 * math.sin(2 * math.pi * t_s / 1.9)])
    return Pose(rot * R_CAM_MARKER0, pos)


def T_dvio_controller(t_s: float) -> Pose:
    return T_DISPLAY_CAMERA @ T_camera_marker(t_s)          # controller body = marker frame


def marker_image(side: int = 600, quiet: int = 150) -> np.ndarray:
    """Marker 7 of DICT_4X4_50, ``side`` px, with a white quiet zone of ``quiet`` px: what draw_marker warps."""
    marker = cv2.aruco.generateImageMarker(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50), 7, side)
    return cv2.copyMakeBorder(marker, quiet, quiet, quiet, quiet, cv2.BORDER_CONSTANT, value=255)


def draw_marker(pose: Pose, marker: np.ndarray, quiet: int = 150, side: int = 600) -> np.ndarray:
    """The camera's view (W x H, BGR) of the marker (side MARKER_SIZE) at ``pose`` = T_camera_marker."""
    h = MARKER_SIZE / 2
    corners = np.array([[-h, h, 0], [h, h, 0], [h, -h, 0], [-h, -h, 0]])
    p = pose.apply(corners)
    px = (K @ (p / p[:, 2:3]).T).T[:, :2]
    src = np.array([[quiet, quiet], [quiet + side, quiet], [quiet + side, quiet + side], [quiet, quiet + side]],
                   dtype=np.float32)
    Hm = cv2.getPerspectiveTransform(src, px.astype(np.float32))
    img = cv2.warpPerspective(marker, Hm, (W, H), flags=cv2.INTER_AREA, borderValue=255)
    return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)


def write_marker_video(path, motion, seconds: float) -> None:
    """A video (MJPG, FPS) of the marker at ``motion(t)`` = T_camera_marker at video time ``t``."""
    marker = marker_image()
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), FPS, (W, H))
    for i in range(int(seconds * FPS)):
        vw.write(draw_marker(motion(i / FPS), marker))
    vw.release()


@pytest.fixture(scope="module")
def media(tmp_path_factory):
    d = tmp_path_factory.mktemp("live")
    video = d / "cam.avi"
    write_marker_video(video, T_camera_marker, VIDEO_S)
    calib = d / "cam.yaml"
    save_calibration(calib, CameraCalibrationFile(K, np.zeros(5), W, H, 0.2, "test"))
    return d, video, calib


@pytest.fixture(scope="module")
def long_media(media):
    """``media`` with a still video (2 fps) that outlasts every wait of the suite: for the tests that
    stop the recording themselves, which must not depend on finishing within the 3 s video."""
    d, video, calib = media
    still = d / "still.avi"
    frame = cv2.VideoCapture(str(video)).read()[1]
    vw = cv2.VideoWriter(str(still), cv2.VideoWriter_fourcc(*"MJPG"), 2.0, (W, H))
    for _ in range(int(2 * DEADLINE_S * 2.0)):
        vw.write(frame)
    vw.release()
    return d, still, calib


# ---------------------------------------------------------------------------------------------- units
def test_offset_estimator_takes_the_minimum_round_trip():
    est = OffsetEstimator()
    true_offset = 5_000_000_000
    # (send, up delay, down delay): asymmetric slow exchanges, one fast symmetric one
    for send, up, down in [(0, 40e6, 5e6), (1e9, 3e6, 30e6), (2e9, 1e6, 1e6), (3e9, 20e6, 2e6)]:
        ping = est.ping(int(send))
        t_client_ms = (send + up + true_offset) / 1e6
        est.pong(ping["id"], t_client_ms, int(send + up + down))
    assert est.best().rtt_ns == 2_000_000
    assert est.offset_ns == true_offset
    assert est.pong(999, 1.0, 10) is None and est.rejected == 1      # answers no ping of ours
    assert est.to_recorder_ns((7e9 + true_offset) / 1e6) == 7_000_000_000


def test_certificate_is_made_once_then_reused(tmp_path):
    d = tmp_path / "tls"
    a = ensure_certificate(d, ["localhost", "127.0.0.1", "192.168.1.20"])
    assert a.created and stat.S_IMODE(os.stat(a.key_path).st_mode) == 0o600
    b = ensure_certificate(d, ["localhost", "192.168.1.20"])
    assert not b.created and b.sha256 == a.sha256
    c = ensure_certificate(d, ["localhost", "10.0.0.5"])     # a new address: a new certificate
    assert c.created and c.sha256 != a.sha256


def _break_pair(d, how: str, cut: float) -> str:
    """Damage the pair in ``d`` as ``how`` says (``cut``: the fraction of a file kept); the reason expected."""
    cert, key = d / "cert.pem", d / "key.pem"
    if how in ("key cut", "cert cut"):
        f = key if how == "key cut" else cert
        f.write_bytes(f.read_bytes()[:int(len(f.read_bytes()) * cut)])
        if cut == 0.0:
            return f"{f.name}: empty"
        return f"{f.name}: not a PEM {'private key' if f is key else 'certificate'} (cut short or damaged)"
    if how == "cert without key":
        key.unlink()
        return f"key.pem: {os.strerror(errno.ENOENT)}"
    if how == "key without cert":
        cert.unlink()
        return f"cert.pem: {os.strerror(errno.ENOENT)}"
    if how == "both empty":
        cert.write_bytes(b"")
        key.write_bytes(b"")
        return "cert.pem: empty"
    assert how == "mismatched"
    other = ensure_certificate(d.parent / "other", ["localhost"])
    key.write_bytes(other.key_path.read_bytes())
    return "key.pem is not the key of cert.pem"


@pytest.mark.parametrize("how, cut", [(how, cut) for how in ("key cut", "cert cut") for cut in (0.0, 0.01, 0.3, 0.6, 0.95)]
                         + [(how, 0.0) for how in ("cert without key", "key without cert", "both empty", "mismatched")])
def test_a_broken_certificate_pair_is_replaced_with_a_reason(tmp_path, how, cut):
    """A pair that cannot be used (what an interrupted write or a user's edit leaves) is replaced, with the reason
    naming the file; the new pair loads into an SSL context and is reused by the next run."""
    d = tmp_path / "tls"
    hosts = ["localhost", "127.0.0.1"]
    first = ensure_certificate(d, hosts)
    reason = _break_pair(d, how, cut)
    again = ensure_certificate(d, hosts)
    assert (again.created, again.broken) == (True, reason) and again.sha256 != first.sha256
    assert again.ssl_context() is not None
    assert stat.S_IMODE(os.stat(again.key_path).st_mode) == 0o600
    assert sorted(p.name for p in d.iterdir()) == ["cert.pem", "key.pem"]          # no temporary left
    reused = ensure_certificate(d, hosts)
    assert (reused.created, reused.broken, reused.sha256) == (False, "", again.sha256)


@pytest.mark.parametrize("failing", [1, 2])
def test_a_write_cut_between_the_files_leaves_a_pair_the_next_run_replaces(tmp_path, monkeypatch, failing):
    """Each file is renamed into place whole; a run stopped at the first or second rename leaves the old pair or
    a new key with the old certificate, and the next run uses the old pair or makes a new one."""
    from phonepose.record.live import tls

    d = tmp_path / "tls"
    old = ensure_certificate(d, ["localhost"])
    renames = []
    real_replace = os.replace

    def replace(src, dst):
        renames.append(dst)
        if len(renames) == failing:
            raise KeyboardInterrupt
        real_replace(src, dst)

    monkeypatch.setattr(tls.os, "replace", replace)
    with pytest.raises(KeyboardInterrupt):
        ensure_certificate(d, ["localhost", "10.0.0.5"])      # a new address: a new pair is written
    monkeypatch.setattr(tls.os, "replace", real_replace)
    assert sorted(p.name for p in d.iterdir()) == ["cert.pem", "key.pem"]
    after = ensure_certificate(d, ["localhost"])
    if failing == 1:   # nothing renamed: the old pair is whole and still used
        assert (after.created, after.broken, after.sha256) == (False, "", old.sha256)
    else:              # the new key is in place, the old certificate is not its certificate
        assert after.created and after.broken == "key.pem is not the key of cert.pem"
        assert after.ssl_context() is not None


@pytest.mark.parametrize("text, kind", [
    ("{not json", "not JSON"),
    ("[1, 2]", "not a JSON object with a string 'type'"),
    ('{"type": "teleport"}', "unknown message type"),
    ('{"type": "pose", "p": [0, 0, 0], "q": [0, 0, 0, 1]}', "pose without 't'"),
    ('{"type": "pose", "t": 1, "p": [0, 0], "q": [0, 0, 0, 1]}', "pose 'p' is not 3 finite numbers"),
    ('{"type": "pose", "t": 1, "p": [0, 0, 0], "q": [0, 0, 0, 2]}', "pose 'q' is not a unit quaternion"),
    ('{"type": "imu", "t": "x", "gyro": [0, 0, 0], "accel": [0, 0, 9.8]}', "imu 't' is not a finite number"),
    ('{"type": "imu", "t": 1, "gyro": [0, 0, NaN], "accel": [0, 0, 9.8]}', "imu 'gyro' is not 3 finite numbers"),
    ('{"type": "marker", "dictionary": "DICT_4X4_50", "id": 7, "size_m": 5}', "marker 'size_m' must be in (0, 1) m"),
    ('{"type": "pong", "id": "a", "t": 1}', "pong 'id' is not an integer"),
    ('{"type": "imu", "t": 1' + "0" * 400 + ', "gyro": [0, 0, 0], "accel": [0, 0, 9.8]}', "imu 't' is not a finite number"),
    ("[" * 100000 + "]" * 100000, "not JSON"),
    # finite but beyond what the int64-ns stamping holds (MAX_STAMP_MS), or beyond any sensor (MAX_VALUE)
    ('{"type": "imu", "t": 1e305, "gyro": [0, 0, 0], "accel": [0, 0, 9.8]}', "imu 't' is out of range"),
    ('{"type": "pose", "t": -4.1e12, "p": [0, 0, 0], "q": [0, 0, 0, 1]}', "pose 't' is out of range"),
    ('{"type": "pong", "id": 1, "t": 1e305}', "pong 't' is out of range"),
    ('{"type": "xrframe", "t": 1e305, "viewer": null, "controllers": []}', "xrframe 't' is out of range"),
    ('{"type": "pose", "t": 1, "p": [1e308, 0, 0], "q": [0, 0, 0, 1]}', "pose 'p' is out of range"),
    ('{"type": "imu", "t": 1, "gyro": [0, 0, 0], "accel": [0, -2e6, 9.8]}', "imu 'accel' is out of range"),
    ('{"type": "pong", "id": 123456789012345678901234567890, "t": 1}', "pong 'id' is out of range"),
    ('{"type": "marker", "dictionary": "DICT_4X4_50", "id": -1, "size_m": 0.05}', "marker 'id' is out of range"),
])
def test_malformed_messages_are_named(text, kind):
    with pytest.raises(Malformed) as exc:
        parse_message(text)
    assert exc.value.kind == kind


# ---------------------------------------------------------------------------------------------- phone
class Phone:
    """A scripted phone page: answers pings at once, streams poses (30 Hz) and IMU (60 Hz) of ``motion``
    (T_camera_marker at video time t; its VIO pose is T_CVIO_DVIO · T_DISPLAY_CAMERA · that)."""

    motion = staticmethod(T_camera_marker)

    def __init__(self, session: LiveSession, port: int, token: str):
        self.s = session
        self.clock = session.source.clock
        self.base = f"https://127.0.0.1:{port}"
        self.token = token
        self.sent: list[tuple[str, float, int]] = []     # (type, t ms, true capture ns on the recorder clock)
        self.received: list[dict] = []

    def phone_ms(self, rec_ns: int) -> float:
        return (rec_ns + OFFSET_NS) / 1e6

    async def _reader(self, ws) -> None:
        async for msg in ws:
            if msg.type != aiohttp.WSMsgType.TEXT:
                break
            m = json.loads(msg.data)
            self.received.append(m)
            if m["type"] == "ping":
                await self.answer_ping(ws, m)

    async def answer_ping(self, ws, ping: dict) -> None:
        """The page's pong, stamped when it answers: at once here."""
        if not ws.closed:
            await ws.send_str(json.dumps({"type": "pong", "id": ping["id"], "server_ns": ping["server_ns"],
                                          "t": self.phone_ms(self.clock.now_ns())}))

    async def connect(self, http: aiohttp.ClientSession):
        ws = await http.ws_connect(f"{self.base}/ws?token={self.token}")
        reader = asyncio.ensure_future(self._reader(ws))
        return ws, reader

    async def send_pose(self, ws, kind: str, start_ns: int, t_true_ns: int, t_ms: float | None = None) -> None:
        pose = T_CVIO_DVIO @ T_DISPLAY_CAMERA @ self.motion((t_true_ns - start_ns) / 1e9)
        t_ms = self.phone_ms(t_true_ns) if t_ms is None else t_ms
        await ws.send_str(json.dumps({"type": kind, "t": t_ms, "p": pose.translation.tolist(),
                                      "q": pose.quat_xyzw.tolist()}))
        self.sent.append((kind, t_ms, t_true_ns))

    async def stream(self, ws, start_ns: int, until_s: float, tap_at_s: float | None = None) -> None:
        """Poses every other IMU sample, on the video's timeline, until video time ``until_s``."""
        k = 0
        tapped = tap_at_s is None
        while True:
            now = self.clock.now_ns()
            t_s = (now - start_ns) / 1e9
            if t_s >= until_s:
                return
            t_ms = self.phone_ms(now)
            await ws.send_str(json.dumps({"type": "imu", "t": t_ms, "gyro": [0.01, 0.02, 0.03],
                                          "accel": [0.1, 9.8, 0.2]}))
            self.sent.append(("imu", t_ms, now))
            if k % 2 == 0:
                await self.send_pose(ws, "pose", start_ns, now)
            if not tapped and t_s >= tap_at_s:
                await self.send_pose(ws, "anchor", start_ns, now)
                tapped = True
            k += 1
            await asyncio.sleep(1 / 60)


def _start(media, tmp_path, **kw) -> tuple[LiveSession, dict, threading.Thread, list[str]]:
    _, video, calib = media
    lines: list[str] = []
    s = LiveSession(tmp_path / "s.mcap", str(video), calib, host="127.0.0.1", port=0, tls_dir=tmp_path / "tls",
                    echo=lines.append, **kw)
    s.start()
    out: dict = {}
    th = threading.Thread(target=lambda: out.setdefault("result", s.run()), daemon=True)
    th.start()
    return s, out, th, lines


def _wait_video_start(s: LiveSession) -> int:
    wait_until(lambda: s.source.camera.start_ns is not None and s.source.recording.latest_frame_ns is not None,
               what="the camera's first frame")
    return s.source.camera.start_ns


def _finish(th: threading.Thread) -> None:
    """Wait for the recording thread of :func:`_start` to end (after the video ended or stop())."""
    th.join(timeout=DEADLINE_S)
    assert not th.is_alive(), f"the recording did not finish within {DEADLINE_S:g} s"


def _messages(path):
    with SessionReader(path) as r:
        return list(r.messages())


STAMP_ROUNDING_NS = 1_000   # a page time in ms as a double (~1.7e12 ms: 0.24 us apart), rounded to ns by the recorder


class ServerSide:
    """The recorder's side of one page connection, and every clock exchange it accounts (also those the
    estimator's window has dropped since): what its samples were stamped with."""

    def __init__(self, conn):
        self.conn = conn
        self.exchanges: list = []
        pong = conn.clock.pong

        def pong_kept(*args):
            ex = pong(*args)
            if ex is not None:
                self.exchanges.append(ex)
            return ex

        conn.clock.pong = pong_kept                   # first, then the ones it already had: none is missed
        self.exchanges.extend(list(conn.clock.exchanges))

    @classmethod
    async def of_new(cls, s: LiveSession, role: str = "phone", not_these: tuple = ()) -> ServerSide:
        """The connection the page of ``role`` just opened (the tests open one of a role at a time)."""
        conn = await wait_until_async(
            lambda: (c := s.source.server.current.get(role)) is not None and all(c is not o.conn for o in not_these)
            and c, what=f"the recorder's side of the new {role} connection")
        return cls(conn)


def _assert_stamped_within_the_clock_sync(errs_ns, sides: list[ServerSide], true_offset_ns: int) -> None:
    """Stamp errors (stamp - true capture time) from the clock offsets the recorder estimated, as they were.

    Each error must be that of an offset one of the connections' exchanges gave (capture = t - offset), and
    each exchange's offset is within half its own round trip of the page's true offset (NTP's bound: the
    page stamps its pong between the ping's send and the pong's receipt). A loaded machine lengthens the
    round trips and widens this bound with them; a fixed few ms would fail there with correct code."""
    by_err = {}
    for side in sides:
        assert side.conn.fallback_offset_ns is None, f"{side.conn.name}: stamped without a pong"
        for ex in side.exchanges:
            assert abs(ex.offset_ns - true_offset_ns) <= ex.rtt_ns / 2 + STAMP_ROUNDING_NS, (side.conn.name, ex)
            by_err[true_offset_ns - ex.offset_ns] = ex
    assert by_err, "no clock exchange"
    for e in errs_ns:
        assert any(abs(e - k) <= STAMP_ROUNDING_NS for k in by_err), \
            (f"a stamp {e / 1e6:+.3f} ms off: no exchange of the recorder's gives that offset",
             sorted((k / 1e6, ex.rtt_ns / 1e6) for k, ex in by_err.items()))


# ---------------------------------------------------------------------------------------------- whole sessions
@pytest.mark.slow
def test_scripted_phone_session_records_and_plays_back(media, tmp_path):
    s, out, th, lines = _start(media, tmp_path)
    phone = Phone(s, s.port, s.token)
    start = _wait_video_start(s)
    statuses: dict = {}
    sides: list[ServerSide] = []

    async def script():
        async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(ssl=False)) as http:
            # wrong or missing token: 403 on every route, nothing recorded from it
            for url in (f"{phone.base}/?token=nope", f"{phone.base}/config", f"{phone.base}/marker.png?token=x"):
                async with http.get(url) as r:
                    statuses[url] = r.status
            with pytest.raises(aiohttp.WSServerHandshakeError) as exc:
                await http.ws_connect(f"{phone.base}/ws?token=wrong")
            statuses["ws"] = exc.value.status
            async with http.get(f"{phone.base}/config?token={s.token}") as r:
                statuses["config"] = await r.json()
            async with http.get(f"{phone.base}/marker.png?token={s.token}") as r:
                statuses["png"] = (await r.read())[:8]

            # first connection: hello, marker, samples, then it drops mid-session (no close frame)
            ws, reader = await phone.connect(http)
            sides.append(await ServerSide.of_new(s))
            await ws.send_str(json.dumps({"type": "hello", "user_agent": "scripted phone", "webxr": True, "message": ""}))
            await ws.send_str(json.dumps({"type": "marker", "dictionary": "DICT_4X4_50", "id": 7, "size_m": MARKER_SIZE,
                                          "ppi": 400.0, "device_pixel_ratio": 2.625}))
            await phone.stream(ws, start, 0.6)
            # malformed messages: logged and ignored, the connection stays
            for bad in ("{oops", '{"type": "teleport"}', '{"type": "pose", "t": 1}',
                        '{"type": "imu", "t": 1, "gyro": [1, 2], "accel": [0, 0, 0]}'):
                await ws.send_str(bad)
            await ws.send_bytes(b"\x00\x01")
            # out of order: a pose stamped 200 ms in the past
            now = phone.clock.now_ns()
            await phone.send_pose(ws, "pose", start, now - 200_000_000)
            await phone.stream(ws, start, 0.8)
            # its samples are stamped through a pong (a loaded machine can delay the pongs past the 0.8 s)
            await wait_until_async(lambda: sides[0].conn.settled, what="the first connection's clock offset")
            ws._response.connection.transport.abort()           # the phone vanishes
            reader.cancel()
            # a new connection (the page reloaded) carries on and taps "anchor"
            ws, reader = await phone.connect(http)
            sides.append(await ServerSide.of_new(s, not_these=tuple(sides)))
            await phone.stream(ws, start, VIDEO_S - 0.3, tap_at_s=TAP_S)
            await ws.close()          # after the samples on the same stream: the server reads them first
            reader.cancel()

    asyncio.run(script())
    _finish(th)
    result = out["result"]
    assert result.stop_reason == "the video file ended"
    assert all(v == 403 for k, v in statuses.items() if k not in ("config", "png"))
    assert statuses["config"] == {"marker": {"dictionary": "DICT_4X4_50", "id": 7}, "gt_controller": "right"}
    assert statuses["png"] == b"\x89PNG\r\n\x1a\n"

    msgs = _messages(tmp_path / "s.mcap")
    by = {}
    for m in msgs:
        by.setdefault(m.topic, []).append(m)
    n_frames = int(VIDEO_S * FPS)
    assert len(by[Topic.CAMERA_IMAGE]) == n_frames and len(by[Topic.DISPLAY_VIO_POSE]) == n_frames
    from phonepose.viewer.frames import FRAME_TREE_TOPICS  # written by the recorder beside the source's records
    recorded = [m.topic for m in msgs if m.topic not in FRAME_TREE_TOPICS]
    assert recorded[:3] == [Topic.SESSION_INFO, Topic.CAMERA_CALIBRATION, Topic.CAMERA_EXTRINSICS]
    assert by[Topic.SESSION_INFO][0].msg.source == "live"
    config = tomllib.loads(by[Topic.SESSION_INFO][0].msg.config_toml)["live"]
    assert (config["camera"], config["marker_id"], config["image_width"]) == (str(media[1]), 7, W)
    assert len(by[Topic.CONTROLLER_MARKER]) == 1 and by[Topic.CONTROLLER_MARKER][0].msg.size_m == MARKER_SIZE
    # nothing received is lost: every pose and IMU sample sent is in the file, in receipt order
    sent_poses = [x for x in phone.sent if x[0] == "pose"]
    sent_imu = [x for x in phone.sent if x[0] == "imu"]
    assert len(by[Topic.CONTROLLER_VIO_POSE]) == len(sent_poses)
    assert len(by[Topic.CONTROLLER_IMU]) == len(sent_imu)
    log_times = [m.log_time_ns for m in msgs]
    assert log_times[3:] == sorted(log_times[3:])                # one time order across topics
    # the page clock offset is recovered: capture stamps = true capture times within the clock sync's error
    # (half the round trip of the exchange used: a few ms on a quiet machine, more on a loaded one)
    pairs = zip(by[Topic.CONTROLLER_VIO_POSE], sent_poses, strict=True)
    errs = [m.msg.timestamp.ToNanoseconds() - true for m, (_, _, true) in pairs]
    _assert_stamped_within_the_clock_sync(errs, sides, OFFSET_NS)
    # out of order: written as received, counted in the summary and /log
    stamps = [m.msg.timestamp.ToNanoseconds() for m in by[Topic.CONTROLLER_VIO_POSE]]
    assert sum(b <= a for a, b in zip(stamps, stamps[1:], strict=False)) == 1
    logs = [m.msg.message for m in by[Topic.LOG]]
    assert any("/controller/vio/pose 1" in t for t in logs)
    assert any("malformed messages ignored: 5" in t for t in logs)
    assert any("refused" in t for t in logs) and any("replaced" in t or "disconnected" in t or "closed" in t
                                                      for t in logs)
    assert sum("ignored a malformed message" in t for t in logs) == 5
    # the anchor: viewer pose at the tap / the marker pose drawn in the frame closest to it
    (ca,), (da,) = by[Topic.CONTROLLER_ANCHOR], by[Topic.DISPLAY_ANCHOR]
    frame_s = (da.msg.timestamp.ToNanoseconds() - start) / 1e9
    tap_true = next(true for kind, _, true in phone.sent if kind == "anchor")
    tap_ns = ca.msg.timestamp.ToNanoseconds()     # the tap on the recorder clock, through the clock sync
    _assert_stamped_within_the_clock_sync([tap_ns - tap_true], sides, OFFSET_NS)
    frame_stamps = [m.msg.timestamp.ToNanoseconds() for m in by[Topic.CAMERA_IMAGE]]
    assert abs(da.msg.timestamp.ToNanoseconds() - tap_ns) == min(abs(f - tap_ns) for f in frame_stamps)   # the closest
    assert abs(da.msg.timestamp.ToNanoseconds() - tap_ns) <= 1e9 / FPS / 2 + STAMP_ROUNDING_NS
    drawn = T_dvio_controller(frame_s)
    got = codec.pose_of(da.msg.pose)
    assert np.linalg.norm(got.translation - drawn.translation) < 0.005
    assert float(got.angle_to(drawn)) < np.deg2rad(3)
    assert da.msg.frame_id == Frame.DISPLAY_VIO and ca.msg.frame_id == Frame.CONTROLLER_VIO
    # it plays back with every tracker giving poses (no ground truth: metrics null)
    pb_result = run_playback(tmp_path / "s.mcap", trackers="all", write_outputs=False)
    assert pb_result.trajectories and not pb_result.has_gt
    for name, traj in pb_result.trajectories.items():
        assert len(traj.stamps_ns) > 10, name
    t1 = pb_result.trajectories["T1"]
    truth = Pose.concatenate([T_dvio_controller((t - start) / 1e9) for t in t1.stamps_ns])
    err = np.linalg.norm(t1.poses.translation - truth.translation, axis=1)
    assert np.median(err) < 0.01, np.median(err)     # VIO mapped through the recorded anchors


def test_bad_camera_or_calibration_fail_before_anything_is_written(media, tmp_path):
    from phonepose.errors import ConfigError, InputFileError

    _, video, calib = media
    other = tmp_path / "other.yaml"
    save_calibration(other, CameraCalibrationFile(K, np.zeros(5), 1280, 720))
    with pytest.raises(ConfigError, match="gives 640x480 frames but the calibration is for 1280x720"):
        LiveSession(tmp_path / "a.mcap", str(video), other, port=0, tls_dir=tmp_path / "tls")
    with pytest.raises(InputFileError, match="no such video file"):
        LiveSession(tmp_path / "a.mcap", str(tmp_path / "nope.avi"), calib, port=0, tls_dir=tmp_path / "tls")
    with pytest.raises(ConfigError, match="marker_size_m 5: "):
        LiveSession(tmp_path / "a.mcap", str(video), calib, port=0, tls_dir=tmp_path / "tls", marker_size_m=5.0)
    assert not (tmp_path / "a.mcap").exists()


def test_anchor_without_the_marker_in_view_is_refused(long_media, tmp_path):
    s, out, th, lines = _start(long_media, tmp_path, marker_size_m=MARKER_SIZE)
    phone = Phone(s, s.port, s.token)
    start = _wait_video_start(s)

    async def script():
        async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(ssl=False)) as http:
            ws, reader = await phone.connect(http)
            # the clock offset from a pong (without one, the tap's own receipt would define the offset)
            await wait_until_async(lambda: "phone" in s.source.server.current and s.source.server.current["phone"].clock.best(),
                                   what="a pong, for the page clock offset")
            # a tap 2 s before the video started: no camera frame near it
            await phone.send_pose(ws, "anchor", start, start - 2_000_000_000)
            await wait_until_async(lambda: any(m["type"] == "error" for m in phone.received),
                                   what="the server's error message for the refused anchor")
            await ws.close()
            reader.cancel()

    asyncio.run(script())
    s.stop("test done")
    _finish(th)
    errors = [m["message"] for m in phone.received if m["type"] == "error"]
    assert errors and errors[0].startswith("anchor refused: the marker was not recognised")
    assert any("anchor refused" in line for line in lines)
    topics = {m.topic for m in _messages(tmp_path / "s.mcap")}
    assert Topic.DISPLAY_ANCHOR not in topics and Topic.CONTROLLER_ANCHOR not in topics
    assert Topic.CONTROLLER_MARKER in topics          # --marker-size: written at the start
    assert out["result"].stop_reason == "test done"


@pytest.mark.slow
def test_cli_prints_the_url_and_sigint_finishes_a_valid_file(long_media, tmp_path):
    _, video, calib = long_media
    out = tmp_path / "cli.mcap"
    proc = subprocess.Popen([sys.executable, "-m", "phonepose", "record", "live", "--camera", str(video),
                             "--calibration", str(calib), "--out", str(out), "--host", "127.0.0.1", "--port", "0",
                             "--tls-dir", str(tmp_path / "tls")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        url = None
        for _ in range(50):
            line = proc.stdout.readline()
            if line.strip().startswith("https://"):
                url = line.strip()
                break
        assert url is not None
        # the output rule's lock, held for the whole recording: no other phonepose replaces the file meanwhile
        # (tests/test_files.py), and reading it says what it is
        from phonepose.files import being_written

        assert being_written(out)
        r = subprocess.run([sys.executable, "-m", "phonepose", "info", str(out)], capture_output=True, text=True,
                           timeout=DEADLINE_S)
        assert r.returncode == 2 and r.stderr == (f"phonepose: error: {out}: a recording in progress (another phonepose "
                                                  "is writing it; its footer and index come last): wait for it to "
                                                  "finish\n"), r.stderr
        sent = 0

        async def script():
            nonlocal sent
            async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(ssl=False)) as http:
                ws = await http.ws_connect(url.replace("/?token=", "/ws?token="))

                errors = []

                async def pong():
                    async for msg in ws:
                        m = json.loads(msg.data)
                        if m["type"] == "ping":
                            await ws.send_str(json.dumps({"type": "pong", "id": m["id"], "t": time.time_ns() / 1e6}))
                        elif m["type"] == "error":
                            errors.append(m["message"])

                reader = asyncio.ensure_future(pong())
                for _ in range(40):
                    await ws.send_str(json.dumps({"type": "imu", "t": time.time_ns() / 1e6, "gyro": [0, 0, 0],
                                                  "accel": [0, 9.8, 0]}))
                    sent += 1
                    await asyncio.sleep(0.01)
                # the server handles a connection's messages in order and answers a malformed one at
                # once: its answer means every sample before it has been taken
                await ws.send_str('{"type": "teleport"}')
                await wait_until_async(lambda: errors, what="the server's answer to a malformed message")
                proc.send_signal(signal.SIGINT)        # stop while the phone is still connected
                await within(reader, what="the server to close the phone's connection after SIGINT")

        asyncio.run(script())
        stdout, stderr = proc.communicate(timeout=DEADLINE_S)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stderr
    assert "interrupted, file is valid" in stdout
    assert "Traceback" not in stderr
    msgs = _messages(out)
    assert sum(m.topic == Topic.CONTROLLER_IMU for m in msgs) == sent
    assert any(m.topic == Topic.CAMERA_IMAGE for m in msgs)


def test_start_errors_are_one_line_and_leave_no_file(media, tmp_path):
    import socket as socketlib

    from phonepose.errors import ConfigError, InputFileError, OutputError

    _, video, calib = media
    out = tmp_path / "x.mcap"
    with pytest.raises(InputFileError, match="camera 57: cannot open it"):
        LiveSession(out, "57", calib, port=0, tls_dir=tmp_path / "tls")
    with pytest.raises(InputFileError, match="no such calibration file"):
        LiveSession(out, str(video), tmp_path / "none.yaml", port=0, tls_dir=tmp_path / "tls")
    (tmp_path / "notadir").write_text("")
    with pytest.raises(OutputError, match="cannot write the TLS certificate"):
        LiveSession(out, str(video), calib, port=0, tls_dir=tmp_path / "notadir" / "tls")
    with pytest.raises(OutputError, match="does not exist or is not writable"):
        LiveSession(tmp_path / "nodir" / "x.mcap", str(video), calib, port=0, tls_dir=tmp_path / "tls")
    busy = socketlib.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen()
    try:
        s = LiveSession(out, str(video), calib, host="127.0.0.1", port=busy.getsockname()[1], tls_dir=tmp_path / "tls")
        with pytest.raises(ConfigError, match=r"\(choose another port\)"):
            s.start()
    finally:
        busy.close()
    assert not out.exists()


def test_an_existing_recording_is_never_replaced_without_force(media, tmp_path):
    _, video, calib = media
    out = tmp_path / "yesterday.mcap"
    out.write_bytes(b"a real session that cannot be recorded again")
    r = subprocess.run([sys.executable, "-m", "phonepose", "record", "live", "--camera", str(video),
                        "--calibration", str(calib), "--out", str(out), "--port", "0", "--no-qr"],
                       capture_output=True, text=True, timeout=DEADLINE_S)
    assert r.returncode == 6 and r.stdout == ""
    assert r.stderr == f"phonepose: error: {out} already exists: choose another --out, or add --force to replace it\n"
    assert out.read_bytes() == b"a real session that cannot be recorded again"


@pytest.mark.slow
def test_the_real_phone_page_in_headless_chromium_records_imu(long_media, tmp_path):
    """The page of static/ (not a script) against the real server over HTTPS: hello, marker size,
    clock pings and DeviceMotion samples end up in the session. (No WebXR in headless Chromium.)"""
    from playwright.sync_api import sync_playwright

    chromium = require_browser()
    s, out, th, lines = _start(long_media, tmp_path)
    n = 30
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=chromium, headless=True, timeout=DEADLINE_S * 1000,
                                     args=["--no-sandbox", "--disable-gpu", "--no-first-run"])
        try:
            ctx = browser.new_context(viewport={"width": 400, "height": 800}, device_scale_factor=2,
                                      ignore_https_errors=True)
            ctx.set_default_timeout(DEADLINE_S * 1000)
            page = ctx.new_page()
            page.goto(f"https://127.0.0.1:{s.port}/?ppi=320&token={s.token}")
            # hello is the connection's first message: once it is handled the socket is open (the page
            # drops samples until then)
            wait_until(lambda: any("no WebXR immersive-ar" in line for line in lines), what="the page's hello")
            # the page's clock as Playwright sees it (fastest of 25 round trips): Chromium's timeOrigin + now()
            # is not the recorder's clock even on one machine (measured 2-12 ms apart), so it is measured
            probes = []
            for _ in range(25):
                t0 = s.source.clock.now_ns()
                page_ms = page.evaluate("() => performance.timeOrigin + performance.now()")
                t1 = s.source.clock.now_ns()
                probes.append((t1 - t0, page_ms * 1e6 - (t0 + t1) / 2))
            probe_rtt_ns, page_offset_ns = min(probes)
            page.evaluate("""async (n) => { for (let i = 0; i < n; i++) {
                window.dispatchEvent(new DeviceMotionEvent('devicemotion', {rotationRate: {alpha: 1, beta: 2, gamma: 3},
                    accelerationIncludingGravity: {x: 0.1, y: 9.8, z: 0.2}, interval: 16}));
                await new Promise((r) => setTimeout(r, 10)); } }""", n)
            wait_until(lambda: s.source.recording.stats["imu"] >= n, what=f"{n} IMU samples at the recorder")
            wait_until(lambda: "phone" in s.source.server.current and s.source.server.current["phone"].clock.best(),
                       what="a pong, for the page clock offset")
            s.stop("test done")
            _finish(th)
        finally:
            browser.close()
    assert any("no WebXR immersive-ar" in line for line in lines)          # hello from headless Chromium
    msgs = _messages(tmp_path / "s.mcap")
    # in /log; the terminal shows it too unless the connect pings took over 0.5 s (a loaded machine)
    offsets = [m.msg.message for m in msgs if m.topic == Topic.LOG and "page clock offset" in m.msg.message]
    # the estimate is within half its best round trip of the page's clock as measured above (itself within
    # half the probe's round trip), plus the 0.1 ms the log rounds to
    offset_ms = float(offsets[0].split("offset ")[1].split(" ms")[0])
    rtt_ms = float(offsets[0].split("best round trip ")[1].split(" ms")[0])
    assert abs(offset_ms - page_offset_ns / 1e6) <= rtt_ms / 2 + probe_rtt_ns / 2e6 + 0.1, \
        (offsets[0], page_offset_ns / 1e6, probe_rtt_ns / 1e6)
    imu = [m for m in msgs if m.topic == Topic.CONTROLLER_IMU]
    assert len(imu) == n
    assert imu[0].msg.gyro_x == pytest.approx(math.radians(2))
    (spec,) = [m.msg for m in msgs if m.topic == Topic.CONTROLLER_MARKER]    # no anchor: written at the end
    assert 0.01 < spec.size_m < 0.1
