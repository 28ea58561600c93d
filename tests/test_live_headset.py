"""Ground truth from a WebXR headset in ``record live`` (issue 20), against the real server: a scripted
headset page (an aiohttp WebSocket client speaking the headset page's protocol) streams the grip pose
of the controller fixed to the phone, and ``calibrate-gt`` recovers, from the recorded session alone,
what the script was made with.

The truth: the video shows the marker (= the phone's body) at ``T_camera_marker(t)``, turning about
all three axes; the display stands still (display_vio = display). The controller's grip sits at
:data:`X_TRUE` on the phone's body, the headset's world is :data:`Z_TRUE` away from display_vio, and
the headset stamps each pose :data:`GT_LAG_S` after the instant it shows, on a page clock
:data:`HEADSET_OFFSET_NS` away from the recorder's (which the ping/pong estimate removes; the lag it
cannot see, calibrate-gt must find).
"""

from __future__ import annotations

import asyncio
import json
import math
import subprocess
import sys

import aiohttp
import numpy as np
import pytest
import test_record_live
from conftest import wait_until_async
from scipy.spatial.transform import Rotation
from test_record_live import (
    MARKER_SIZE,
    R_CAM_MARKER0,
    Phone,
    ServerSide,
    _assert_stamped_within_the_clock_sync,
    _finish,
    _messages,
    _start,
    _wait_video_start,
    write_marker_video,
)

from phonepose.calibration.calibrate_gt import calibrate_gt_session
from phonepose.calibration.gt_calibration import GtCalibration
from phonepose.geometry import Pose
from phonepose.playback.engine import run_playback
from phonepose.playback.scheduler import GT_TOLERANCE_S, MAX_GAP_S
from phonepose.record.live.recording import T_DISPLAY_CAMERA
from phonepose.record.live.webxr import gt_world_to_xr, xr_to_gt_world
from phonepose.schemas.topics import Frame, Topic
from phonepose.session import codec

media = test_record_live.media
long_media = test_record_live.long_media
HEADSET_S = 8.0
HEADSET_OFFSET_NS = -987_654_321_123      # the headset page's clock (performance.timeOrigin + now) vs the recorder's
GT_LAG_S = 0.030                          # its poses are stamped this late (frame time vs the instant tracked)
XR_HZ = 72.0
GAP = (4.0, 4.35)                         # video seconds during which the phone's controller is not tracked
X_TRUE = Pose(Rotation.from_euler("zyx", [80.0, -6.0, 4.0], degrees=True), np.array([0.012, -0.055, -0.018]))  # body <- grip
Z_TRUE = Pose(Rotation.from_euler("zyx", [-35.0, 3.0, -2.0], degrees=True), np.array([1.2, -0.4, -0.8]))     # dvio <- gt_world
T_WORLD_BOARD = Pose(Rotation.from_euler("z", 20, degrees=True), np.array([0.9, 0.1, 0.75]))                  # left controller
QUEST_UA = ("Mozilla/5.0 (X11; Linux x86_64; Quest 3) AppleWebKit/537.36 (KHTML, like Gecko) OculusBrowser/33.0.0.7 "
            "SamsungBrowser/4.0 Chrome/126.0.6478.122 VR Safari/537.36")


def T_camera_marker(t_s: float) -> Pose:
    """The phone turning about all three axes in front of the camera (the headset procedure's motion)."""
    rot = Rotation.from_euler("zyx", [25 * math.sin(2 * math.pi * t_s / 3.7), 18 * math.sin(2 * math.pi * t_s / 2.9),
                                      15 * math.sin(2 * math.pi * t_s / 2.3)], degrees=True)
    pos = np.array([0.04 * math.sin(2 * math.pi * t_s / 3.1), 0.03 * math.cos(2 * math.pi * t_s / 2.6),
                    0.34 + 0.03 * math.sin(2 * math.pi * t_s / 4.1)])
    return Pose(rot * R_CAM_MARKER0, pos)


def T_world_grip(t_s: float) -> Pose:
    """B = Z⁻¹ A X: the grip in the headset's world when the phone's body is at A (display_vio)."""
    return Z_TRUE.inv() @ T_DISPLAY_CAMERA @ T_camera_marker(t_s) @ X_TRUE


@pytest.fixture(scope="module")
def headset_media(media, tmp_path_factory):
    d = tmp_path_factory.mktemp("headset")
    _, _, calib = media
    video = d / "turning.avi"
    write_marker_video(video, T_camera_marker, HEADSET_S)
    return d, video, calib


class TurningPhone(Phone):
    """The scripted phone of test_record_live, its VIO following this module's motion (so T4-T8 have input)."""

    motion = staticmethod(T_camera_marker)


class Headset(Phone):
    """A scripted headset page: answers pings at once on its own clock, streams ``xrframe`` at 72 Hz."""

    def phone_ms(self, rec_ns: int) -> float:
        return (rec_ns + HEADSET_OFFSET_NS) / 1e6

    async def connect(self, http: aiohttp.ClientSession):
        ws = await http.ws_connect(f"{self.base}/ws?token={self.token}&role=headset")
        reader = asyncio.ensure_future(self._reader(ws))
        return ws, reader

    async def stream(self, ws, start_ns: int, until_s: float, gap: tuple[float, float] | None = None) -> None:
        while True:
            now = self.clock.now_ns()
            t_s = (now - start_ns) / 1e9
            if t_s >= until_s:
                return
            p, q = gt_world_to_xr(T_world_grip(t_s))
            right = {"hand": "right"} if gap and gap[0] <= t_s < gap[1] else {"hand": "right", "p": p, "q": q}
            bp, bq = gt_world_to_xr(T_WORLD_BOARD)
            vp, vq = gt_world_to_xr(Pose(Rotation.from_euler("z", 5 * t_s, degrees=True), np.array([0.0, 0.0, 1.6])))
            t_ms = self.phone_ms(now + int(GT_LAG_S * 1e9))
            await ws.send_str(json.dumps({"type": "xrframe", "t": t_ms, "viewer": {"p": vp, "q": vq},
                                          "controllers": [right, {"hand": "left", "p": bp, "q": bq}]}))
            self.sent.append(("right" if "p" in right else "gap", t_ms, now))
            await asyncio.sleep(1 / XR_HZ)


def test_conversion_round_trip_and_axes():
    """WebXR y up / -z forward / +x right become gt_world z up / +x forward / +y left."""
    T = xr_to_gt_world([1.0, 2.0, 3.0], [0.0, 0.0, 0.0, 1.0])
    assert np.allclose(T.translation, [-3.0, -1.0, 2.0])
    ahead = xr_to_gt_world([0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0])
    assert np.allclose(ahead.rotation.apply([0.0, 0.0, -1.0]), [1.0, 0.0, 0.0])      # a viewer's -z: forward
    left = xr_to_gt_world([0.0, 0.0, 0.0], Rotation.from_euler("y", 90, degrees=True).as_quat())   # turned left
    assert np.allclose(left.rotation.apply([0.0, 0.0, -1.0]), [0.0, 1.0, 0.0])
    assert np.allclose(left.rotation.apply([0.0, 1.0, 0.0]), [0.0, 0.0, 1.0])         # its up stays up
    pose = Pose(Rotation.from_euler("zyx", [10, 20, 30], degrees=True), np.array([0.1, -0.2, 0.3]))
    assert xr_to_gt_world(*gt_world_to_xr(pose)).allclose(pose, atol=1e-12)


@pytest.mark.slow
def test_scripted_headset_ground_truth_calibrates_and_scores(headset_media, tmp_path):
    s, out, th, lines = _start(headset_media, tmp_path, marker_size_m=MARKER_SIZE)
    headset = Headset(s, s.port, s.token)
    phone = TurningPhone(s, s.port, s.token)
    start = _wait_video_start(s)
    statuses: dict = {}
    sides: list[ServerSide] = []

    async def script():
        async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(ssl=False)) as http:
            for url in (f"{headset.base}/headset", f"{headset.base}/headset?token=nope"):
                async with http.get(url) as r:
                    statuses[url] = r.status
            async with http.get(f"{headset.base}/headset?token={s.token}") as r:
                statuses["page"] = (r.status, "btn-vr" in await r.text())
            await asyncio.gather(run_headset(http), run_phone(http))

    async def run_phone(http):
        ws, reader = await phone.connect(http)
        await phone.stream(ws, start, HEADSET_S - 0.3, tap_at_s=1.0)
        await ws.close()
        reader.cancel()

    async def run_headset(http):
        ws, reader = await headset.connect(http)
        sides.append(await ServerSide.of_new(s, "headset"))
        await ws.send_str(json.dumps({"type": "hello", "user_agent": QUEST_UA, "webxr": True, "message": ""}))
        await ws.send_str(json.dumps({"type": "xrsession", "state": "started", "space": "local-floor",
                                      "message": ""}))
        await ws.send_str(json.dumps({"type": "pose", "t": 1.0, "p": [0, 0, 0], "q": [0, 0, 0, 1]}))  # not a headset's
        await headset.stream(ws, start, HEADSET_S - 0.2, gap=GAP)
        await wait_until_async(lambda: s.source.recording.stats[Topic.GT_CONTROLLER_POSE]
                               >= sum(k == "right" for k, _, _ in headset.sent), what="every pose at the recorder")
        await ws.close()
        reader.cancel()

    asyncio.run(script())
    _finish(th)
    assert statuses == {f"{headset.base}/headset": 403, f"{headset.base}/headset?token=nope": 403, "page": (200, True)}
    assert s.headset_url == s.url.replace("/?token=", "/headset?token=")
    msgs = _messages(tmp_path / "s.mcap")
    by: dict = {}
    for m in msgs:
        by.setdefault(m.topic, []).append(m)
    gt = by[Topic.GT_CONTROLLER_POSE]
    sent = [x for x in headset.sent if x[0] == "right"]
    assert len(gt) == len(sent) and len(by[Topic.GT_BOARD_CONTROLLER_POSE]) == len(headset.sent)
    assert len(by[Topic.GT_HEADSET_POSE]) == len(headset.sent)
    assert {m.msg.frame_id for m in gt} == {Frame.GT_WORLD}
    # stamped on the recorder clock (log time = stamp): the true instant + the lag, within the clock sync's error
    # (half the round trip of the exchange used: a few ms on a quiet machine, more on a loaded one)
    errs = [m.log_time_ns - (true + int(GT_LAG_S * 1e9)) for m, (_, _, true) in zip(gt, sent, strict=True)]
    assert all(m.log_time_ns == m.msg.timestamp.ToNanoseconds() for m in gt)
    _assert_stamped_within_the_clock_sync(errs, sides, HEADSET_OFFSET_NS)
    first = codec.pose_of(gt[0].msg.pose)
    assert first.allclose(T_world_grip((sent[0][2] - start) / 1e9), atol=1e-6)
    assert codec.pose_of(by[Topic.GT_BOARD_CONTROLLER_POSE][0].msg.pose).allclose(T_WORLD_BOARD, atol=1e-9)
    infos = by[Topic.SESSION_INFO]
    assert [i.msg.ground_truth_source for i in infos] == ["", "webxr-headset (Quest 3, OculusBrowser/33.0.0.7, right controller)"]
    assert Topic.GT_CALIBRATION not in by
    info = subprocess.run([sys.executable, "-m", "phonepose", "info", str(tmp_path / "s.mcap"), "--json"],
                          capture_output=True, text=True)
    assert json.loads(info.stdout)["ground_truth_source"] == infos[-1].msg.ground_truth_source, info.stderr
    logs = [m.msg.message for m in by[Topic.LOG]]
    lost = [t for t in logs if "right controller (on the phone) lost tracking " in t]
    assert len(lost) == 1, logs
    # expected from the frames as sent (a loaded machine can stretch the scripted gap): the recorder stamps them
    # on its clock through the sync, each off by its own measured error (checked above against the sync's bound);
    # the log rounds to 0.1 s and the summary to 0.01 s
    kinds = [k for k, _, _ in headset.sent]
    first_gap = kinds.index("gap")
    back = first_gap + kinds[first_gap:].index("right")
    assert "gap" not in kinds[back:]
    xr_frames = by[Topic.GT_BOARD_CONTROLLER_POSE]       # the left controller: one per frame sent, gap or not
    frame_errs = [m.msg.timestamp.ToNanoseconds() - (true + int(GT_LAG_S * 1e9))
                  for m, (_, _, true) in zip(xr_frames, headset.sent, strict=True)]
    _assert_stamped_within_the_clock_sync(frame_errs, sides, HEADSET_OFFSET_NS)

    def sync_s(*i: int) -> float:      # how far the stamps of frames i may move a difference between them
        return sum(abs(frame_errs[k]) for k in i) / 1e9 + 1e-6

    into_s = float(lost[0].split("lost tracking ")[1].split(" s into")[0])     # from the first XR frame to the gap
    assert abs(into_s - (headset.sent[first_gap][2] - headset.sent[0][2]) / 1e9) <= 0.05 + sync_s(first_gap, 0), lost[0]
    summary = next(t for t in logs if t.startswith("right controller (on the phone): tracking lost 1 time(s), "))
    gap_s = float(summary.split("time(s), ")[1].split(" s in all")[0])
    sent_gap_s = (headset.sent[back][2] - headset.sent[first_gap - 1][2]) / 1e9
    assert sent_gap_s >= GAP[1] - GAP[0] - 2 / XR_HZ
    assert abs(gap_s - sent_gap_s) <= 0.005 + sync_s(back, first_gap - 1), (summary, sent_gap_s)
    assert any("pose message on the headset's connection" in t for t in logs)
    assert any("immersive-vr session started, poses in its 'local-floor' reference space" in t for t in logs)

    # calibrate-gt on the recording alone: the lag, the world and the grip
    cal = calibrate_gt_session(tmp_path / "s.mcap")
    T_world_camera = Z_TRUE.inv() @ T_DISPLAY_CAMERA
    errors = {"time_offset_ms": 1e3 * abs(cal.time_offset_s - GT_LAG_S),
              "world_camera_mm": 1e3 * cal.T_world_camera.distance_to(T_world_camera),
              "world_camera_deg": np.degrees(cal.T_world_camera.angle_to(T_world_camera)),
              "grip_body_mm": 1e3 * cal.T_controller_gt.distance_to(X_TRUE),
              "grip_body_deg": np.degrees(cal.T_controller_gt.angle_to(X_TRUE))}
    print("calibrate-gt errors:", {k: round(float(v), 3) for k, v in errors.items()})   # reported in docs (pytest -s)
    assert errors["time_offset_ms"] < 5 and errors["world_camera_mm"] < 5 and errors["grip_body_mm"] < 5, errors
    assert errors["world_camera_deg"] < 0.5 and errors["grip_body_deg"] < 0.5, errors
    assert not cal.warnings, cal.warnings
    # playback scores the session through the estimate as through the truth it was scripted with
    truth = GtCalibration(T_controller_gt=X_TRUE, time_offset_s=GT_LAG_S, T_world_display_vio=Z_TRUE.inv())
    scored = {name: run_playback(tmp_path / "s.mcap", trackers="T1,T4", write_outputs=False, gt_calibration=c)
              for name, c in (("estimate", cal), ("truth", truth))}
    # the ticks it can score, from the streams as recorded (a loaded machine sends fewer than XR_HZ frames and
    # fewer VIO poses than scripted, so no fixed count): the 20 Hz grid from the first camera frame where the
    # ground truth associates (samples within GT_TOLERANCE_S on both sides, the TUM rule); for T1 also from
    # the anchor on (its log time) and with a VIO pose to hold (at most MAX_GAP_S old)
    t0 = by[Topic.CAMERA_IMAGE][0].msg.timestamp.ToNanoseconds()
    vio = np.array([m.msg.timestamp.ToNanoseconds() for m in by[Topic.CONTROLLER_VIO_POSE]])
    anchor_log_ns = by[Topic.CONTROLLER_ANCHOR][0].log_time_ns
    tol_ns, hold_ns = int(GT_TOLERANCE_S * 1e9), int(MAX_GAP_S * 1e9)

    def scoreable(c: GtCalibration) -> tuple[int, int]:
        gt_ns = np.array([m.msg.timestamp.ToNanoseconds() for m in gt]) - int(round(c.time_offset_s * 1e9))
        ticks = t0 + np.arange((gt_ns[-1] - t0) // 50_000_000 + 1) * 50_000_000
        i = np.searchsorted(gt_ns, ticks, side="right") - 1
        j = np.minimum(i + 1, len(gt_ns) - 1)
        at = (i >= 0) & (gt_ns[np.maximum(i, 0)] == ticks)
        around = (i >= 0) & (i + 1 < len(gt_ns)) & (ticks - gt_ns[np.maximum(i, 0)] <= tol_ns) & (gt_ns[j] - ticks <= tol_ns)
        k = np.searchsorted(vio, ticks, side="right") - 1
        held = (k >= 0) & (ticks - vio[np.maximum(k, 0)] <= hold_ns)
        ok = at | around
        return int(ok.sum()), int((ok & (ticks >= anchor_log_ns) & held).sum())

    for tracker in ("T1", "T4"):
        a, b = (scored[n].metrics["trackers"][tracker]["inside"] for n in ("estimate", "truth"))
        assert abs(a["p_ate_m"] - b["p_ate_m"]) < 0.0005 and abs(a["r_ate_deg"] - b["r_ate_deg"]) < 0.1, (tracker, a, b)
        assert a["p_ate_m"] < 0.005 and a["r_ate_deg"] < 2.0, (tracker, a)   # the marker's own noise
        for name, c in (("estimate", cal), ("truth", truth)):
            every, from_anchor = scoreable(c)
            frames = scored[name].metrics["trackers"][tracker]["inside"]["frames"]
            # the marker is in view throughout: every tick the ground truth covers (T1: once it has an anchor)
            assert frames == (every if tracker == "T4" else from_anchor) > 0, (tracker, name, frames, every, from_anchor)


def test_a_second_headset_replaces_the_first_and_neither_replaces_the_phone(long_media, tmp_path):
    s, out, th, lines = _start(long_media, tmp_path, marker_size_m=MARKER_SIZE)
    phone, first, second = Phone(s, s.port, s.token), Headset(s, s.port, s.token), Headset(s, s.port, s.token)
    start = _wait_video_start(s)
    current = s.source.server.current

    async def script():
        async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(ssl=False)) as http:
            ws_p, reader_p = await phone.connect(http)
            ws_1, reader_1 = await first.connect(http)
            await wait_until_async(lambda: "headset" in current and "phone" in current, what="both connections")
            phone_conn = current["phone"]
            ws_2, reader_2 = await second.connect(http)
            await wait_until_async(lambda: ws_1.closed, what="the first headset to be closed")
            assert ws_1.close_code == 1000 and not ws_p.closed and current["phone"] is phone_conn
            await second.stream(ws_2, start, (s.source.clock.now_ns() - start) / 1e9 + 0.3)
            await phone.stream(ws_p, start, (s.source.clock.now_ns() - start) / 1e9 + 0.3)
            n = sum(k == "right" for k, _, _ in second.sent)
            await wait_until_async(lambda: s.source.recording.stats[Topic.GT_CONTROLLER_POSE] >= n, what="the poses")
            for ws, reader in ((ws_p, reader_p), (ws_2, reader_2)):
                await ws.close()
                reader.cancel()
            reader_1.cancel()

    asyncio.run(script())
    s.stop("test done")
    _finish(th)
    errors = [m["message"] for m in first.received if m["type"] == "error"]
    assert errors == ["another page connected; this one is no longer recorded"]
    assert not [m for m in phone.received if m["type"] == "error"]
    assert any("headset #2 (127.0.0.1): replaced by headset #3 (127.0.0.1)" in line for line in lines), lines
    msgs = _messages(tmp_path / "s.mcap")
    assert sum(m.topic == Topic.GT_CONTROLLER_POSE for m in msgs) == sum(k == "right" for k, _, _ in second.sent)
    assert sum(m.topic == Topic.CONTROLLER_IMU for m in msgs) == sum(k == "imu" for k, _, _ in phone.sent)
