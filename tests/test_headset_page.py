"""The real headset page (static/headset.html + headset.js) in headless Chromium with an emulated Meta
Quest 3 (IWER, tests/webxr_emulation.py), against the real ``record live`` server: the page's own
WebXR code produces the ground truth, and the recorded ``/gt/...`` poses must equal the poses the test
gave the emulated controllers and headset, through WebXR's axis conventions and webxr.py's conversion
(a wrong sign anywhere fails: every component of the poses set is non-zero and different). Also the
bad inputs of issue 20: a browser without WebXR, a session without controllers, a controller that
loses tracking; each one clear line, and the recording goes on.
"""

from __future__ import annotations

import numpy as np
import pytest
import test_record_live
from conftest import wait_until
from playwright.sync_api import sync_playwright
from scipy.spatial.transform import Rotation
from test_record_live import MARKER_SIZE, _finish, _messages, _start, _wait_video_start
from webxr_emulation import grip_offset, launch, new_page, set_connected, set_pose

from phonepose.geometry import Pose
from phonepose.schemas.topics import Frame, Topic
from phonepose.session import codec

media = test_record_live.media
long_media = test_record_live.long_media

# WebXR (local-floor) poses, every component non-zero and distinct
RIGHT = ([0.23, 1.07, -0.41], Rotation.from_euler("xyz", [20, -35, 50], degrees=True))
LEFT = ([-0.31, 0.94, -0.27], Rotation.from_euler("xyz", [-15, 25, -40], degrees=True))
HEAD = ([0.05, 1.62, 0.12], Rotation.from_euler("xyz", [-8, 12, 3], degrees=True))
POSE_TOL_M, POSE_TOL_RAD = 1e-5, 1e-5     # IWER computes in float32 (gl-matrix)
# docs/format.md, written out here rather than taken from webxr.py so that a wrong sign there fails too:
# gt_world x = -xr z (forward), y = -xr x (left), z = xr y (up)
GT_WORLD_FROM_XR = Pose.from_matrix(np.array([[0, 0, -1, 0], [-1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 1]], dtype=float))


@pytest.fixture(scope="module")
def browser():
    with sync_playwright() as pw:
        b = launch(pw)
        try:
            yield b
        finally:
            b.close()


def _place(page, body: str, pose) -> None:
    p, rot = pose
    set_pose(page, body, p, rot.as_quat())


def _expected_grip(page, hand: str, pose) -> Pose:
    """Where the recorder must put the grip: the controller's pose times the model's grip offset, in gt_world."""
    p, rot = pose
    return GT_WORLD_FROM_XR @ Pose(rot, np.array(p)) @ Pose.from_matrix(np.array(grip_offset(page, hand)))


def _enter_vr(page) -> None:
    page.wait_for_selector("body[data-ready='true']")
    assert page.is_enabled("#btn-vr")
    page.click("#btn-vr")
    page.wait_for_function("window.phonepose.state.counts.frames > 0")


def _count(s, topic: str) -> int:
    return s.source.recording.stats[topic]


@pytest.mark.slow
def test_emulated_quest_controller_poses_are_recorded_exactly_and_a_gap_once(browser, long_media, tmp_path):
    s, out, th, lines = _start(long_media, tmp_path, marker_size_m=MARKER_SIZE)
    _wait_video_start(s)
    page = new_page(browser)
    try:
        opened_ns = s.source.clock.now_ns()
        page.goto(s.headset_url)
        _place(page, "right", RIGHT)
        _place(page, "left", LEFT)
        _place(page, "headset", HEAD)
        _enter_vr(page)
        wait_until(lambda: _count(s, Topic.GT_CONTROLLER_POSE) >= 30, what="30 ground-truth poses at the recorder")
        expected = {Topic.GT_CONTROLLER_POSE: _expected_grip(page, "right", RIGHT),
                    Topic.GT_BOARD_CONTROLLER_POSE: _expected_grip(page, "left", LEFT),
                    Topic.GT_HEADSET_POSE: GT_WORLD_FROM_XR @ Pose(HEAD[1], np.array(HEAD[0]))}
        # the right controller switched off for a while: a gap, logged once, counted; the page says so
        set_connected(page, "right", False)
        wait_until(lambda: s.source.recording.headset.tracks["right"].lost_ns is not None, what="the gap at the recorder")
        before = _count(s, Topic.GT_CONTROLLER_POSE)
        board = _count(s, Topic.GT_BOARD_CONTROLLER_POSE)
        wait_until(lambda: _count(s, Topic.GT_BOARD_CONTROLLER_POSE) >= board + 20, what="frames during the gap")
        assert _count(s, Topic.GT_CONTROLLER_POSE) == before
        set_connected(page, "right", True)
        wait_until(lambda: _count(s, Topic.GT_CONTROLLER_POSE) >= before + 20, what="poses after the gap")
        tracking = page.text_content("#tracking")
        s.stop("test done")
        _finish(th)
        stopped_ns = s.source.clock.now_ns()
    finally:
        page.context.close()
    assert tracking == ("The right controller lost tracking 1 time(s): the ground truth has gaps there "
                        "(keep it in the headset's view).")
    msgs = _messages(tmp_path / "s.mcap")
    for topic, want in expected.items():
        got = [m for m in msgs if m.topic == topic]
        assert len(got) >= 30, topic
        assert {m.msg.frame_id for m in got} == {Frame.GT_WORLD}
        for m in got:
            pose = codec.pose_of(m.msg.pose)
            assert np.linalg.norm(pose.translation - want.translation) < POSE_TOL_M, (topic, pose, want)
            assert float(pose.angle_to(want)) < POSE_TOL_RAD, (topic, pose, want)
        # stamped with the XR frames' times on the recorder clock: increasing, between the page's load and the end
        stamps = np.array([m.log_time_ns for m in got])
        assert np.all(np.diff(stamps) > 0) and opened_ns < stamps[0] and stamps[-1] < stopped_ns, topic
    logs = [m.msg.message for m in msgs if m.topic == Topic.LOG]
    assert any("WebXR immersive-vr available" in t and "Quest 3" in t for t in logs)   # IWER's user agent
    assert any("immersive-vr session started, poses in its 'local-floor' reference space" in t for t in logs)
    assert sum("right controller (on the phone) lost tracking" in t for t in logs) == 1
    assert any(t.startswith("right controller (on the phone): tracking lost 1 time(s), ") for t in logs)
    info = [m.msg for m in msgs if m.topic == Topic.SESSION_INFO][-1]
    assert info.ground_truth_source == "webxr-headset (Quest 3, OculusBrowser/33.0.0, right controller)"


@pytest.mark.slow
def test_no_webxr_and_no_controllers_are_one_line_each_and_the_recording_goes_on(browser, long_media, tmp_path):
    s, out, th, lines = _start(long_media, tmp_path, marker_size_m=MARKER_SIZE, gt_controller="left")
    _wait_video_start(s)
    url = f"https://127.0.0.1:{s.port}/headset?token={s.token}"
    plain = new_page(browser, device=None)           # Chromium's own navigator.xr: no immersive-vr device
    try:
        plain.goto(url)
        plain.wait_for_selector("body[data-ready='true']")
        message = plain.text_content("#xr-message")
        disabled = not plain.is_enabled("#btn-vr")
        wait_until(lambda: any("no WebXR immersive-vr" in line for line in lines), what="the page's hello")
    finally:
        plain.context.close()
    assert disabled and message.startswith("WebXR immersive-vr is not available in this browser")
    assert message.endswith("open this link in the browser of a WebXR headset (Meta Quest, Pico, ...)")
    page = new_page(browser)
    try:
        page.goto(url)
        page.wait_for_selector("body[data-ready='true']")
        assert page.text_content("#gt-hand") == "left"              # --gt-controller, through /config
        set_connected(page, "left", False)
        set_connected(page, "right", False)
        _enter_vr(page)
        wait_until(lambda: any("the XR session has no controllers" in line for line in lines),
                   what="the no-controllers line")
        n = _count(s, Topic.GT_HEADSET_POSE)
        wait_until(lambda: _count(s, Topic.GT_HEADSET_POSE) >= n + 20, what="the recording going on")
        wait_until(lambda: page.text_content("#tracking").startswith("No controllers in the VR session"),
                   what="the page's line")
        s.stop("test done")
        _finish(th)
    finally:
        page.context.close()
    result = out["result"]
    assert result.record.frames > 0
    warned = [line for line in lines if "controllers" in line]
    assert sum("the XR session has no controllers: no ground truth for the phone (turn the left controller on" in line
               for line in warned) == 1, warned
    assert sum("no WebXR immersive-vr" in line for line in lines) == 1
    assert any("never the left controller: no /gt/controller/pose" in line for line in result.summary)
    msgs = _messages(tmp_path / "s.mcap")
    assert not any(m.topic == Topic.GT_CONTROLLER_POSE for m in msgs)
    assert sum(m.topic == Topic.GT_HEADSET_POSE for m in msgs) >= 20
