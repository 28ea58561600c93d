"""One rehearsed recording: ``record live`` on the scene's video, the browser's pages playing the scene.

Timeline: Chromium starts; the recording starts and the video's still lead-in plays while the phone
page opens (Start AR) and the headset page (its VR button); each page's clock is measured against the
recorder's and sim time 0 (the first moving frame) is handed to it; the Anchor button is tapped during
the lead-in (the marker is in view and the phone holds still, as a user would tap); the recording
ends with the video.
"""

from __future__ import annotations

import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from phonepose.errors import ConfigError
from phonepose.record.rehearse.browser import DevicePage, RehearsalBrowser, browser_failure, grip_offset, wait_for
from phonepose.record.rehearse.scene import Scene

ANCHOR_BEFORE_S = 5.0     # the tap: this long before the motion starts (lead-in: still, in view; a click can take 1-2 s)
# Enter VR this long before the motion: the ground truth starts then. Sooner, calibrate-gt would weigh the still
# lead-in's one pose hundreds of times, and its world->camera would carry that pose's marker error
ENTER_VR_BEFORE_S = 2.0


@dataclass
class RecordedRun:
    path: Path
    summary: list[str]
    counts: dict
    stop_reason: str
    sim0_ns: int                                  # sim time 0 on the recorder's clock
    clocks: dict = field(default_factory=dict)    # page name -> PageClock
    page_states: dict = field(default_factory=dict)
    headset: bool = False
    setup_s: float = float("nan")                 # recording start -> both pages playing
    tracking: list = field(default_factory=list)  # the live trackers' closing summary (record live -t)


def record_rehearsal(scene: Scene, out: Path, *, iwer: Path, headset: bool, timeout_s: float,
                     echo: Callable[[str], None], tracking=None) -> RecordedRun:
    from playwright.sync_api import Error as PlaywrightError

    try:
        with tempfile.TemporaryDirectory(prefix="phonepose-rehearsal-tls-") as tls, \
                RehearsalBrowser(iwer, timeout_s) as browser:    # a certificate for this run only; Chromium first
            return _record(scene, out, Path(tls), browser, headset=headset, timeout_s=timeout_s, echo=echo,
                           tracking=tracking)
    except PlaywrightError as exc:
        raise browser_failure(exc) from None


def _record(scene: Scene, out: Path, tls: Path, browser: RehearsalBrowser, *, headset: bool, timeout_s: float,
            echo: Callable[[str], None], tracking=None) -> RecordedRun:
    from phonepose.record.live import LiveSession

    marker = scene.config.marker
    live = LiveSession(out, str(scene.video_path), scene.calibration_path, host="127.0.0.1", port=0, tls_dir=tls,
                       dictionary=marker.dictionary, marker_id=marker.id, marker_size_m=marker.size_m, pace=True,
                       echo=lambda line: echo(f"  record live: {line}"), tracking=tracking)
    try:
        url = live.start()
    except BaseException:
        live.source.close()
        raise
    headset_url = live.headset_url
    client = None
    if live.source.pose_server is not None:
        echo(f"  live trackers: pose stream at {live.source.pose_server.url}")
        client = PoseStreamClient(live.source.pose_server.url)
    result: dict = {}

    def run() -> None:
        try:
            result["live"] = live.run()
        except BaseException as exc:   # noqa: BLE001 - re-raised in the caller's thread
            result["error"] = exc

    thread = threading.Thread(target=run, name="phonepose-rehearsal-recorder", daemon=True)
    thread.start()
    source = live.source
    clock = source.clock
    try:
        # the camera thread has read its second frame: the video's clock has been restarted at "now"
        wait_for(lambda: source.camera.frames >= 2 or "error" in result, "the recording to start", timeout_s)
        if "error" in result:
            raise result["error"]
        assert source.camera.start_ns is not None   # a file's first frame time
        sim0_ns = source.camera.start_ns + int(round(scene.lead_in_s * 1e9))
        run_info = RecordedRun(out, [], {}, "", sim0_ns, headset=headset)
        t_setup = time.monotonic()
        steps: list[str] = []

        def step(what: str) -> None:
            steps.append(f"{what} {time.monotonic() - t_setup:.1f} s")

        pages: list[DevicePage] = []
        phone = browser.open(url, "phone")
        pages.append(phone)
        phone.evaluate("t => window.__rehearsal.load(t)", {"mode": "phone", "viewer": scene.phone_table(),
                                                          "imu": scene.imu_table()})
        vr = None
        if headset:
            vr = browser.open(headset_url, "headset")
            pages.append(vr)
            vr.evaluate("t => window.__rehearsal.load(t)", {"mode": "headset", **scene.headset_tables(grip_offset(vr))})
        step("pages loaded")
        for p in pages:
            run_info.clocks[p.name] = p.measure_clock(clock.now_ns)
            p.start(sim0_ns)
        wait_for(lambda: phone.page.is_enabled("#btn-ar"), "the phone page to offer Start AR", timeout_s)
        phone.page.click("#btn-ar")
        wait_for(lambda: phone.page.inner_text("#btn-ar").strip() == "Stop AR", "the phone's AR session", timeout_s)
        step("AR")
        if vr is not None:
            wait_for(lambda: vr.page.is_enabled("#btn-vr"), "the headset page to offer its VR button", timeout_s)
        run_info.setup_s = time.monotonic() - t_setup
        late = (clock.now_ns() - sim0_ns) / 1e9 + ANCHOR_BEFORE_S
        if late > 0:
            raise ConfigError(f"rehearsal: the browser took {run_info.setup_s:.1f} s to open the pages ({', '.join(steps)}), "
                              f"{late:.1f} s too long for the {scene.lead_in_s:g} s lead-in: give a longer "
                              "{lead_in_s}", parameter="lead_in_s", value=scene.lead_in_s)
        wait_for(lambda: clock.now_ns() >= sim0_ns - int(ANCHOR_BEFORE_S * 1e9), "the anchor's moment", timeout_s)
        phone.page.click("#btn-anchor")
        echo(f"  pages ready ({', '.join(steps)}); tapped Anchor at sim time "
             f"{(clock.now_ns() - sim0_ns) / 1e9:+.2f} s")
        if vr is not None:
            wait_for(lambda: clock.now_ns() >= sim0_ns - int(ENTER_VR_BEFORE_S * 1e9), "the moment to enter VR",
                     timeout_s)
            vr.page.click("#btn-vr")
            wait_for(lambda: vr.state()["driven"] > 0, "the headset's VR session", timeout_s)
            # late on a busy machine: the ground truth then misses the motion's first moments (said here; scored)
            echo(f"  entered VR, its first frame at sim time {(clock.now_ns() - sim0_ns) / 1e9:+.2f} s")
        end_s = scene.duration_s
        wait_for(lambda: not thread.is_alive(), "the video to end", end_s + scene.lead_in_s + timeout_s)
        for p in pages:
            run_info.page_states[p.name] = p.state()
        # what IWER emulated of the phone page's optional features (docs: "what IWER emulates")
        run_info.page_states["phone"].update(phone.evaluate(
            "() => { const s = window.phonepose.state; return {xr_anchors: s.anchors.length, "
            "dom_overlay: Boolean(s.xrSession && s.xrSession.domOverlayState), "
            "page_message: document.getElementById('error').textContent}; }"))
    finally:
        if thread.is_alive():
            live.stop("rehearsal ended")
            thread.join(timeout_s)
        if client is not None:
            client.stop(timeout_s)
    if "error" in result:
        raise result["error"]
    res = result["live"]
    run_info.summary, run_info.counts, run_info.stop_reason = res.summary, res.counts, res.stop_reason
    run_info.tracking = list(res.tracking)
    if client is not None:
        run_info.tracking.append(f"pose stream: an application client received {client.received} estimate(s)"
                                 + (f" ({client.error})" if client.error else ""))
    return run_info


class PoseStreamClient:
    """An application reading the live trackers' pose stream during the rehearsal (as examples/pose_client.py
    does), in a thread of its own: it counts the estimates it receives."""

    def __init__(self, url: str):
        import asyncio

        self.url = url
        self.received = 0
        self.error = ""
        self._loop = asyncio.new_event_loop()
        self._stop: asyncio.Event | None = None
        self._thread = threading.Thread(target=self._loop.run_until_complete, args=(self._read(),),
                                        name="phonepose-rehearsal-pose-client", daemon=True)
        self._thread.start()

    async def _read(self) -> None:
        import asyncio

        import aiohttp

        self._stop = asyncio.Event()
        try:
            async with aiohttp.ClientSession() as session, session.ws_connect(self.url) as ws:
                reading = asyncio.ensure_future(self._count(ws))
                stopping = asyncio.ensure_future(self._stop.wait())
                await asyncio.wait({reading, stopping}, return_when=asyncio.FIRST_COMPLETED)
                for task in (reading, stopping):
                    task.cancel()
        except (aiohttp.ClientError, OSError) as exc:
            self.error = f"{type(exc).__name__}: {exc}"

    async def _count(self, ws) -> None:
        import aiohttp

        async for msg in ws:
            if msg.type != aiohttp.WSMsgType.TEXT:
                break
            self.received += 1

    def stop(self, timeout_s: float) -> None:
        if self._stop is not None:
            self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(timeout_s)
